//! The Pioneer 3-AT with an inverted pendulum (paper §5): a skid-steer base on four motorised
//! wheels with encoders, a ring of 16 sonars, and a passive pendulum with a position sensor.
//! Task: one wheel speed for all wheels, Box([-6.4], [6.4]) rad/s; observation x, vx, pole
//! angle, pole rate; reward 1 − 2|θ| − |x|/10; terminated at |θ| > 0.3 rad or |x| > 5 m;
//! truncated after 600 steps; each episode starts with a random kick (all wheels at ±2.0…2.5
//! rad/s for 5 control steps) so episodes start from varied angles. Design pattern 1.

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_rl::task::{EnvReset, ResetSet, TaskSet};
use twinbots_rl::{Action, DesignPattern, Episode, PpoConfig, SolvedCriterion, Space, TaskPlugin, TaskSpec};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ArenaConfig, DistanceSensor, InArena, Motor, MotorCommand, Mount, PositionSensor, SimPlugin, SimSet,
    SimSettings, SpawnOptions, Supervisor, spawn_robot,
};

pub const URDF: &str = include_str!("../../../assets/robots/pioneer3at/pioneer3at.urdf");
pub const URDF_PATH: &str = "assets/robots/pioneer3at/pioneer3at.urdf";
/// Max wheel speed (rad/s).
pub const MAX_WHEEL_SPEED: f32 = 6.4;
pub const WHEEL_RADIUS: f32 = 0.11;
/// Axle height: the base link's origin above the ground.
pub const AXLE_HEIGHT: f32 = 0.11;
pub const MAX_ANGLE: f32 = 0.3;
pub const MAX_X: f32 = 5.0;
pub const EPISODE_STEPS: u32 = 600;
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

/// PPO settings: SB3's defaults with observation normalisation (a continuous-control task).
pub fn ppo_config() -> PpoConfig {
    PpoConfig { normalize_observations: true, n_steps: 512, ..Default::default() }
}

pub fn task_spec() -> TaskSpec {
    TaskSpec {
        name: "pioneer3at".into(),
        observation_space: Space::uniform_box(4, f32::NEG_INFINITY, f32::INFINITY),
        action_space: Space::Box { low: vec![-MAX_WHEEL_SPEED], high: vec![MAX_WHEEL_SPEED] },
        // The paper's figure: ≈500 mean episode reward (it needed 32 M steps).
        solved: Some(SolvedCriterion::mean_score(100, 500.0)),
    }
}

pub fn headless_app_with(arenas: usize, seed: u64, _pattern: DesignPattern) -> App {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { settings: sim_settings(), ..default() })
        .insert_resource(ArenaConfig { count: arenas, seed })
        .add_plugins(Pioneer3atPlugin);
    app
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

/// The start kick: steps left and the wheel speed it drives.
#[derive(Component, Clone, Copy, Debug, Default)]
struct Kick {
    steps_left: u32,
    speed: f32,
}

#[derive(Resource, Clone)]
struct PioneerModel(RobotModel);

pub struct Pioneer3atPlugin;

impl Plugin for Pioneer3atPlugin {
    fn build(&self, app: &mut App) {
        if !app.is_plugin_added::<TaskPlugin>() {
            app.add_plugins(TaskPlugin);
        }
        app.insert_resource(PioneerModel(model()))
            .insert_resource(task_spec())
            .add_systems(Startup, spawn_arenas)
            .add_systems(Update, apply_action.in_set(SimSet::Actuate))
            .add_systems(
                Update,
                (observe.in_set(TaskSet::Observe), reward.in_set(TaskSet::Reward), terminate.in_set(TaskSet::Terminate)),
            )
            .add_systems(EnvReset, (kick.in_set(ResetSet::Events), observe.in_set(ResetSet::Observe)));
    }
}

/// Where sonar `i` sits on the base link: on the body's edge, facing its bearing.
pub fn sonar_offset(i: usize) -> Pose {
    let a = SONAR_BEARINGS[i].to_radians();
    let x = if i < 8 { 0.2 } else { -0.2 } + 0.05 * a.cos();
    Pose::from_parts(Vec3::new(x, 0.14 * a.sin(), 0.05), Quat::from_rotation_z(a))
}

/// Spawns one Pioneer with its sonar ring into an arena; returns its parts.
pub fn spawn_pioneer(commands: &mut Commands, arena_entity: Entity, arena: &mut Arena, model: &RobotModel, base: Pose) -> PioneerParts {
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

fn spawn_arenas(mut commands: Commands, model: Res<PioneerModel>, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    for index in 0..config.count {
        let arena_entity = commands.spawn_empty().id();
        let mut arena = Arena::new(index, config.seed, settings.dt, settings.gravity);
        arena.add_ground(1.0);
        let parts = spawn_pioneer(&mut commands, arena_entity, &mut arena, &model.0, Pose::from_translation(Vec3::new(0.0, 0.0, AXLE_HEIGHT)));
        arena.mark_initial();
        commands.entity(arena_entity).insert((arena, parts, Kick::default(), Action(vec![0.0]), Episode { needs_reset: true, ..default() }));
    }
}

/// Drives all four wheels at one speed (rad/s).
pub fn drive(parts: &PioneerParts, speeds: [f32; 4], motors: &mut Query<&mut Motor>) {
    for (wheel, speed) in parts.wheels.iter().zip(speeds) {
        if let Ok(mut m) = motors.get_mut(*wheel) {
            m.command = MotorCommand::Velocity(speed.clamp(-MAX_WHEEL_SPEED, MAX_WHEEL_SPEED));
        }
    }
}

fn apply_action(mut arenas: Query<(&PioneerParts, &Action, &mut Kick)>, mut motors: Query<&mut Motor>) {
    for (parts, action, mut kick) in &mut arenas {
        let speed = if kick.steps_left > 0 {
            kick.steps_left -= 1;
            kick.speed
        } else if let Some(&a) = action.0.first() {
            a
        } else {
            continue;
        };
        drive(parts, [speed; 4], &mut motors);
    }
}

fn observe(supervisor: Supervisor, sensors: Query<&PositionSensor>, mut arenas: Query<(&PioneerParts, &mut Episode)>) {
    for (parts, mut episode) in &mut arenas {
        let (Some(base), Some(pole)) = (supervisor.link_state(parts.base), supervisor.link_state(parts.pole_link)) else {
            continue;
        };
        let angle = sensors.get(parts.pendulum).map_or(0.0, |s| s.value);
        episode.observation.clear();
        episode.observation.extend([base.pose.translation.x, base.linvel.x, angle, pole.angvel.y]);
    }
}

fn reward(mut arenas: Query<&mut Episode, With<PioneerParts>>) {
    for mut e in &mut arenas {
        let (x, angle) = (e.observation[0], e.observation[2]);
        e.reward = 1.0 - 2.0 * angle.abs() - x.abs() / 10.0;
    }
}

fn terminate(mut arenas: Query<&mut Episode, With<PioneerParts>>) {
    for mut e in &mut arenas {
        let (x, angle) = (e.observation[0], e.observation[2]);
        e.terminated = angle.abs() > MAX_ANGLE || x.abs() > MAX_X;
        e.truncated = !e.terminated && e.length + 1 >= EPISODE_STEPS;
    }
}

/// Reset event: the next 5 control steps drive all wheels at a random ±2.0…2.5 rad/s.
fn kick(mut supervisor: Supervisor, mut arenas: Query<(Entity, &Episode, &mut Kick)>) {
    for (arena, episode, mut kick) in &mut arenas {
        if !episode.needs_reset {
            continue;
        }
        if let Some(mut a) = supervisor.arena_mut(arena) {
            let speed = a.rng.random_range(2.0..=2.5);
            let sign = if a.rng.random::<bool>() { 1.0 } else { -1.0 };
            *kick = Kick { steps_left: 5, speed: sign * speed };
        }
    }
}
