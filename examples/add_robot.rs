//! Adding a robot without touching the core crates: a torque-driven pendulum arm ("swing-up").
//! Its URDF, what its controller reads (`SwingState`), its task as terms, a plugin that spawns
//! it and connects its devices, and its description; then PPO on 4 arenas of it. See
//! docs/adding-a-robot.md.
//!
//! Run: `cargo run --release --example add_robot`

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_api::*;
use twinbots_learn::*;
use twinbots_sim::urdf::parse_urdf;
use twinbots_sim::{
    ArenaConfig, Framing, JointState, Motor, MotorCommand, PositionSensor, SimSet, SimSettings, SpawnOptions,
    Supervisor, spawn_robot,
};
use twinbots_task::robot::{RobotDescription, TaskDescription, TrainingDefaults, headless_app};
use twinbots_task::task::{EnvReset, ResetSet, Resetting, TaskSet, spawn_arenas};
use twinbots_task::*;

// 1. The robot: a 1 kg, 0.5 m arm on a motorised hinge 1 m above the ground, torque ≤ 2 N·m.
const URDF: &str = r#"<robot name="swing_arm"><link name="world"/>
  <link name="arm"><inertial><origin xyz="0 0 0.25"/><mass value="1"/>
    <inertia ixx="0.021" ixy="0" ixz="0" iyy="0.021" iyz="0" izz="0.0005"/></inertial>
    <visual><origin xyz="0 0 0.25"/><geometry><box size="0.04 0.04 0.5"/></geometry></visual></link>
  <joint name="shoulder" type="continuous"><parent link="world"/><child link="arm"/>
    <origin xyz="0 0 1"/><axis xyz="0 1 0"/><limit effort="2" velocity="8"/></joint></robot>"#;

// 2. What the controller knows: the arm's angle (θ = 0 upright) and speed from its encoder, the
//    torque it applied, and the start angle the next episode drew.
#[derive(Component, Clone, Copy, Default)]
struct SwingState {
    angle: f32,
    speed: f32,
    torque: f32,
    start: f32,
}

// 3. The task as terms (Gymnasium's Pendulum): observe [cos θ, sin θ, θ̇], pay for angle, speed
//    and torque, 200 steps, start anywhere.
fn swing_up() -> TaskDefinition<SwingState> {
    TaskDefinition {
        name: "swing_arm".into(),
        terms: TaskTerms {
            observations: vec![
                ObservationTerm::scalar("cos_angle", |s: &SwingState| s.angle.cos()).bounded(-1.0, 1.0),
                ObservationTerm::scalar("sin_angle", |s: &SwingState| s.angle.sin()).bounded(-1.0, 1.0),
                ObservationTerm::scalar("speed", |s: &SwingState| s.speed),
            ],
            rewards: vec![
                RewardTerm::new("angle", -1.0, |s: &SwingState| s.angle.sin().atan2(s.angle.cos()).powi(2)),
                RewardTerm::new("speed", -0.1, |s: &SwingState| s.speed * s.speed),
                RewardTerm::new("torque", -0.001, |s: &SwingState| s.torque * s.torque),
            ],
            time_limit: Some(200),
            start_events: vec![StartEvent::new("start_angle", |s: &mut SwingState, rng| {
                s.start = rng.random_range(-3.1..3.1)
            })],
            ..default()
        },
        action_space: Space::Box { low: vec![-2.0], high: vec![2.0] },
        solved: None,
        goal: None,
    }
}

// 4. The plugin: spawn the arm in every arena, apply actions, read the devices, put the drawn
//    start in place at a reset.
#[derive(Component, Clone, Copy)]
struct Shoulder(Entity);
struct SwingArmPlugin;

impl Plugin for SwingArmPlugin {
    fn build(&self, app: &mut App) {
        app.add_plugins(TaskTermsPlugin::new(swing_up(), DesignPattern::Supervised))
            .add_systems(Startup, spawn)
            .add_systems(Update, (act.in_set(SimSet::Actuate), read.in_set(TaskSet::Read)))
            .add_systems(EnvReset, (place.in_set(ResetSet::Place), read.in_set(ResetSet::Read)));
    }
}

fn spawn(mut commands: Commands, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    let model = parse_urdf(URDF, Path::new("swing_arm.urdf"), Path::new(".")).expect("valid URDF");
    spawn_arenas(&mut commands, &config, &settings, |commands, entity, arena| {
        let robot = spawn_robot(commands, entity, arena, &model, SpawnOptions::default());
        (Shoulder(robot.joint("shoulder").expect("the URDF has a shoulder")), SwingState::default())
    });
}

fn act(mut arms: Query<(&Shoulder, &Action, &mut SwingState)>, mut motors: Query<&mut Motor>) {
    for (shoulder, action, mut state) in &mut arms {
        if let (Some(&torque), Ok(mut m)) = (action.0.first(), motors.get_mut(shoulder.0)) {
            m.command = MotorCommand::Torque(torque);
            state.torque = torque;
        }
    }
}

fn read(sensors: Query<(&PositionSensor, &JointState)>, mut arms: Query<(&Shoulder, &mut SwingState)>) {
    for (shoulder, mut state) in &mut arms {
        if let Ok((position, joint)) = sensors.get(shoulder.0) {
            (state.angle, state.speed) = (position.value, joint.velocity);
        }
    }
}

fn place(mut supervisor: Supervisor, arms: Query<(&Shoulder, &SwingState), With<Resetting>>) {
    for (shoulder, state) in &arms {
        supervisor.set_joint_position(shoulder.0, state.start);
    }
}

/// 10 ms physics steps, a control step of five (50 ms).
fn swing_arm_timing() -> SimSettings {
    SimSettings { dt: 0.01, substeps: 5, ..default() }
}

// 5. The description every front reads (one registration line puts it into the CLI's registry).
fn swing_arm() -> RobotDescription {
    RobotDescription {
        name: "swing_arm",
        description: "a torque-driven pendulum arm (swing-up)",
        tasks: vec![TaskDescription {
            name: "swing-up",
            description: "swing up and balance",
            spec: std::sync::Arc::new(|| swing_up().spec()),
            server: false,
            training: None,
            scripted: None,
        }],
        patterns: vec![DesignPattern::Supervised],
        framing: Framing::default(),
        defaults: TrainingDefaults {
            algos: vec![AlgoDefaults {
                hyperparams: "n_steps = 1024\ngamma = 0.9\nlearning_rate = 1e-3\nnormalize_observations = true",
                ..AlgoDefaults::new("ppo")
            }],
            ..Default::default()
        },
        settings: std::sync::Arc::new(swing_arm_timing),
        build: std::sync::Arc::new(|request| headless_app(swing_arm_timing(), request, SwingArmPlugin)),
        rig: None,
        feedback: None,
        cell: None,
    }
}

fn main() -> anyhow::Result<()> {
    let mut registry = Registry::default();
    registry.register(swing_arm())?;
    let robot = registry.find("swing_arm")?;
    let mut env = AppVecEnv::new(robot.app(None, 4, 1, DesignPattern::Supervised)?);
    let mut model =
        Ppo::new(robot.defaults.of("ppo").config()?, env.observation_space().clone(), env.action_space().clone(), 1)?;
    let mut first = None;
    model.learn(&mut env, 120_000, &mut |s: &UpdateStats, _: &dyn twinbots_learn::Agent| {
        first = first.or((s.episodes > 0).then_some(s.mean_reward));
        println!("{:>7} steps  mean episode reward {:>8.1}", s.timesteps, s.mean_reward);
        Ok(Flow::Continue)
    })?;
    println!(
        "swing_arm: first episodes {:.0}, after training {:.0}",
        first.unwrap_or(f32::NAN),
        model.mean_recent_score()
    );
    Ok(())
}
