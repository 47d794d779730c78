//! The Pioneer 3-AT with an inverted pendulum (paper §5): a skid-steer base on four motorised
//! wheels with encoders, a ring of 16 sonars, and a passive pendulum with a position sensor.
//! Task: one wheel speed for all wheels, Box([-6.4], [6.4]) rad/s; observation x, vx, pole
//! angle, pole rate; reward 1 − 2|θ| − |x|/10; terminated at |θ| > 0.3 rad or |x| > 5 m;
//! truncated after 600 steps; each episode starts with a random kick (all wheels at ±2.0…2.5
//! rad/s for 5 control steps) so episodes start from varied angles. Design pattern 1.

use std::path::Path;

use std::borrow::Cow;
use std::sync::Arc;

use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ArenaConfig, DistanceSensor, Framing, InArena, Motor, MotorCommand, Mount, PositionSensor, SimSet,
    SimSettings, SpawnOptions, SpawnedRobot, Supervisor, spawn_robot,
};
use twinbots_task::robot::{
    AlgoDefaults, JointExcitation, RigDescription, RobotDescription, TaskDescription, TrainingDefaults, headless_app,
};
use twinbots_task::task::{EnvReset, ResetSet, TaskSet, spawn_arenas};
use twinbots_task::{
    Action, DesignPattern, ObservationTerm, RewardTerm, SolvedCriterion, Space, StartEvent, TaskDefinition, TaskSpec,
    TaskTerms, TaskTermsPlugin, TerminationTerm,
};

pub const URDF: &str = include_str!("../../../../assets/robots/pioneer3at/pioneer3at.urdf");
pub const URDF_PATH: &str = "assets/robots/pioneer3at/pioneer3at.urdf";
/// Max wheel speed (rad/s).
pub const MAX_WHEEL_SPEED: f32 = 6.4;
pub const WHEEL_RADIUS: f32 = 0.11;
/// Axle height: the base link's origin above the ground.
pub const AXLE_HEIGHT: f32 = 0.11;
pub const MAX_ANGLE: f32 = 0.3;
pub const MAX_X: f32 = 5.0;
pub const EPISODE_STEPS: u32 = 600;
/// The start kick: this many control steps…
pub const KICK_STEPS: u32 = 5;
/// …at a wheel speed of this size (rad/s), either way.
pub const KICK_SPEED: [f32; 2] = [2.0, 2.5];
/// Bearings (deg) of the 16 sonars, front ring then rear ring, as on the real robot.
pub const SONAR_BEARINGS: [f32; 16] =
    [90.0, 50.0, 30.0, 10.0, -10.0, -30.0, -50.0, -90.0, -90.0, -130.0, -150.0, -170.0, 170.0, 150.0, 130.0, 90.0];
pub const SONAR_RANGE: f32 = 5.0;

/// 64 ms control steps of 8 × 8 ms physics steps.
pub fn sim_settings() -> SimSettings {
    SimSettings { dt: 0.008, substeps: 8, ..default() }
}

pub fn model() -> RobotModel {
    parse_urdf(URDF, Path::new(URDF_PATH), Path::new("assets/robots/pioneer3at"))
        .expect("the built-in Pioneer 3-AT URDF is valid (checked by the tests)")
}

/// What the Pioneer's controller knows at a step, and the start kick it is giving.
#[derive(Component, Clone, Copy, Debug, Default, PartialEq)]
pub struct PioneerState {
    /// Base position (m) and velocity (m/s) along its driving direction.
    pub x: f32,
    pub vx: f32,
    /// Pendulum angle (rad) and rate (rad/s).
    pub angle: f32,
    pub rate: f32,
    /// Control steps of the start kick left, and its wheel speed (rad/s).
    pub kick_steps: u32,
    pub kick_speed: f32,
}

/// The paper's pendulum task: reward 1 − 2|θ| − |x|/10; terminated at |θ| > 0.3 rad or
/// |x| > 5 m; truncated after 600 steps; every episode begins with a random kick (all wheels at
/// ±2.0…2.5 rad/s for 5 control steps) so episodes start from varied angles.
pub fn balance_task() -> TaskDefinition<PioneerState> {
    TaskDefinition {
        name: "pioneer3at".into(),
        terms: TaskTerms {
            observations: vec![
                // Plausible: far beyond the episode's ±5 m and 0.3 rad and the base's top speed.
                ObservationTerm::scalar("base_x", |s: &PioneerState| s.x).plausible(-50.0, 50.0),
                ObservationTerm::scalar("base_velocity", |s: &PioneerState| s.vx).plausible(-10.0, 10.0),
                ObservationTerm::scalar("pole_angle", |s: &PioneerState| s.angle)
                    .plausible(-std::f32::consts::PI, std::f32::consts::PI),
                ObservationTerm::scalar("pole_rate", |s: &PioneerState| s.rate).plausible(-100.0, 100.0),
            ],
            rewards: vec![
                RewardTerm::new("alive", 1.0, |_| 1.0).bounded(1.0, 1.0),
                // Both end the episode long before their bounds (0.3 rad, 5 m): the bounds only
                // give the reward a declared range.
                RewardTerm::new("pole_angle", -2.0, |s: &PioneerState| s.angle.abs())
                    .bounded(0.0, std::f32::consts::PI),
                RewardTerm::new("distance", -0.1, |s: &PioneerState| s.x.abs()).bounded(0.0, 2.0 * MAX_X),
            ],
            terminations: vec![
                TerminationTerm::new("pole_fallen", |s: &PioneerState| s.angle.abs() > MAX_ANGLE),
                TerminationTerm::new("out_of_range", |s: &PioneerState| s.x.abs() > MAX_X),
            ],
            time_limit: Some(EPISODE_STEPS),
            start_events: vec![StartEvent::new("kick", |s: &mut PioneerState, rng| {
                let speed = rng.random_range(KICK_SPEED[0]..=KICK_SPEED[1]);
                let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
                (s.kick_steps, s.kick_speed) = (KICK_STEPS, sign * speed);
            })],
        },
        action_space: Space::Box { low: vec![-MAX_WHEEL_SPEED], high: vec![MAX_WHEEL_SPEED] },
        // The paper's figure: ≈500 mean episode reward (it needed 32 M steps).
        solved: Some(SolvedCriterion::mean_score(100, 500.0)),
        goal: None,
    }
}

pub fn task_spec() -> TaskSpec {
    balance_task().spec()
}

/// The classical controller: a linear-quadratic regulator of the pendulum on a base whose
/// acceleration it chooses (gains from the linearised pendulum, hinge to ball's effective length
/// 0.96 m, at the 64 ms control step), turned into the wheel speed that reaches that
/// acceleration within one control step, clipped to the wheels' ±6.4 rad/s. Studies set learnt
/// policies beside it.
pub fn feedback(obs: &[f32]) -> Vec<f32> {
    let [x, v, angle, rate] = [obs[0], obs[1], obs[2], obs[3]];
    let [kx, kv, ka, kr] = FEEDBACK_GAINS;
    let acceleration = kx * x + kv * v + ka * angle + kr * rate;
    let speed = (v + 0.064 * acceleration) / WHEEL_RADIUS;
    vec![speed.clamp(-MAX_WHEEL_SPEED, MAX_WHEEL_SPEED)]
}

/// [`feedback`]'s gains (m/s² of base acceleration per m, m/s, rad and rad/s): discrete LQR with
/// state weights (1, 1, 20, 1) and control weight 0.5.
const FEEDBACK_GAINS: [f32; 4] = [1.07, 2.41, 31.2, 9.73];

/// How the Pioneer describes itself to the registry.
pub fn robot() -> RobotDescription {
    RobotDescription {
        name: "pioneer3at",
        description: "Pioneer 3-AT skid-steer base, 16 sonars, inverted pendulum; Box([-6.4],[6.4]) wheel speed, 64 ms step",
        tasks: vec![TaskDescription {
            name: "balance",
            description: "balance the pendulum on the driving base",
            spec: Arc::new(task_spec),
            server: false,
            training: None,
            scripted: None,
        }],
        patterns: vec![DesignPattern::Supervised],
        framing: Framing::default(),
        // SB3's defaults with observation normalisation (a continuous-control task).
        defaults: TrainingDefaults {
            algos: vec![AlgoDefaults {
                hyperparams: "normalize_observations = true\nn_steps = 512",
                ..AlgoDefaults::new("ppo")
            }],
            ..default()
        },
        settings: Arc::new(sim_settings),
        build: Arc::new(|request| headless_app(sim_settings(), request, Pioneer3atPlugin)),
        rig: Some(rig()),
        feedback: Some(Arc::new(feedback)),
        cell: None,
    }
}

/// The twin's nominal joint dynamics (a calibration file's format).
pub const PARAMETERS: &str = include_str!("../../../../assets/robots/pioneer3at/parameters.toml");
/// Where a calibration starts.
pub const PRIOR: &str = include_str!("../../../../assets/robots/pioneer3at/prior.toml");

/// The Pioneer on its test stand: on the ground, its wheels driven by speed, the pendulum free.
/// Logs command the wheels every physics step.
pub fn rig() -> RigDescription {
    const WHEELS: [JointExcitation; 4] = [
        JointExcitation { channel: 0, joint: Cow::Borrowed("front_left_wheel_joint"), speed: 3.0, travel: 20.0 },
        JointExcitation { channel: 0, joint: Cow::Borrowed("front_right_wheel_joint"), speed: 3.0, travel: 20.0 },
        JointExcitation { channel: 0, joint: Cow::Borrowed("back_left_wheel_joint"), speed: 3.0, travel: 20.0 },
        JointExcitation { channel: 0, joint: Cow::Borrowed("back_right_wheel_joint"), speed: 3.0, travel: 20.0 },
    ];
    RigDescription {
        model: Arc::new(model),
        settings: sim_settings(),
        nominal: PARAMETERS.into(),
        prior: PRIOR.into(),
        fit: ["pendulum_joint.damping", "pendulum_joint.friction", "command_delay"].map(String::from).to_vec(),
        spawn: Arc::new(spawn_rig),
        excitation: WHEELS.to_vec(),
        command_steps: 1,
    }
}

fn spawn_rig(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut Arena,
    joint_positions: &[(String, f32)],
) -> SpawnedRobot {
    arena.add_ground(1.0);
    let base = Pose::from_translation(Vec3::new(0.0, 0.0, AXLE_HEIGHT));
    spawn_robot(
        commands,
        arena_entity,
        arena,
        &model(),
        SpawnOptions { base, joint_positions: joint_positions.to_vec(), ..default() },
    )
}

/// A headless app of the pendulum task (design pattern 1).
pub fn headless_app_with(arenas: usize, seed: u64, pattern: DesignPattern) -> App {
    (robot().build)(&twinbots_task::AppRequest { task: "balance", arenas, seed, pattern })
}

/// The entities of an arena's Pioneer, on the arena entity.
#[derive(Component, Clone, Debug)]
pub struct PioneerParts {
    pub base: Entity,
    pub pole_link: Entity,
    pub pendulum: Entity,
    /// front-left, front-right, back-left, back-right.
    pub wheels: [Entity; 4],
    pub sonars: Vec<Entity>,
}

#[derive(Resource, Clone)]
struct PioneerModel(RobotModel);

pub struct Pioneer3atPlugin;

impl Plugin for Pioneer3atPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(PioneerModel(model()))
            .insert_resource(rig().nominal_parameters())
            .add_plugins(TaskTermsPlugin::new(balance_task(), DesignPattern::Supervised))
            .add_systems(Startup, spawn_pioneers)
            .add_systems(Update, (apply_action.in_set(SimSet::Actuate), read_supervised.in_set(TaskSet::Read)))
            .add_systems(EnvReset, read_supervised.in_set(ResetSet::Read));
    }
}

/// Where sonar `i` sits on the base link: on the body's edge, facing its bearing.
pub fn sonar_offset(i: usize) -> Pose {
    let a = SONAR_BEARINGS[i].to_radians();
    let x = if i < 8 { 0.2 } else { -0.2 } + 0.05 * a.cos();
    Pose::from_parts(Vec3::new(x, 0.14 * a.sin(), 0.05), Quat::from_rotation_z(a))
}

/// Spawns one Pioneer with its sonar ring into an arena; returns its parts.
pub fn spawn_pioneer(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut Arena,
    model: &RobotModel,
    base: Pose,
) -> PioneerParts {
    let robot = spawn_robot(commands, arena_entity, arena, model, SpawnOptions { base, ..default() });
    let get = |found: Option<Entity>, name: &str| found.unwrap_or_else(|| panic!("Pioneer URDF has no '{name}'"));
    let base_link = get(robot.link("base_link"), "base_link");
    let sonars = (0..SONAR_BEARINGS.len())
        .map(|i| {
            let mount = Mount { link: base_link, offset: sonar_offset(i) };
            commands.spawn((DistanceSensor::linear(SONAR_RANGE), mount, InArena(arena_entity))).id()
        })
        .collect();
    PioneerParts {
        base: base_link,
        pole_link: get(robot.link("pole"), "pole"),
        pendulum: get(robot.joint("pendulum_joint"), "pendulum_joint"),
        wheels: ["front_left", "front_right", "back_left", "back_right"]
            .map(|w| get(robot.joint(&format!("{w}_wheel_joint")), w)),
        sonars,
    }
}

fn spawn_pioneers(
    mut commands: Commands,
    model: Res<PioneerModel>,
    config: Res<ArenaConfig>,
    settings: Res<SimSettings>,
) {
    spawn_arenas(&mut commands, &config, &settings, |commands, arena_entity, arena| {
        arena.add_ground(1.0);
        let base = Pose::from_translation(Vec3::new(0.0, 0.0, AXLE_HEIGHT));
        (spawn_pioneer(commands, arena_entity, arena, &model.0, base), PioneerState::default())
    });
}

/// Drives all four wheels at one speed (rad/s).
pub fn drive(parts: &PioneerParts, speeds: [f32; 4], motors: &mut Query<&mut Motor>) {
    for (wheel, speed) in parts.wheels.iter().zip(speeds) {
        if let Ok(mut m) = motors.get_mut(*wheel) {
            m.command = MotorCommand::Velocity(speed.clamp(-MAX_WHEEL_SPEED, MAX_WHEEL_SPEED));
        }
    }
}

/// The start kick's speed while it lasts, the action after.
fn apply_action(mut arenas: Query<(&PioneerParts, &Action, &mut PioneerState)>, mut motors: Query<&mut Motor>) {
    for (parts, action, mut state) in &mut arenas {
        let speed = if state.kick_steps > 0 {
            state.kick_steps -= 1;
            state.kick_speed
        } else if let Some(&a) = action.0.first() {
            a
        } else {
            continue;
        };
        drive(parts, [speed; 4], &mut motors);
    }
}

/// The base's x and velocity and the pole's rate from the Supervisor, the angle from the
/// pendulum's position sensor.
fn read_supervised(
    supervisor: Supervisor,
    sensors: Query<&PositionSensor>,
    mut arenas: Query<(&PioneerParts, &mut PioneerState)>,
) {
    for (parts, mut state) in &mut arenas {
        let (Some(base), Some(pole)) = (supervisor.link_state(parts.base), supervisor.link_state(parts.pole_link))
        else {
            continue;
        };
        state.x = base.pose.translation.x;
        state.vx = base.linvel.x;
        state.angle = sensors.get(parts.pendulum).map_or(0.0, |s| s.value);
        state.rate = pole.angvel.y;
    }
}
