//! A robot defined only in this file — URDF, controller state, task terms, plugin, description
//! — is registered, trained for a few updates, evaluated, and served under design pattern 3,
//! without any other crate knowing it.

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_api::*;
use twinbots_learn::*;
use twinbots_link::robot::{AtHome, Controller, Phase, RobotCycleSet, ServerRobotPlugin};
use twinbots_server::server::{RobotServer, ServerSettings};
use twinbots_sim::urdf::parse_urdf;
use twinbots_sim::{
    ArenaConfig, Framing, JointState, Motor, MotorCommand, PositionSensor, SimSet, SimSettings, SpawnOptions,
    Supervisor, spawn_robot,
};
use twinbots_task::robot::{RobotDescription, TaskDescription, TrainingDefaults, headless_app};
use twinbots_task::task::{EnvReset, ResetSet, Resetting, TaskSet, spawn_arenas};
use twinbots_task::*;

/// A motorised turntable: a 2 kg plate on a vertical hinge, speed ≤ 2 rad/s.
const URDF: &str = r#"<robot name="turntable">
  <link name="world"/>
  <link name="plate">
    <inertial><mass value="2"/><inertia ixx="0.02" ixy="0" ixz="0" iyy="0.02" iyz="0" izz="0.04"/></inertial>
    <visual><geometry><cylinder radius="0.2" length="0.02"/></geometry></visual>
  </link>
  <joint name="spin" type="revolute">
    <parent link="world"/><child link="plate"/><origin xyz="0 0 0.5"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="5" velocity="2"/>
  </joint>
</robot>"#;

const MAX_SPEED: f32 = 2.0;

/// What the turntable's controller knows: its encoder, its command, its drawn start.
#[derive(Component, Clone, Copy, Debug, Default)]
struct TableState {
    angle: f32,
    speed: f32,
    target: f32,
    start: f32,
}

fn on_target(s: &TableState) -> bool {
    (s.target - s.angle).abs() < 0.05 && s.speed.abs() < 0.1
}

/// Turn to a target angle and stop there.
fn turn_task() -> TaskDefinition<TableState> {
    TaskDefinition {
        name: "turntable".into(),
        terms: TaskTerms {
            observations: vec![
                ObservationTerm::scalar("angle", |s: &TableState| s.angle).bounded(-3.0, 3.0),
                ObservationTerm::scalar("speed", |s: &TableState| s.speed),
                ObservationTerm::scalar("target_offset", |s: &TableState| s.target - s.angle),
            ],
            rewards: vec![
                RewardTerm::new("error", -1.0, |s: &TableState| (s.target - s.angle).abs()),
                RewardTerm::new("arrival", 5.0, |s: &TableState| f32::from(u8::from(on_target(s)))),
            ],
            terminations: vec![TerminationTerm::goal("on_target", on_target)],
            time_limit: Some(50),
            start_events: vec![StartEvent::new("target", |s: &mut TableState, rng| {
                s.target = rng.random_range(-1.5..1.5);
                s.start = rng.random_range(-0.3..0.3);
            })],
        },
        action_space: Space::Box { low: vec![-1.0], high: vec![1.0] },
        solved: Some(SolvedCriterion::success_rate(20, 0.9)),
        goal: None,
    }
}

#[derive(Component, Clone, Copy)]
struct Spin(Entity);

struct TurntablePlugin(DesignPattern);

impl Plugin for TurntablePlugin {
    fn build(&self, app: &mut App) {
        app.add_plugins(TaskTermsPlugin::new(turn_task(), self.0))
            .add_systems(Startup, spawn)
            .add_systems(Update, (act.in_set(SimSet::Actuate), read.in_set(TaskSet::Read)));
        if self.0 == DesignPattern::Server {
            app.add_plugins(ServerRobotPlugin::<TableState>::new("turntable"))
                .add_systems(Update, home.in_set(RobotCycleSet::Home));
        } else {
            app.add_systems(EnvReset, (place.in_set(ResetSet::Place), read.in_set(ResetSet::Read)));
        }
    }
}

fn spawn(mut commands: Commands, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    let model = parse_urdf(URDF, Path::new("turntable.urdf"), Path::new(".")).unwrap();
    spawn_arenas(&mut commands, &config, &settings, |commands, entity, arena| {
        let robot = spawn_robot(commands, entity, arena, &model, SpawnOptions::default());
        (Spin(robot.joint("spin").unwrap()), TableState::default())
    });
}

fn act(tables: Query<(&Spin, &Action)>, mut motors: Query<&mut Motor>) {
    for (spin, action) in &tables {
        if let (Some(&a), Ok(mut m)) = (action.0.first(), motors.get_mut(spin.0)) {
            m.command = MotorCommand::Velocity(a.clamp(-1.0, 1.0) * MAX_SPEED);
        }
    }
}

fn read(sensors: Query<(&PositionSensor, &JointState)>, mut tables: Query<(&Spin, &mut TableState)>) {
    for (spin, mut state) in &mut tables {
        let (position, joint) = sensors.get(spin.0).unwrap();
        (state.angle, state.speed) = (position.value, joint.velocity);
    }
}

fn place(mut supervisor: Supervisor, tables: Query<(&Spin, &TableState), With<Resetting>>) {
    for (spin, state) in &tables {
        supervisor.set_joint_position(spin.0, state.start);
    }
}

/// Pattern 3: back to 0 with its own motor.
fn home(mut tables: Query<(&Spin, &TableState, &Controller, &mut AtHome)>, mut motors: Query<&mut Motor>) {
    for (spin, state, controller, mut at_home) in &mut tables {
        if controller.phase() == Phase::Homing {
            at_home.0 = state.angle.abs() < 0.02 && state.speed.abs() < 0.05;
            motors.get_mut(spin.0).unwrap().command = MotorCommand::Position(0.0);
        }
    }
}

fn turntable_timing() -> SimSettings {
    SimSettings { dt: 0.01, substeps: 4, ..default() }
}

fn turntable() -> RobotDescription {
    RobotDescription {
        name: "turntable",
        description: "a motorised turntable (test robot)",
        tasks: vec![TaskDescription {
            name: "turn",
            description: "turn to a target angle",
            spec: std::sync::Arc::new(|| turn_task().spec()),
            server: true,
            training: None,
            scripted: None,
        }],
        patterns: vec![DesignPattern::Supervised],
        framing: Framing::default(),
        defaults: TrainingDefaults {
            algos: vec![AlgoDefaults {
                arenas: 4,
                hyperparams: "n_steps = 128\nbatch_size = 64",
                ..AlgoDefaults::new("ppo")
            }],
            ..Default::default()
        },
        settings: std::sync::Arc::new(turntable_timing),
        build: std::sync::Arc::new(|request| {
            headless_app(turntable_timing(), request, TurntablePlugin(request.pattern))
        }),
        rig: None,
        feedback: None,
        cell: None,
    }
}

#[test]
fn a_robot_defined_in_a_test_file_is_registered_trained_evaluated_and_served() {
    let mut registry = Registry::default();
    registry.register(cartpole::robot()).unwrap();
    registry.register(turntable()).unwrap();
    assert!(registry.register(turntable()).is_err(), "a name is registered once");
    let robot = registry.find("turntable").unwrap();
    let spec = robot.task();
    assert_eq!(spec.observation_names, ["angle", "speed", "target_offset"]);
    assert_eq!(spec.reward_terms, ["error", "arrival"]);
    assert!(robot.app(None, 1, 0, DesignPattern::Radio).unwrap_err().to_string().contains("supported: 1, 3"));

    // Trained for a few updates.
    let mut env =
        AppVecEnv::new(robot.app(None, robot.defaults.of("ppo").arenas, 0, DesignPattern::Supervised).unwrap());
    let mut model = Ppo::new(
        robot.defaults.of("ppo").config().unwrap(),
        spec.observation_space.clone(),
        spec.action_space.clone(),
        0,
    )
    .unwrap();
    model
        .learn(&mut env, 4 * 128 * 4, &mut |_: &UpdateStats, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue))
        .unwrap();
    assert_eq!(model.state.updates, 4);
    assert!(model.state.episodes > 0, "episodes of at most 50 steps ended in 2048 steps");

    // Evaluated by the project's evaluation: score, success rate, and the score divided among
    // the reward terms.
    let mut eval = AppVecEnv::new(robot.app(None, 2, 7, DesignPattern::Supervised).unwrap());
    let result = evaluate_policy("turn", &model, &mut eval, 6, 7).unwrap();
    assert_eq!(result.episodes, 6);
    assert!(result.success_rate.is_some_and(|r| (0.0..=1.0).contains(&r)), "a goal task reports success");
    let terms: f32 = result.rewards.values().sum();
    assert_eq!(result.rewards.len(), 2, "{:?}", result.rewards);
    assert!(
        (terms - result.mean_score).abs() < 1e-3 * result.mean_score.abs().max(1.0),
        "{:?} vs {}",
        result.rewards,
        result.mean_score
    );

    // Served under pattern 3: robots that home themselves, no Supervisor, the same terms.
    let learner = Box::new(
        Ppo::new(
            robot.defaults.of("ppo").config().unwrap(),
            spec.observation_space.clone(),
            spec.action_space.clone(),
            1,
        )
        .unwrap(),
    );
    let settings = ServerSettings::new("turntable", &spec, 2, 1024);
    let updates = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counted = updates.clone();
    let count = move |_: &_, _: &dyn twinbots_learn::Agent| {
        counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        Ok(Flow::Continue)
    };
    let server = RobotServer::start("127.0.0.1:0".parse().unwrap(), learner, settings, Box::new(count)).unwrap();
    let mut app = crate::server::robots_against(robot, server.addr);
    let run = crate::server::run_robots_until_done(&mut app, 20_000);
    assert!(run.episodes > 0);
    let (served, _) = server.wait().unwrap();
    let updates = updates.load(std::sync::atomic::Ordering::Relaxed);
    assert!(served.timesteps() >= 1024 && updates >= 4, "{} steps, {updates} updates", served.timesteps());
}
