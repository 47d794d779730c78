//! Design pattern 3 for the cart-pole: no Supervisor anywhere in the app. The robot observes
//! with its own devices only (wheel encoders for position and speed, the pole's position
//! sensor, the angle's change per step for its rate), talks to a RobotServer through its
//! Communicator, and restarts episodes the way a real cell would: it drives itself back to
//! the centre with its own motors while the lab operator holds the pole upright, then the
//! operator lets go at a small random tilt.

use std::net::SocketAddr;
use std::time::Duration;

use bevy::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_rl::Space;
use twinbots_server::client::{Communicator, Identity};
use twinbots_server::protocol::{RobotMessage, ServerMessage};
use twinbots_sim::{ArenaConfig, JointState, Motor, MotorCommand, Operator, PositionSensor, SimSet, SimSettings};

use crate::{CartPoleParts, MAX_CART_X, MAX_POLE_ANGLE, MAX_SCORE, WHEEL_SPEED, drive_wheels};

const WHEEL_RADIUS: f32 = 0.04;

/// Where the RobotServer is, and how long a robot keeps trying to reach it.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ServerAddress {
    pub addr: SocketAddr,
    pub patience: Duration,
}

/// Set when the robots should stop: `Ok(reason)` when the server finished training.
#[derive(Resource, Clone, Debug, Default)]
pub struct RobotRunState {
    pub stop: Option<Result<String, String>>,
    /// Episodes the robots finished, and reconnections they made.
    pub episodes: u64,
    pub reconnects: u32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
enum Mode {
    /// Driving back to x = 0 while the operator holds the pole.
    Homing,
    /// Home: the operator has let go; the next step announces the episode.
    Starting,
    Running,
}

/// The robot's controller: its Communicator and what it knows from its own devices.
#[derive(Component)]
pub struct RobotController {
    communicator: Communicator,
    mode: Mode,
    score: f32,
    obs: [f32; 4],
    previous_angle: f32,
    awaiting_reply: bool,
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

fn connect_robots(
    mut commands: Commands,
    address: Res<ServerAddress>,
    config: Res<ArenaConfig>,
    cartpole: Res<crate::CartPoleConfig>,
    mut state: ResMut<RobotRunState>,
    arenas: Query<(Entity, &twinbots_sim::Arena)>,
) {
    for (entity, arena) in &arenas {
        let mut communicator = Communicator::new(address.addr, identity(), address.patience);
        if let Err(e) = communicator.connect() {
            state.stop = Some(Err(format!("robot {}: {e}", arena.index)));
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        rng.set_stream(arena.index as u64);
        commands.entity(entity).insert(RobotController {
            communicator,
            mode: Mode::Homing,
            score: 0.0,
            obs: [0.0; 4],
            previous_angle: 0.0,
            awaiting_reply: false,
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
        let message = match robot.mode {
            Mode::Homing => continue,
            Mode::Starting => RobotMessage::Start { obs },
            Mode::Running => {
                robot.score += 1.0;
                let terminated = obs[2].abs() > MAX_POLE_ANGLE || obs[0].abs() > MAX_CART_X;
                let truncated = !terminated && robot.score > MAX_SCORE;
                RobotMessage::Step { obs, reward: 1.0, terminated, truncated }
            }
        };
        robot.awaiting_reply = robot.communicator.send(&message).is_ok();
        if !robot.awaiting_reply {
            lost(&mut robot, &mut state);
        }
    }
    for (parts, mut robot) in &mut robots {
        if !std::mem::take(&mut robot.awaiting_reply) {
            continue;
        }
        match robot.communicator.receive() {
            Ok(ServerMessage::Action { action }) => {
                if robot.mode == Mode::Starting {
                    robot.mode = Mode::Running;
                    robot.score = 0.0;
                }
                drive_wheels(parts, action.first().copied().unwrap_or(0.0), &mut motors);
            }
            Ok(ServerMessage::Ack) => {
                state.episodes += 1;
                robot.mode = Mode::Homing;
            }
            Ok(ServerMessage::Done { reason }) => state.stop = Some(Ok(reason)),
            Ok(ServerMessage::Error { message, fatal: true }) => state.stop = Some(Err(message)),
            Ok(ServerMessage::Error { message, .. }) => warn!("server: {message}"),
            Ok(ServerMessage::Welcome { .. }) => {}
            Err(_) => lost(&mut robot, &mut state),
        }
    }
}

/// The server went away: reconnect (with backoff) and begin a fresh episode from home.
fn lost(robot: &mut RobotController, state: &mut RobotRunState) {
    robot.mode = Mode::Homing;
    match robot.communicator.connect() {
        Ok(()) => state.reconnects += 1,
        Err(e) => state.stop = Some(Err(e.to_string())),
    }
}

/// Homing with the robot's own motors: a P controller on the odometry drives back to x = 0.
fn home(mut robots: Query<(&CartPoleParts, &mut RobotController)>, mut motors: Query<&mut Motor>) {
    for (parts, mut robot) in &mut robots {
        if robot.mode != Mode::Homing {
            continue;
        }
        let [x, v, ..] = robot.obs;
        if x.abs() < 0.005 && v.abs() < 0.02 {
            robot.mode = Mode::Starting;
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
        match robot.mode {
            Mode::Homing => {
                operator.place_joint(parts.pole_joint, 0.0);
                robot.previous_angle = 0.0;
            }
            Mode::Starting => {
                let tilt = robot.initial_tilt;
                let angle = if tilt > 0.0 { robot.rng.random_range(-tilt..=tilt) } else { 0.0 };
                operator.place_joint(parts.pole_joint, angle);
                robot.previous_angle = angle;
            }
            Mode::Running => {}
        }
    }
}
