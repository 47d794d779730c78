//! The cart-pole twin (deepbots replica, paper §5) as a Bevy plugin: robot, world and task.
//!
//! A 2 kg cart on four velocity-controlled wheels rolls on the ground; a passive pole swings on
//! a hinge with a position sensor. Action: Discrete(2), all wheels at -5 or +5 rad/s.
//! Observation: cart x, cart velocity, pole angle, pole angular velocity. Reward +1 per step;
//! terminated past 15° or ±0.4 m; truncated once the score exceeds 1950 (design pattern 1: the
//! cart's x and velocity and the pole's angular velocity come from the Supervisor).

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_rl::task::{ResetSet, TaskSet};
use twinbots_rl::{Action, DesignPattern, Episode, SolvedCriterion, Space, TaskPlugin, TaskSpec};

mod radio;
pub mod server;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ArenaConfig, MotorCommand, Motor, PositionSensor, SimPlugin, SimSet, SimSettings,
    SpawnOptions, Supervisor, spawn_robot,
};

/// The robot's URDF, compiled in so the twin works from any directory.
pub const URDF: &str = include_str!("../../../assets/robots/cartpole/cartpole.urdf");
pub const URDF_PATH: &str = "assets/robots/cartpole/cartpole.urdf";

/// Wheel speed of the two actions (rad/s): ±5 rad/s is ±0.2 m/s on 0.04 m wheels.
pub const WHEEL_SPEED: f32 = 5.0;
/// Episode ends when the pole passes this angle (15°).
pub const MAX_POLE_ANGLE: f32 = 15.0 * std::f32::consts::PI / 180.0;
/// Episode ends when the cart leaves ±this (m).
pub const MAX_CART_X: f32 = 0.4;
/// Episode is truncated once its score exceeds this.
pub const MAX_SCORE: f32 = 1950.0;
/// Height of the cart's centre: the wheels' radius, so they touch the ground.
pub const CART_HEIGHT: f32 = 0.04;

/// Timing of the twin: 4 ms physics, 8 substeps, a 32 ms control step as in the paper.
pub fn sim_settings() -> SimSettings {
    SimSettings {
        dt: 0.004,
        substeps: 8,
        ..default()
    }
}

/// PPO settings for the twin: RL Zoo's CartPole-v1 settings (short rollouts, many epochs,
/// linear learning-rate decay); SB3's defaults otherwise.
pub fn ppo_config() -> twinbots_rl::PpoConfig {
    twinbots_rl::PpoConfig::zoo_cartpole()
}

/// The parsed cart-pole URDF.
pub fn model() -> RobotModel {
    parse_urdf(URDF, Path::new(URDF_PATH), Path::new("assets/robots/cartpole"))
        .expect("the built-in cart-pole URDF is valid (checked by the tests)")
}

/// Everything needed to train or run the cart-pole headless (design pattern 1).
pub fn headless_app(arenas: usize, seed: u64) -> App {
    headless_app_with(arenas, seed, DesignPattern::Supervised)
}

/// As [`headless_app`], under the given design pattern.
pub fn headless_app_with(arenas: usize, seed: u64, pattern: DesignPattern) -> App {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin {
            settings: sim_settings(),
            ..default()
        })
        .insert_resource(ArenaConfig { count: arenas, seed })
        .add_plugins(CartPolePlugin { pattern, ..default() });
    app
}

/// The cart-pole twin and its balancing task.
#[derive(Clone, Copy, Debug)]
pub struct CartPolePlugin {
    /// Start angles are drawn uniformly from ±this (rad) at every reset.
    pub initial_tilt: f32,
    pub pattern: DesignPattern,
}

impl Default for CartPolePlugin {
    fn default() -> Self {
        Self { initial_tilt: 0.05, pattern: DesignPattern::Supervised }
    }
}

/// The model and start-state settings, shared by the systems.
#[derive(Resource, Clone)]
pub(crate) struct CartPoleConfig {
    model: RobotModel,
    initial_tilt: f32,
    pattern: DesignPattern,
}

/// The entities of an arena's cart-pole, kept on the arena entity.
#[derive(Component, Clone, Copy, Debug)]
pub struct CartPoleParts {
    pub cart: Entity,
    pub pole_link: Entity,
    pub pole_joint: Entity,
    pub wheels: [Entity; 4],
}

impl Plugin for CartPolePlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(CartPoleConfig {
            model: model(),
            initial_tilt: self.initial_tilt,
            pattern: self.pattern,
        })
        .add_systems(Startup, spawn_arenas);
        if self.pattern == DesignPattern::Server {
            // No task machinery (it resets through the Supervisor): the robot and the server
            // run the episodes.
            server::build(app);
            return;
        }
        if !app.is_plugin_added::<TaskPlugin>() {
            app.add_plugins(TaskPlugin);
        }
        app.insert_resource(task_spec())
            .add_systems(
                Update,
                (reward.in_set(TaskSet::Reward), terminate.in_set(TaskSet::Terminate)),
            )
            .add_systems(twinbots_rl::task::EnvReset, tilt_pole.in_set(ResetSet::Events));
        match self.pattern {
            DesignPattern::Supervised => {
                app.add_systems(Update, (apply_action.in_set(SimSet::Actuate), observe.in_set(TaskSet::Observe)))
                    .add_systems(twinbots_rl::task::EnvReset, observe.in_set(ResetSet::Observe));
            }
            DesignPattern::Radio => radio::build(app),
            DesignPattern::Server => {}
        }
    }
}

/// The cart-pole task's spaces and solved criterion.
pub fn task_spec() -> TaskSpec {
    TaskSpec {
        name: "cartpole".into(),
        observation_space: Space::uniform_box(4, f32::NEG_INFINITY, f32::INFINITY),
        action_space: Space::Discrete { n: 2 },
        solved: Some(SolvedCriterion::mean_score(100, MAX_SCORE)),
    }
}

/// A pattern-3 robot process: `arenas` cart-poles with no Supervisor in the app, each with a
/// Communicator to the RobotServer at `server`.
pub fn robot_app(arenas: usize, seed: u64, server: twinbots_server::robot::ServerAddress) -> App {
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { settings: sim_settings(), supervisor: false })
        .insert_resource(twinbots_sim::OperatorAccess)
        .insert_resource(ArenaConfig { count: arenas, seed })
        .insert_resource(server)
        .add_plugins(CartPolePlugin { pattern: DesignPattern::Server, ..default() });
    app
}

pub(crate) fn spawn_arenas(
    mut commands: Commands,
    config: Res<CartPoleConfig>,
    arenas: Res<ArenaConfig>,
    settings: Res<SimSettings>,
) {
    for index in 0..arenas.count {
        let arena_entity = commands.spawn_empty().id();
        let mut arena = Arena::new(index, arenas.seed, settings.dt, settings.gravity);
        arena.add_ground(1.0);
        let robot = spawn_robot(
            &mut commands,
            arena_entity,
            &mut arena,
            &config.model,
            SpawnOptions {
                base: Pose::from_translation(Vec3::new(0.0, 0.0, CART_HEIGHT)),
                ..default()
            },
        );
        let part = |name: &str, found: Option<Entity>| {
            found.unwrap_or_else(|| panic!("cart-pole URDF has no '{name}'"))
        };
        let parts = CartPoleParts {
            cart: part("cart", robot.link("cart")),
            pole_link: part("pole", robot.link("pole")),
            pole_joint: part("pole_joint", robot.joint("pole_joint")),
            wheels: ["wheel1_joint", "wheel2_joint", "wheel3_joint", "wheel4_joint"]
                .map(|w| part(w, robot.joint(w))),
        };
        if config.pattern == DesignPattern::Radio {
            radio::equip(&mut commands, arena_entity, &mut arena, &parts);
        }
        arena.mark_initial();
        commands.entity(arena_entity).insert((
            arena,
            parts,
            Action(vec![0.0]),
            Episode {
                needs_reset: true,
                ..default()
            },
        ));
    }
}

/// Action 0 drives all wheels at -5 rad/s, action 1 at +5 rad/s.
fn drive_wheels(parts: &CartPoleParts, action: f32, motors: &mut Query<&mut Motor>) {
    let speed = if action >= 0.5 { WHEEL_SPEED } else { -WHEEL_SPEED };
    for wheel in parts.wheels {
        if let Ok(mut motor) = motors.get_mut(wheel) {
            motor.command = MotorCommand::Velocity(speed);
        }
    }
}

/// An empty action (an action latency still filling) leaves the wheels as they are.
fn apply_action(arenas: Query<(&CartPoleParts, &Action)>, mut motors: Query<&mut Motor>) {
    for (parts, action) in &arenas {
        if let Some(&a) = action.0.first() {
            drive_wheels(parts, a, &mut motors);
        }
    }
}

fn observe(
    supervisor: Supervisor,
    sensors: Query<&PositionSensor>,
    mut arenas: Query<(&CartPoleParts, &mut Episode)>,
) {
    for (parts, mut episode) in &mut arenas {
        let (Some(cart), Some(pole)) = (
            supervisor.link_state(parts.cart),
            supervisor.link_state(parts.pole_link),
        ) else {
            continue;
        };
        let angle = sensors.get(parts.pole_joint).map_or(0.0, |s| s.value);
        episode.observation.clear();
        episode.observation.extend([
            cart.pose.translation.x,
            cart.linvel.x,
            angle,
            pole.angvel.y,
        ]);
    }
}

fn reward(mut arenas: Query<&mut Episode, With<CartPoleParts>>) {
    for mut episode in &mut arenas {
        episode.reward = 1.0;
    }
}

fn terminate(mut arenas: Query<&mut Episode, With<CartPoleParts>>) {
    for mut e in &mut arenas {
        let (x, angle) = (e.observation[0], e.observation[2]);
        e.terminated = angle.abs() > MAX_POLE_ANGLE || x.abs() > MAX_CART_X;
        e.truncated = !e.terminated && e.score + e.reward > MAX_SCORE;
    }
}

/// Reset event: the pole starts at a small random angle from the arena's random stream.
fn tilt_pole(
    config: Res<CartPoleConfig>,
    mut supervisor: Supervisor,
    mut arenas: Query<(Entity, &CartPoleParts, &Episode)>,
) {
    for (arena, parts, episode) in &mut arenas {
        if !episode.needs_reset {
            continue;
        }
        let tilt = config.initial_tilt;
        let angle = match supervisor.arena_mut(arena) {
            Some(mut a) if tilt > 0.0 => a.rng.random_range(-tilt..=tilt),
            _ => 0.0,
        };
        supervisor.set_joint_position(parts.pole_joint, angle);
    }
}
