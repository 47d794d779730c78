//! Design pattern 3 for the cart-pole: no Supervisor anywhere in the app. The robot observes
//! with its own devices only (wheel encoders for position and speed, the pole's position
//! sensor, the angle's change per step for its rate), talks to a RobotServer through its
//! Communicator, and restarts episodes the way a real cell would: it drives itself back to
//! the centre with its own motors while the lab operator holds the pole upright, then the
//! operator lets go at a small random tilt.

use bevy::prelude::*;
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use twinbots_rl::Space;
use twinbots_server::client::Identity;
use twinbots_server::protocol::RobotMessage;
use twinbots_server::robot::{Conversation, Phase, RobotRunState, ServerAddress};
use twinbots_sim::{JointState, Motor, MotorCommand, Operator, PositionSensor, SimSet, SimSettings};

use crate::{CartPoleParts, MAX_CART_X, MAX_POLE_ANGLE, MAX_SCORE, WHEEL_SPEED, drive_wheels};

const WHEEL_RADIUS: f32 = 0.04;

/// The robot's controller: its conversation with the server and what it knows from its own
/// devices. Homing: driving back to x = 0 while the operator holds the pole; starting: the
/// operator has let go.
#[derive(Component)]
pub struct RobotController {
    conversation: Conversation,
    score: f32,
    obs: [f32; 4],
    previous_angle: f32,
    rng: ChaCha8Rng,
    initial_tilt: f32,
}

pub(crate) fn build(app: &mut App) {
    app.init_resource::<RobotRunState>()
        .add_systems(Startup, connect_robots.after(crate::spawn_arenas))
        .add_systems(Update, (home, operate).chain().in_set(SimSet::Actuate))
        .add_systems(Update, (observe, exchange).chain().in_set(SimSet::Task));
}

/// The observation, action spaces and name a pattern-3 cart-pole announces.
pub fn identity() -> Identity {
    Identity {
        robot: "cartpole".into(),
        observation_space: Space::uniform_box(4, f32::NEG_INFINITY, f32::INFINITY),
        action_space: Space::Discrete { n: 2 },
    }
}

/// Each arena's robot connects; its controller's random stream is its arena's.
fn connect_robots(
    mut commands: Commands,
    address: Res<ServerAddress>,
    cartpole: Res<crate::CartPoleConfig>,
    mut state: ResMut<RobotRunState>,
    arenas: Query<(Entity, &twinbots_sim::Arena)>,
) {
    for (entity, arena) in &arenas {
        let Some(conversation) = Conversation::connect_robot(&address, identity(), arena.index, &mut state) else { return };
        let rng = arena.rng.clone();
        commands.entity(entity).insert(RobotController {
            conversation,
            score: 0.0,
            obs: [0.0; 4],
            previous_angle: 0.0,
            rng,
            initial_tilt: cartpole.initial_tilt,
        });
    }
}

/// Encoders and the pole sensor → [x, v, angle, angular rate].
fn observe(
    settings: Res<SimSettings>,
    sensors: Query<&PositionSensor>,
    encoders: Query<&JointState>,
    mut robots: Query<(&CartPoleParts, &mut RobotController)>,
) {
    for (parts, mut robot) in &mut robots {
        let wheels: Vec<&JointState> = parts.wheels.iter().filter_map(|&w| encoders.get(w).ok()).collect();
        let n = wheels.len().max(1) as f32;
        let x = wheels.iter().map(|s| s.position).sum::<f32>() / n * WHEEL_RADIUS;
        let v = wheels.iter().map(|s| s.velocity).sum::<f32>() / n * WHEEL_RADIUS;
        let angle = sensors.get(parts.pole_joint).map_or(0.0, |s| s.value);
        let rate = (angle - robot.previous_angle) / settings.control_dt();
        robot.previous_angle = angle;
        robot.obs = [x, v, angle, rate];
    }
}

/// One request and reply per robot per step; requests go out to all robots before any reply
/// is awaited.
fn exchange(
    mut state: ResMut<RobotRunState>,
    mut robots: Query<(&CartPoleParts, &mut RobotController)>,
    mut motors: Query<&mut Motor>,
) {
    if state.stop.is_some() {
        return;
    }
    for (_, mut robot) in &mut robots {
        let obs = robot.obs.to_vec();
        let message = match robot.conversation.phase {
            Phase::Homing => continue,
            Phase::Starting => {
                robot.score = 0.0;
                RobotMessage::Start { obs }
            }
            Phase::Running => {
                robot.score += 1.0;
                let terminated = obs[2].abs() > MAX_POLE_ANGLE || obs[0].abs() > MAX_CART_X;
                let truncated = !terminated && robot.score > MAX_SCORE;
                RobotMessage::Step { obs, reward: 1.0, terminated, truncated, success: None }
            }
        };
        robot.conversation.send(&message, &mut state);
    }
    for (parts, mut robot) in &mut robots {
        if let Some(action) = robot.conversation.receive(&mut state) {
            drive_wheels(parts, action.first().copied().unwrap_or(0.0), &mut motors);
        }
    }
}

/// Homing with the robot's own motors: a P controller on the odometry drives back to x = 0.
fn home(mut robots: Query<(&CartPoleParts, &mut RobotController)>, mut motors: Query<&mut Motor>) {
    for (parts, mut robot) in &mut robots {
        if robot.conversation.phase != Phase::Homing {
            continue;
        }
        let [x, v, ..] = robot.obs;
        if x.abs() < 0.005 && v.abs() < 0.02 {
            robot.conversation.phase = Phase::Starting;
            continue;
        }
        let speed = (-4.0 * x / WHEEL_RADIUS).clamp(-WHEEL_SPEED, WHEEL_SPEED);
        for wheel in parts.wheels {
            if let Ok(mut m) = motors.get_mut(wheel) {
                m.command = MotorCommand::Velocity(speed);
            }
        }
    }
}

/// The lab operator: holds the pole upright while the robot homes, and lets go at a small
/// random tilt when it is home.
fn operate(mut operator: Operator, mut robots: Query<(&CartPoleParts, &mut RobotController)>) {
    for (parts, mut robot) in &mut robots {
        match robot.conversation.phase {
            Phase::Homing => {
                operator.place_joint(parts.pole_joint, 0.0);
                robot.previous_angle = 0.0;
            }
            Phase::Starting => {
                let tilt = robot.initial_tilt;
                let angle = if tilt > 0.0 { robot.rng.random_range(-tilt..=tilt) } else { 0.0 };
                operator.place_joint(parts.pole_joint, angle);
                robot.previous_angle = angle;
            }
            Phase::Running => {}
        }
    }
}
