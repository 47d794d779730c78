//! Design pattern 3 for the UR5e: no Supervisor anywhere in the app. The controller knows the
//! arm from its encoders and its own kinematics, takes reach targets from the cell's work
//! orders (its own random stream), and talks to a RobotServer through its Communicator.
//! Episodes restart the way a real cell's do: the arm homes with its own motors (position
//! control back to home), and if the part has been knocked out of fixture A, the lab operator
//! puts it back before the next episode starts.

use bevy::prelude::*;
use rand_chacha::ChaCha8Rng;
use twinbots_server::client::Identity;
use twinbots_server::protocol::RobotMessage;
use twinbots_server::robot::{Conversation, Phase, RobotRunState, ServerAddress};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::{Arena, ArenaConfig, JointState, Motor, Operator, OperatorAccess, PositionSensor, SimPlugin, SimSet, SimSettings};

use crate::arm::{self, ActionHistory, ArmState};
use crate::cell::{self, CellModels, CellParts, FIXTURE_A, part_seat};
use crate::kinematics::HOME;
use crate::reach::{EPISODE_STEPS, sample_target};

/// The operator re-seats the part when it is this far from its seat (m).
const PART_OUT_OF_PLACE: f32 = 0.005;

/// What a pattern-3 UR5e announces to the server.
pub fn identity() -> Identity {
    let spec = crate::task_spec();
    Identity { robot: "ur5e".into(), observation_space: spec.observation_space, action_space: spec.action_space }
}

/// A pattern-3 robot process: `arenas` cells, each arm with a Communicator to `server`.
pub fn robot_app(arenas: usize, seed: u64, server: ServerAddress) -> App {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { settings: crate::sim_settings(), supervisor: false })
        .insert_resource(OperatorAccess)
        .insert_resource(ArenaConfig { count: arenas, seed })
        .insert_resource(server)
        .init_resource::<RobotRunState>()
        .init_resource::<CellModels>()
        .add_systems(Startup, (build_cells, connect_robots).chain())
        .add_systems(Update, (home, operate).chain().in_set(SimSet::Actuate))
        .add_systems(Update, (observe, exchange).chain().in_set(SimSet::Task));
    app
}

/// The arm's controller: its conversation with the server, what its encoders say, and the
/// reach it is on.
#[derive(Component)]
pub struct RobotController {
    conversation: Conversation,
    /// The arm as last read; `None` until the first reading (the controller does not guess).
    pub arm: Option<ArmState>,
    pub target: Vec3,
    steps: u32,
    actions: ActionHistory,
    rng: ChaCha8Rng,
}

impl RobotController {
    pub fn phase(&self) -> Phase {
        self.conversation.phase
    }
}

fn build_cells(mut commands: Commands, models: Res<CellModels>, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    cell::spawn_cells(&mut commands, &models, &config, &settings);
}

/// Each arena's robot connects; its controller's random stream is its arena's.
fn connect_robots(mut commands: Commands, address: Res<ServerAddress>, mut state: ResMut<RobotRunState>, arenas: Query<(Entity, &Arena)>) {
    for (entity, arena) in &arenas {
        let Some(conversation) = Conversation::connect_robot(&address, identity(), arena.index, &mut state) else { return };
        let rng = arena.rng.clone();
        commands.entity(entity).insert(RobotController {
            conversation,
            arm: None,
            target: Vec3::ZERO,
            steps: 0,
            actions: ActionHistory::default(),
            rng,
        });
    }
}

fn observe(sensors: Query<(&PositionSensor, &JointState)>, mut robots: Query<(&CellParts, &mut RobotController)>) {
    for (parts, mut robot) in &mut robots {
        robot.arm = Some(ArmState::read(parts, &sensors));
    }
}

/// One request and reply per robot per step, all requests out before any reply is awaited.
fn exchange(mut state: ResMut<RobotRunState>, mut robots: Query<(&CellParts, &mut RobotController)>, mut motors: Query<&mut Motor>) {
    if state.stop.is_some() {
        return;
    }
    for (_, mut robot) in &mut robots {
        let robot = &mut *robot;
        let Some(arm) = &robot.arm else { continue };
        let mut obs = Vec::new();
        let message = match robot.conversation.phase {
            Phase::Homing => continue,
            Phase::Starting => {
                robot.steps = 0;
                robot.actions = ActionHistory::default();
                robot.target = sample_target(&mut robot.rng);
                arm.observation(robot.target, &robot.actions, &mut obs);
                RobotMessage::Start { obs }
            }
            Phase::Running => {
                robot.steps += 1;
                let arrived = arm.has_reached(robot.target);
                let truncated = !arrived && robot.steps >= EPISODE_STEPS;
                arm.observation(robot.target, &robot.actions, &mut obs);
                let reward = arm::reach_reward(arm, robot.target, &robot.actions, arrived);
                let success = (arrived || truncated).then_some(arrived);
                RobotMessage::Step { obs, reward, terminated: arrived, truncated, success }
            }
        };
        robot.conversation.send(&message, &mut state);
    }
    for (parts, mut robot) in &mut robots {
        if let Some(action) = robot.conversation.receive(&mut state) {
            arm::drive(parts, arm::joint_speeds(&action), &mut motors);
            robot.actions.push(&action);
        }
    }
}

/// Homing with the arm's own motors: position control back to home; once there, the next
/// step starts an episode.
fn home(mut robots: Query<(&CellParts, &mut RobotController)>, mut motors: Query<&mut Motor>) {
    for (parts, mut robot) in &mut robots {
        if robot.conversation.phase != Phase::Homing || robot.arm.is_none() {
            continue;
        }
        if robot.arm.as_ref().is_some_and(ArmState::is_home) {
            robot.conversation.phase = Phase::Starting;
            arm::drive(parts, [0.0; 6], &mut motors);
        } else {
            arm::drive_to(parts, HOME, &mut motors);
        }
    }
}

/// The lab operator: when an episode is about to start and the part is out of fixture A, puts
/// it back.
fn operate(mut operator: Operator, robots: Query<(&CellParts, &RobotController)>) {
    for (parts, robot) in &robots {
        if robot.conversation.phase != Phase::Starting {
            continue;
        }
        let seat = parts.base * Pose::from_translation(part_seat(FIXTURE_A));
        let out_of_place = operator.object_pose(parts.part).is_none_or(|p| {
            (p.translation - seat.translation).length() > PART_OUT_OF_PLACE || p.rotation.angle_between(seat.rotation) > 0.05
        });
        if out_of_place {
            operator.place_object(parts.part, seat);
        }
    }
}
