//! Any serial arm from a robot file (`*.toml`: a URDF plus the keys of
//! `twinbots_sim::urdf::robot_file`), with no Rust of its own: the arm welded to the floor of an
//! empty cell or to the table of its own (the file's `cell`), its joints under speed-commanded
//! servos that hold position (a UR's `speedj`, a Franka's joint velocity interface), a
//! goal-conditioned reach ([`reach`]) that trains with SAC + HER or PPO and, with a cell and a
//! vacuum gripper, the cell's pick-and-place program ([`pick_place`]) and pick-and-place learned
//! end to end ([`pick_place_learned`]). `twinbots train path/to/arm.toml` reaches it through
//! [`robot`].
//!
//! The controller knows only its encoders and the chain's kinematics (the tool from the
//! URDF in double precision). Its protective stop, which ends the episode as a failure, trips as
//! a joint enters the last 0.01 (rad or m) of its range, or (its safety system, the UR5e's) as a
//! joint runs beyond its URDF velocity or effort limit.

pub mod arm;
pub mod deploy;
pub mod pick_place;
pub mod pick_place_learned;
pub mod reach;
pub mod servo;
pub mod work_area;

use std::sync::Arc;

use bevy::math::Vec3;
use bevy::prelude::*;
use twinbots_link::robot::{AtHome, Controller, Phase, RobotCycleSet, ServerRobotPlugin};
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::robot_file::{PHYSICS_STEP, RobotFile};
use twinbots_sim::{
    ArenaConfig, Framing, InArena, JointState, Motor, MotorCommand, Mount, PhysicsSubstep, PositionSensor, SimSet,
    SimSettings, SpawnOptions, SubstepSet, Supervisor, VacuumGripper, spawn_robot,
};
use twinbots_task::cell::parts::CellFurniture;
use twinbots_task::cell::program::SpeedSlider;
use twinbots_task::robot::{
    AlgoDefaults, JointExcitation, RigDescription, RobotDescription, TaskDescription, TrainingDefaults, headless_app,
};
use twinbots_task::task::{EnvReset, ResetSet, Resetting, TaskSet, spawn_arenas};
use twinbots_task::{Action, DesignPattern, Episode, TaskTermsPlugin};

pub use crate::arm::Arm;
use crate::pick_place::ArmCell;
use crate::reach::ReachState;

/// SAC + HER settings of the reach: the UR5e reach's (RL Zoo's FetchReach settings with
/// observation normalisation and 8 gradient steps per step of the 4 arenas).
pub const SAC_HYPERPARAMS: &str = "learning_rate = 1e-3
gamma = 0.95
tau = 0.05
hidden = [64, 64]
her_goals = 4
normalize_observations = true
learning_starts = 1000
gradient_steps = 8
log_interval = 250";

/// PPO settings: the UR5e reach's.
pub const PPO_HYPERPARAMS: &str = "normalize_observations = true
n_steps = 256
batch_size = 256
hidden = [128, 128]
log_std_init = -1.0";

/// The twin's timing: 4 ms physics steps of the file's `solver_iterations` (8 by default, the
/// UR5e's, whose accuracy the sim tests hold), as many per control step as the file's
/// `policy_period` takes.
pub fn sim_settings(file: &RobotFile) -> SimSettings {
    let substeps = (file.policy_period / PHYSICS_STEP).round() as u32;
    SimSettings { dt: PHYSICS_STEP as f32, substeps, solver_iterations: file.solver_iterations as usize, ..default() }
}

/// The description of the arm in the robot file at `path`: what `twinbots_run::registry::find`
/// returns for a ROBOT argument ending in `.toml`. Its name is the file's path as given (a run
/// records it, and `eval`/`export` find the arm again by it).
pub fn robot(path: &std::path::Path) -> anyhow::Result<RobotDescription> {
    let file = RobotFile::read(path)?;
    Ok(describe(path, Arc::new(Arm::of(file)?)))
}

/// [`robot`] of an arm already read from the robot file at `path` (its meshes loaded once).
pub fn describe(path: &std::path::Path, arm: Arc<Arm>) -> RobotDescription {
    // A description's names are static (a built-in robot's are literals); a process reads
    // one robot file per command, so the few bytes live as long as it.
    let name: &'static str = Box::leak(path.display().to_string().into_boxed_str());
    let description: &'static str = Box::leak(
        format!(
            "{}-joint arm from {} (tool '{}'); reach: Box([-1,1]^{}) joint speeds, {} ms step",
            arm.dof(),
            arm.file.urdf.display(),
            arm.file.chain.tool,
            arm.dof(),
            (arm.file.policy_period * 1000.0).round()
        )
        .into_boxed_str(),
    );
    let reach = arm.base.translation.z + arm.reach();
    let settings = sim_settings(&arm.file);
    let spec_arm = arm.clone();
    let build_arm = arm.clone();
    let feedback_arm = arm.clone();
    let mut tasks = vec![TaskDescription {
        name: "reach",
        description: "tool link to a target around home, at rest within 1 cm (position only)",
        spec: Arc::new(move || reach::reach_task(&spec_arm).spec()),
        server: true,
        training: None,
        scripted: None,
    }];
    if arm.cell.is_some() && arm.file.gripper.is_some() {
        let (spec_arm, classic_arm) = (arm.clone(), arm.clone());
        tasks.push(TaskDescription {
            name: "pick-place",
            description: "the part from the pick fixture to the place fixture: the cell program's waypoints driven by the reach policy",
            spec: Arc::new(move || pick_place::pick_place_task(&spec_arm).spec()),
            server: false,
            training: None,
            // Its classical controller: the reach's, between the program's straight moves.
            scripted: Some(Arc::new(move |obs: &[f32]| reach::resolved_rate(&classic_arm.file, obs))),
        });
        let spec_arm = arm.clone();
        tasks.push(TaskDescription {
            name: "pick-place-learned",
            description: "the part to a goal on the table or in the air, the policy moving the tool and switching the suction (SAC + HER)",
            spec: Arc::new(move || pick_place_learned::pick_place_learned_task(&spec_arm).spec()),
            server: false,
            training: Some(twinbots_task::cell::learned::training),
            scripted: Some(Arc::new(pick_place_learned::scripted)),
        });
    }
    RobotDescription {
        name,
        description,
        tasks,
        patterns: vec![DesignPattern::Supervised],
        // Cameras 1.6 reaches away, looking at 0.4 of the arm's height.
        framing: Framing { target: Vec3::new(0.0, 0.0, 0.4 * reach), distance: 1.6 * reach.max(0.3), facing: 0.0 },
        defaults: TrainingDefaults {
            algo: "sac",
            eval_episodes: 200,
            algos: vec![
                AlgoDefaults {
                    algo: "sac",
                    arenas: 4,
                    timesteps: 200_000,
                    eval_every: 5,
                    hyperparams: SAC_HYPERPARAMS,
                },
                AlgoDefaults {
                    algo: "ppo",
                    arenas: 8,
                    timesteps: 3_000_000,
                    eval_every: 20,
                    hyperparams: PPO_HYPERPARAMS,
                },
            ],
        },
        settings: Arc::new(move || settings),
        build: Arc::new(move |request| {
            let task = match request.task {
                "pick-place" => ArmTask::PickPlace,
                "pick-place-learned" => ArmTask::PickPlaceLearned,
                _ => ArmTask::Reach,
            };
            let plugin = ArmPlugin { arm: build_arm.clone(), task, pattern: request.pattern, kind: name };
            headless_app(settings, request, plugin)
        }),
        rig: Some(rig(&arm, settings)),
        feedback: Some(Arc::new(move |obs: &[f32]| reach::resolved_rate(&feedback_arm.file, obs))),
        cell: None,
    }
}

/// Which task the arm's cell runs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ArmTask {
    #[default]
    Reach,
    /// Pick-and-place ([`pick_place`]): an arm with a cell and a gripper.
    PickPlace,
    /// Pick-and-place learned end to end ([`pick_place_learned`]): the same arm.
    PickPlaceLearned,
}

/// The arm's cell and its task.
pub struct ArmPlugin {
    pub arm: Arc<Arm>,
    pub task: ArmTask,
    pub pattern: DesignPattern,
    /// The robot's name as the registry knows it (what a pattern-3 robot announces).
    pub kind: &'static str,
}

/// The arm's joints in the controller's order (one per arena).
#[derive(Component, Clone, Debug)]
pub struct ArmJoints(pub Vec<Entity>);

impl Plugin for ArmPlugin {
    fn build(&self, app: &mut App) {
        let definition = match self.task {
            ArmTask::Reach => reach::reach_task(&self.arm),
            ArmTask::PickPlace => pick_place::pick_place_task(&self.arm),
            ArmTask::PickPlaceLearned => pick_place_learned::pick_place_learned_task(&self.arm),
        };
        app.insert_resource((*self.arm).clone())
            .add_plugins(TaskTermsPlugin::new(definition, self.pattern))
            .add_systems(Startup, spawn_cells)
            .add_systems(Update, read_arm.in_set(TaskSet::Read))
            .add_systems(PhysicsSubstep, (meter_energy, watch_limits).in_set(SubstepSet::Record));
        if self.task == ArmTask::PickPlaceLearned {
            // The policy moves the tool and switches the suction (no cell program).
            app.add_systems(
                Update,
                (pick_place_learned::apply_action, pick_place::apply_suction).chain().in_set(SimSet::Actuate),
            );
        } else {
            app.add_systems(Update, apply_action.in_set(SimSet::Actuate));
        }
        match self.task {
            ArmTask::Reach => {
                app.add_systems(Update, report.in_set(TaskSet::Report));
            }
            ArmTask::PickPlace => {
                app.add_systems(
                    Update,
                    (
                        pick_place::apply_suction.in_set(SimSet::Actuate),
                        pick_place::run_program.after(read_arm).in_set(TaskSet::Read),
                        pick_place::report.in_set(TaskSet::Report),
                    ),
                )
                .add_systems(EnvReset, pick_place::place_part.in_set(ResetSet::Place));
            }
            ArmTask::PickPlaceLearned => {
                let read_part =
                    || (pick_place_learned::read_part, pick_place_learned::read_vacuum).chain().after(read_arm);
                app.add_systems(
                    Update,
                    (read_part().in_set(TaskSet::Read), pick_place_learned::report.in_set(TaskSet::Report)),
                )
                .add_systems(
                    EnvReset,
                    (pick_place::place_part.in_set(ResetSet::Place), read_part().in_set(ResetSet::Read)),
                );
            }
        }
        if self.pattern == DesignPattern::Server {
            // Design pattern 3: no Supervisor; the arm homes with its own motors.
            app.add_plugins(ServerRobotPlugin::<ReachState>::new(self.kind))
                .add_systems(Update, (home.in_set(RobotCycleSet::Home), reset_energy.in_set(RobotCycleSet::Operate)));
        } else {
            app.add_systems(EnvReset, (place_arm.in_set(ResetSet::Place), read_arm.in_set(ResetSet::Read)));
        }
    }
}

/// Homing speed's gain (1/s): speed = gain × distance to the start, within each joint's task speed.
const HOMING_GAIN: f32 = 10.0;
/// Homed: every joint this close to the drawn start (rad or m)…
const HOME_TOLERANCE: f32 = 0.01;
/// …and this slow (rad/s or m/s).
const HOME_SPEED: f32 = 0.02;

/// Pattern 3: the arm drives itself to the drawn start (near home) with its own motors and says
/// when it is there; an arm in a protective stop first brakes to rest, then the stop is
/// unlocked (as an operator does) and it homes out of the stop's margin.
fn home(
    arm: Res<Arm>,
    mut robots: Query<(&ArmJoints, &mut ReachState, &Controller, &mut AtHome)>,
    mut motors: Query<&mut Motor>,
) {
    for (joints, mut state, controller, mut at_home) in &mut robots {
        if controller.phase() != Phase::Homing || state.q.len() != joints.0.len() {
            continue;
        }
        let still = state.qd.iter().all(|v| v.abs() < HOME_SPEED);
        if state.stopped {
            if !still {
                continue;
            }
            state.stopped = false;
            state.safety.unlock();
        }
        let start = state.start_pose.clone();
        at_home.0 = still && state.q.iter().zip(&start).all(|(q, s)| (q - s).abs() < HOME_TOLERANCE);
        for (k, &joint) in joints.0.iter().enumerate() {
            let limit = arm.file.speed_limits[k] as f32;
            let speed = if at_home.0 { 0.0 } else { (HOMING_GAIN * (start[k] - state.q[k])).clamp(-limit, limit) };
            if let Ok(mut m) = motors.get_mut(joint) {
                m.command = MotorCommand::Velocity(speed);
            }
        }
    }
}

/// The arm on its test stand (what `record`, `replay`, `identify` and the UR controller
/// stand-in drive): welded at its base on the ground, as in its cell, its controlled joints'
/// drives holding position and taking speeds (a UR's `speedj`) every control period.
/// Calibrations fit each controlled joint's damping, friction and armature and the command
/// delay, from the URDF's values (no prior beyond them); excitation moves each joint within
/// ±0.3 rad of where it starts at up to 0.5 rad/s (or half its rated speed, if lower).
fn rig(arm: &Arm, settings: SimSettings) -> RigDescription {
    let (model, spawned) = (arm.model.clone(), arm.clone());
    let joints = arm.file.joints.clone();
    let mut fit: Vec<String> =
        joints.iter().flat_map(|j| ["damping", "friction", "armature"].map(|p| format!("{j}.{p}"))).collect();
    fit.push("command_delay".into());
    let excitation = joints
        .iter()
        .enumerate()
        .map(|(i, j)| {
            let rated = arm.model.joint(j).map_or(f32::INFINITY, |joint| joint.limits.velocity);
            JointExcitation { joint: j.clone().into(), channel: i as u8, speed: (0.5 * rated).min(0.5), travel: 0.3 }
        })
        .collect();
    RigDescription {
        model: Arc::new(move || model.clone()),
        settings,
        nominal: "".into(),
        prior: "".into(),
        fit,
        spawn: Arc::new(move |commands, arena_entity, arena, start| {
            arena.add_ground(0.8);
            let at: Vec<f32> = (spawned.file.joints.iter().zip(spawned.home()))
                .map(|(name, q)| start.iter().find(|(n, _)| n == name).map_or(q, |(_, q)| *q))
                .collect();
            spawn_arm(commands, arena_entity, arena, &spawned, Pose::IDENTITY, &at).0
        }),
        excitation,
        command_steps: (arm.file.control_period / PHYSICS_STEP).round().max(1.0) as u32,
    }
}

/// Each arena: the arm welded on an empty floor, or in its cell (the table, the fixtures and
/// the part of its layout, the arm on the table top, the gripper at its tool link).
fn spawn_cells(mut commands: Commands, arm: Res<Arm>, config: Res<ArenaConfig>, settings: Res<SimSettings>) {
    let home = arm.home();
    let furniture = arm.cell.as_ref().map(|_| CellFurniture::default());
    spawn_arenas(&mut commands, &config, &settings, |commands, arena_entity, arena| {
        let part = match (&arm.cell, &furniture) {
            (Some(layout), Some(furniture)) => Some(furniture.spawn(commands, arena_entity, arena, layout)),
            _ => {
                arena.add_ground(0.8);
                None
            }
        };
        let (robot, joints) = spawn_arm(commands, arena_entity, arena, &arm, arm.root(), &home);
        let state = ReachState { start_pose: home.clone(), ..default() };
        let tool = robot.link(&arm.file.chain.tool).expect("the robot file's tool is a link of its URDF");
        let gripper = arm.file.gripper.map(|g| {
            // The cup sucks along the tool link's z; a mounted device's forward axis is its +X.
            let cup = Mount { link: tool, offset: Pose::from_rotation(Quat::from_rotation_arc(Vec3::X, Vec3::Z)) };
            let gripper = VacuumGripper::new(g.radius as f32, g.stroke as f32);
            commands.spawn((gripper, cup, InArena(arena_entity))).id()
        });
        if let (Some(part), Some(gripper), Some(fixtures)) = (part, gripper, arm.fixtures()) {
            commands.entity(arena_entity).insert(ArmCell { part, gripper, tool, fixtures });
        }
        (ArmJoints(joints), state)
    });
}

/// Spawns the arm, its root link welded at `root`, its controlled joints at `start` (the
/// controller's order) and its `held_positions` joints where the file holds them. The
/// controlled joints' drives are a speed-commanded servo's: they hold position (zero speed until
/// told otherwise, as a powered UR does) and ramp a new speed within the file's
/// `acceleration_limits`; the held joints' drives hold them. Returns the robot and its
/// controlled joints.
fn spawn_arm(
    commands: &mut Commands,
    arena_entity: Entity,
    arena: &mut twinbots_sim::Arena,
    arm: &Arm,
    root: Pose,
    start: &[f32],
) -> (twinbots_sim::SpawnedRobot, Vec<Entity>) {
    let file = &arm.file;
    let held = file.held_positions.iter().map(|(name, q)| (name.clone(), *q as f32));
    let joint_positions = file.joints.iter().cloned().zip(start.iter().copied()).chain(held).collect();
    let options = SpawnOptions { base: root, fixed_base: true, joint_positions, ..default() };
    let robot = spawn_robot(commands, arena_entity, arena, &arm.model, options);
    let joint = |name: &str| robot.joint(name).expect("the robot file's joints are the URDF's (checked on reading)");
    let joints: Vec<Entity> = file.joints.iter().map(|name| joint(name)).collect();
    let drives = (joints.iter().enumerate())
        .map(|(k, &j)| (j, file.acceleration_limits.as_ref().map(|limits| limits[k] as f32)))
        .chain(file.held_positions.iter().map(|(name, _)| (joint(name), None)));
    for (joint, acceleration) in drives {
        commands.entity(joint).entry::<Motor>().and_modify(move |mut m| {
            m.holds_position = true;
            m.command = MotorCommand::Velocity(0.0);
            m.initial_command = MotorCommand::Velocity(0.0);
            m.max_acceleration = acceleration;
        });
    }
    (robot, joints)
}

/// The policy's action becomes joint speeds (each joint's task speed limit at full scale,
/// times the arena's speed slider if it has one), unless the arm is in a protective stop: then
/// it holds.
fn apply_action(
    arm: Res<Arm>,
    mut arenas: Query<(&ArmJoints, &Action, &mut ReachState, Option<&SpeedSlider>)>,
    mut motors: Query<&mut Motor>,
) {
    for (joints, action, mut state, slider) in &mut arenas {
        if action.0.is_empty() {
            continue;
        }
        let stopped = state.stopped;
        let scale = slider.map_or(1.0, |s| s.0);
        // The pick-and-place program's straight moves are the controller's (MoveL).
        let straight = pick_place::straight_move(&arm, &state);
        for (k, &joint) in joints.0.iter().enumerate() {
            let a = action.0.get(k).copied().unwrap_or(0.0).clamp(-1.0, 1.0);
            let speed = match &straight {
                _ if stopped => 0.0,
                Some(speeds) => speeds[k] * scale,
                None => a * arm.file.speed_limits[k] as f32 * scale,
            };
            if let Ok(mut m) = motors.get_mut(joint) {
                m.command = MotorCommand::Velocity(speed);
            }
        }
        state.push_action(&action.0);
    }
}

/// The joints from their position sensors and encoders, the tool through the controller's own
/// kinematics, and the protective stop (latched until the reset).
fn read_arm(
    arm: Res<Arm>,
    sensors: Query<(&PositionSensor, &JointState)>,
    mut arenas: Query<(&ArmJoints, &mut ReachState)>,
) {
    for (joints, mut state) in &mut arenas {
        let (q, qd): (Vec<f32>, Vec<f32>) =
            joints.0.iter().map(|&j| sensors.get(j).map_or((0.0, 0.0), |(p, s)| (p.value, s.velocity))).unzip();
        let at_limit = state.read(&arm, q, qd);
        state.stopped |= at_limit && !state.at_limit;
        state.at_limit = at_limit;
    }
}

/// Reset: the Supervisor puts the arm at the drawn start, its stop unlocked, the episode's
/// energy from nothing.
fn place_arm(mut supervisor: Supervisor, mut arenas: Query<(&ArmJoints, &mut ReachState), With<Resetting>>) {
    for (joints, mut state) in &mut arenas {
        for (&joint, &q) in joints.0.iter().zip(&state.start_pose) {
            supervisor.set_joint_position(joint, q);
        }
        state.stopped = false;
        state.safety.unlock();
        state.energy = 0.0;
    }
}

/// Pattern 3: an episode's energy counts from its start, not from the homing before it.
fn reset_energy(mut robots: Query<(&Controller, &mut ReachState)>) {
    for (controller, mut state) in &mut robots {
        if controller.phase() == Phase::Starting {
            state.energy = 0.0;
        }
    }
}

/// The controller's safety system, every physics step once the joints are measured: a joint
/// beyond its URDF velocity or effort limit stops the arm, which holds where it is.
fn watch_limits(
    settings: Res<SimSettings>,
    mut readings: Query<(&JointState, &mut Motor)>,
    mut arenas: Query<(&ArmJoints, &mut ReachState)>,
) {
    for (joints, mut state) in &mut arenas {
        if !state.stopped {
            let state = &mut *state;
            state.stopped =
                twinbots_task::safety::watch(&mut state.safety, &joints.0, &mut readings, settings.dt).is_some();
        }
    }
}

/// Adds the energy the motors delivered in the last physics step, Σ|τ·ω|·dt over the arm's
/// joints (their torque feedback and encoder speeds), as the UR5e's twin meters it.
fn meter_energy(
    settings: Res<SimSettings>,
    joints: Query<&JointState>,
    mut arenas: Query<(&ArmJoints, &mut ReachState)>,
) {
    for (arm_joints, mut state) in &mut arenas {
        let power: f32 = joints.iter_many(&arm_joints.0).map(|s| (s.effort * s.velocity).abs()).sum();
        state.energy += power * settings.dt;
    }
}

/// The figures of a reach that ended: its final error, its stop, the energy its motors spent
/// and, if it arrived, its cycle time.
fn report(settings: Res<SimSettings>, mut arenas: Query<(&ReachState, &mut Episode)>) {
    for (state, mut e) in &mut arenas {
        if e.done() {
            e.running.metrics.insert("final_error_mm".into(), 1000.0 * state.distance());
            if e.running.success == Some(true) {
                let cycle_time = (e.running.length + 1) as f32 * settings.control_dt();
                e.running.metrics.insert("cycle_time_s".into(), cycle_time);
            }
            let stops = f32::from(u8::from(state.stopped));
            e.running.metrics.insert("protective_stops".into(), stops);
            e.running.metrics.insert("energy_j".into(), state.energy);
        }
    }
}
