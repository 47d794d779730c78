//! Adding a robot without touching the core crates: a torque-driven pendulum arm ("swing-up"),
//! its URDF, its task as a Bevy plugin (observation, reward and termination terms and a reset
//! event), then PPO on 4 arenas of it. See docs/adding-a-robot.md.
//!
//! Run: `cargo run --release --example add_robot`

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_rl::task::{EnvReset, ResetSet, TaskSet};
use twinbots_rl::{Action, AppVecEnv, Episode, Flow, Ppo, PpoConfig, Space, TaskPlugin, TaskSpec, VecEnv};
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{
    Arena, ArenaConfig, JointState, Motor, MotorCommand, PositionSensor, SimPlugin, SimSet, SimSettings, SpawnOptions,
    Supervisor, spawn_robot,
};

// 1. The robot: a 1 kg, 0.5 m arm on a motorised hinge 1 m above the ground, torque ≤ 2 N·m.
const URDF: &str = r#"<robot name="swing_arm">
  <link name="world"/>
  <link name="arm">
    <inertial><origin xyz="0 0 0.25"/><mass value="1"/>
      <inertia ixx="0.021" ixy="0" ixz="0" iyy="0.021" iyz="0" izz="0.0005"/></inertial>
    <visual><origin xyz="0 0 0.25"/><geometry><box size="0.04 0.04 0.5"/></geometry>
      <material name="teal"><color rgba="0.1 0.6 0.6 1"/></material></visual>
  </link>
  <joint name="shoulder" type="continuous">
    <parent link="world"/><child link="arm"/><origin xyz="0 0 1"/><axis xyz="0 1 0"/>
    <limit effort="2" velocity="8"/>
  </joint>
</robot>"#;

const MAX_TORQUE: f32 = 2.0;

// 2. Its parts, kept on each arena entity.
#[derive(Component, Clone, Copy)]
struct Arm {
    shoulder: Entity,
}

#[derive(Resource, Clone)]
struct ArmModel(RobotModel);

// 3. The plugin: spawn, act, observe, reward, terminate, reset.
struct SwingArmPlugin;

impl Plugin for SwingArmPlugin {
    fn build(&self, app: &mut App) {
        let model = parse_urdf(URDF, Path::new("swing_arm.urdf"), Path::new(".")).expect("valid URDF");
        app.add_plugins(TaskPlugin)
            .insert_resource(ArmModel(model))
            .insert_resource(TaskSpec {
                name: "swing_arm".into(),
                observation_space: Space::uniform_box(3, f32::NEG_INFINITY, f32::INFINITY),
                action_space: Space::Box { low: vec![-MAX_TORQUE], high: vec![MAX_TORQUE] },
                solved: None,
            })
            .add_systems(Startup, spawn)
            .add_systems(Update, act.in_set(SimSet::Actuate))
            .add_systems(Update, (observe.in_set(TaskSet::Observe), reward.in_set(TaskSet::Reward), end.in_set(TaskSet::Terminate)))
            .add_systems(EnvReset, (random_start.in_set(ResetSet::Events), observe.in_set(ResetSet::Observe)));
    }
}

fn spawn(mut commands: Commands, model: Res<ArmModel>, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    for index in 0..config.count {
        let entity = commands.spawn_empty().id();
        let mut arena = Arena::new(index, config.seed, settings.dt, settings.gravity);
        let robot = spawn_robot(&mut commands, entity, &mut arena, &model.0, SpawnOptions::default());
        arena.mark_initial();
        let shoulder = robot.joint("shoulder").expect("the URDF has a shoulder");
        commands.entity(entity).insert((arena, Arm { shoulder }, Action(vec![0.0]), Episode { needs_reset: true, ..default() }));
    }
}

fn act(arms: Query<(&Arm, &Action)>, mut motors: Query<&mut Motor>) {
    for (arm, action) in &arms {
        if let (Some(&torque), Ok(mut m)) = (action.0.first(), motors.get_mut(arm.shoulder)) {
            m.command = MotorCommand::Torque(torque);
        }
    }
}

/// θ = 0 is upright; [cos θ, sin θ, θ̇] from the encoder, as Gymnasium's Pendulum.
fn observe(sensors: Query<(&PositionSensor, &JointState)>, mut arms: Query<(&Arm, &mut Episode)>) {
    for (arm, mut e) in &mut arms {
        let Ok((pos, state)) = sensors.get(arm.shoulder) else { continue };
        e.observation = vec![pos.value.cos(), pos.value.sin(), state.velocity];
    }
}

fn reward(mut arms: Query<(&Action, &mut Episode), With<Arm>>) {
    for (action, mut e) in &mut arms {
        let angle = e.observation[1].atan2(e.observation[0]);
        let u = action.0.first().copied().unwrap_or(0.0);
        e.reward = -(angle * angle + 0.1 * e.observation[2].powi(2) + 0.001 * u * u);
    }
}

fn end(mut arms: Query<&mut Episode, With<Arm>>) {
    for mut e in &mut arms {
        e.terminated = false;
        e.truncated = e.length + 1 >= 200;
    }
}

/// Reset event: the arm starts at a random angle.
fn random_start(mut supervisor: Supervisor, arms: Query<(Entity, &Arm, &Episode)>) {
    for (arena, arm, e) in &arms {
        if e.needs_reset {
            let angle = supervisor.arena_mut(arena).map_or(0.0, |mut a| a.rng.random_range(-3.1..3.1));
            supervisor.set_joint_position(arm.shoulder, angle);
        }
    }
}

fn main() -> anyhow::Result<()> {
    // 4. An app of 4 arenas, and PPO on it through the vectorised env.
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { settings: SimSettings { dt: 0.01, substeps: 5, ..default() }, ..default() })
        .insert_resource(ArenaConfig { count: 4, seed: 1 })
        .add_plugins(SwingArmPlugin);
    let mut env = AppVecEnv::new(app);
    let config = PpoConfig { n_steps: 1024, gamma: 0.9, learning_rate: 1e-3, normalize_observations: true, ..Default::default() };
    let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 1)?;
    let mut first = None;
    model.learn(&mut env, 120_000, &mut |s: &twinbots_rl::UpdateStats, _: &Ppo| {
        if s.episodes > 0 && first.is_none() {
            first = Some(s.mean_reward);
        }
        println!("{:>7} steps  mean episode reward {:>8.1}", s.timesteps, s.mean_reward);
        Ok(Flow::Continue)
    })?;
    println!("swing_arm: first episodes {:.0}, after training {:.0}", first.unwrap_or(f32::NAN), model.mean_recent_score());
    Ok(())
}
