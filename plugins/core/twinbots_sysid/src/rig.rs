//! A robot on its test stand, once per parameter set: the twin that `record`, `replay` and
//! `identify` drive, one arena per candidate, all stepped side by side.

use bevy::prelude::*;
use twinbots_log::JointSample;
use twinbots_sim::parameters::{apply_to_joint, catalogue};
use twinbots_sim::urdf::RobotModel;
use twinbots_sim::{
    Arena, Joint, JointDynamics, JointState, Motor, MotorCommand, ParameterSpec, Parameters, PhysicsSubstep, SimPlugin,
    SimSettings,
};
use twinbots_task::robot::{RigDescription, RobotDescription};

/// A robot's test rig and what a log of it holds.
pub struct Rig {
    pub robot: &'static str,
    pub description: RigDescription,
    pub model: RobotModel,
    pub settings: SimSettings,
    /// The twin's parameters as it always runs (its URDF and built-in table).
    pub nominal: Parameters,
    /// Every parameter the twin has, with its nominal value and unit.
    pub catalogue: Vec<ParameterSpec>,
    /// The movable joints in the model's order: the joints a log of the robot states.
    pub joints: Vec<String>,
    /// Whether each of `joints` has a motor (measures an effort, takes commands).
    pub actuated: Vec<bool>,
    /// Each joint's movable ancestors (indices into `joints`): the joints whose efforts its
    /// own dynamics reach, through the links they carry.
    pub ancestors: Vec<Vec<usize>>,
}

impl Rig {
    /// The rig of a registered robot; an error for a robot that has none.
    pub fn of(robot: &RobotDescription) -> anyhow::Result<Self> {
        let Some(description) = robot.rig.clone() else {
            anyhow::bail!("robot '{}' has no test rig: it cannot record, replay or identify", robot.name);
        };
        let model = (description.model)();
        let nominal = description.nominal_parameters();
        let catalogue = catalogue(&model, &nominal);
        let movable = model.joints.iter().filter(|j| j.kind.is_movable());
        let (joints, actuated): (Vec<String>, Vec<bool>) =
            movable.map(|j| (j.name.clone(), j.limits.effort > 0.0)).unzip();
        let settings = description.settings;
        let ancestors = ancestors(&model, &joints);
        Ok(Self { robot: robot.name, description, model, settings, nominal, catalogue, joints, actuated, ancestors })
    }

    /// A calibration file's parameters (`twinbots identify`'s `calibration.toml`), checked
    /// against this robot's catalogue; none without a file.
    pub fn read_calibration(&self, path: Option<&std::path::Path>) -> anyhow::Result<Parameters> {
        Ok(twinbots_task::calibration::Calibration::read_optional(path, &self.catalogue, self.robot)?.parameters)
    }

    /// The nominal parameters with `overrides` over them, checked against the catalogue.
    pub fn parameters(&self, overrides: &Parameters) -> anyhow::Result<Parameters> {
        overrides.check(&self.catalogue, self.robot).map_err(anyhow::Error::msg)?;
        let mut out = self.nominal.clone();
        out.extend(overrides);
        Ok(out)
    }

    /// The physics step (s).
    pub fn dt(&self) -> f64 {
        self.settings.dt_seconds()
    }

    /// A parameter's value in `params`, else its nominal one.
    pub fn value(&self, params: &Parameters, name: &str) -> f64 {
        params.get(name).or_else(|| self.catalogue.iter().find(|p| p.name == name).map(|p| p.default)).unwrap_or(0.0)
    }

    /// Each joint's encoder bias in `params`.
    pub fn biases(&self, params: &Parameters) -> Vec<f64> {
        self.joints.iter().map(|j| self.value(params, &format!("{j}.bias"))).collect()
    }
}

/// For each of `joints`, the movable joints between it and the root.
fn ancestors(model: &RobotModel, joints: &[String]) -> Vec<Vec<usize>> {
    joints
        .iter()
        .map(|name| {
            let mut out = Vec::new();
            let mut link = model.joint(name).map(|j| j.parent);
            while let Some(parent) = link {
                let Some(up) = model.joints.iter().find(|j| j.child == parent) else { break };
                if let Some(i) = joints.iter().position(|n| *n == up.name) {
                    out.push(i);
                }
                link = Some(up.parent);
            }
            out
        })
        .collect()
}

/// What the controller sends, by physics step: at step `k`, `changes[k]` sets those joints'
/// commands (index into [`Rig::joints`]) before the step; a command holds until replaced.
#[derive(Clone, Debug, Default)]
pub struct Program {
    pub changes: Vec<Vec<(usize, MotorCommand)>>,
}

impl Program {
    pub fn steps(&self) -> usize {
        self.changes.len()
    }
}

/// What one arena's joints measured after each physics step: `[step][joint]`, in
/// [`Rig::joints`]' order, and before the first step (`start`).
#[derive(Clone, Debug, Default)]
pub struct Trajectory {
    pub start: Reading,
    pub steps: Vec<Reading>,
}

/// The joints' measured positions, speeds and efforts at one time.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Reading {
    pub position: Vec<f32>,
    pub velocity: Vec<f32>,
    pub effort: Vec<f32>,
}

impl Trajectory {
    /// The trajectory as a log's joint samples, every `dt` from 0: what the encoders read
    /// (the joints' positions plus `bias`), the speeds and the efforts.
    pub fn samples(&self, dt: f64, bias: &[f64]) -> Vec<JointSample> {
        std::iter::once(self.start.sample(0.0, bias))
            .chain(self.steps.iter().enumerate().map(|(k, r)| r.sample((k + 1) as f64 * dt, bias)))
            .collect()
    }
}

impl Reading {
    /// The reading as a log's joint sample at `time`: what the encoders read (the joints'
    /// positions plus `bias`), the speeds and the efforts.
    pub fn sample(&self, time: f64, bias: &[f64]) -> JointSample {
        JointSample {
            time,
            position: self.position.iter().zip(bias).map(|(&q, b)| q as f64 + b).collect(),
            velocity: self.velocity.iter().map(|&v| v as f64).collect(),
            effort: self.effort.iter().map(|&e| e as f64).collect(),
        }
    }
}

/// Runs `program` on one arena per parameter set (each the full set the twin runs with), the
/// joints started at `start` (by name); returns each arena's trajectory.
pub fn run(rig: &Rig, start: &[(String, f32)], program: &Program, sets: &[Parameters]) -> Vec<Trajectory> {
    let mut stand = Stand::new(rig, start, sets);
    let mut out: Vec<Trajectory> = (0..sets.len())
        .map(|a| Trajectory { start: stand.reading(a), steps: Vec::with_capacity(program.steps()) })
        .collect();
    for changes in &program.changes {
        for arena in 0..sets.len() {
            for &(j, command) in changes {
                stand.command(arena, j, command);
            }
        }
        stand.step();
        for (a, trajectory) in out.iter_mut().enumerate() {
            trajectory.steps.push(stand.reading(a));
        }
    }
    out
}

/// The rig on one arena per parameter set, stepped a physics step at a time: what [`run`]
/// replays a program on, and what a live stand-in for the robot steps in real time.
pub struct Stand {
    app: App,
    /// Per arena, the entities of [`Rig::joints`].
    joints: Vec<Vec<Entity>>,
    /// Per arena, its entity and its links' entities by name.
    arenas: Vec<(Entity, std::collections::HashMap<String, Entity>)>,
}

impl Stand {
    /// The rig's arenas built (one per set), the joints at `start` (by name).
    pub fn new(rig: &Rig, start: &[(String, f32)], sets: &[Parameters]) -> Self {
        let mut app = App::new();
        // A test stand is the lab's, not the robot's: its operator may place the joints (`place`).
        app.add_plugins(MinimalPlugins).add_plugins(SimPlugin { settings: rig.settings, supervisor: true });
        let (joints, arenas) =
            sets.iter().enumerate().map(|(index, params)| spawn(&mut app, rig, index, start, params)).unzip();
        // Start-up only: the world as built.
        app.update();
        Self { app, joints, arenas }
    }

    /// Adds a point mass of `mass` kg to `link` of `arena`, at `at` in the link's frame: a load
    /// the rig's model does not know (a payload on the flange).
    pub fn add_payload(&mut self, arena: usize, link: &str, mass: f32, at: Vec3) -> anyhow::Result<()> {
        use twinbots_sim::rapier::prelude::MassProperties;
        let (arena_entity, links) = &self.arenas[arena];
        let entity = *links.get(link).ok_or_else(|| anyhow::anyhow!("the rig has no link '{link}'"))?;
        let world = self.app.world_mut();
        let l = world.get::<twinbots_sim::Link>(entity).expect("a spawned link has a Link").clone();
        let mut physics = twinbots_sim::physics_in_mut(world, *arena_entity).expect("the stand grants the Supervisor");
        let body = physics.bodies.get_mut(l.body).ok_or_else(|| anyhow::anyhow!("link '{link}' has no body"))?;
        let point = l.offset * at;
        body.set_additional_mass_properties(MassProperties::new(point, mass, Vec3::splat(1e-6)), true);
        Ok(())
    }

    /// Puts `arena`'s joints at `positions` (in [`Rig::joints`]' order), at rest: the rig
    /// re-anchored to a robot that stands there. Each drive's reference moves with its joint,
    /// so a rig that stood settled under its load stands settled there.
    pub fn place(&mut self, arena: usize, positions: &[f32]) {
        let joints = self.joints[arena].clone();
        let before: Vec<f32> = self.reading(arena).position;
        let world = self.app.world_mut();
        let mut state: bevy::ecs::system::SystemState<twinbots_sim::Supervisor> =
            bevy::ecs::system::SystemState::new(world);
        let mut supervisor = state.get_mut(world).expect("the rig app has the Supervisor's resources");
        for (&joint, &q) in joints.iter().zip(positions) {
            supervisor.set_joint_position(joint, q);
        }
        state.apply(world);
        for ((&joint, &q), old) in joints.iter().zip(positions).zip(before) {
            if let Some(mut motor) = world.get_mut::<Motor>(joint) {
                motor.shift_reference(q - old);
            }
        }
    }

    /// Sets joint `joint`'s (index into [`Rig::joints`]) motor command in `arena`; a joint
    /// without a motor ignores it.
    pub fn command(&mut self, arena: usize, joint: usize, command: MotorCommand) {
        if let Some(mut motor) = self.app.world_mut().get_mut::<Motor>(self.joints[arena][joint]) {
            motor.command = command;
        }
    }

    /// One physics step of every arena.
    pub fn step(&mut self) {
        self.app.world_mut().run_schedule(PhysicsSubstep);
    }

    /// Where `arena`'s link `link` is now, in arena coordinates (`None`: no such link).
    pub fn link_pose(&self, arena: usize, link: &str) -> Option<twinbots_sim::rapier::prelude::Pose> {
        let world = self.app.world();
        let (arena_entity, links) = &self.arenas[arena];
        let l = world.get::<twinbots_sim::Link>(*links.get(link)?)?;
        let body = twinbots_sim::physics_in(world, *arena_entity)?.bodies.get(l.body)?;
        Some(*body.position() * l.offset)
    }

    /// The stand's world and `arena`'s entity: what a renderer draws the rig from.
    pub fn scene(&mut self, arena: usize) -> (&mut World, Entity) {
        (self.app.world_mut(), self.arenas[arena].0)
    }

    /// What `arena`'s joints measure now.
    pub fn reading(&self, arena: usize) -> Reading {
        let world = self.app.world();
        let mut r = Reading::default();
        for &e in &self.joints[arena] {
            let s = world.get::<JointState>(e).expect("every movable joint has a JointState");
            r.position.push(s.position);
            r.velocity.push(s.velocity);
            r.effort.push(s.effort);
        }
        r
    }
}

/// The entities of an arena's [`Rig::joints`], and the arena's entity with its links'.
type Spawned = (Vec<Entity>, (Entity, std::collections::HashMap<String, Entity>));

/// Spawns arena `index` with the rig on it, its joints set to `params`.
fn spawn(app: &mut App, rig: &Rig, index: usize, start: &[(String, f32)], params: &Parameters) -> Spawned {
    let world = app.world_mut();
    let entity = world.spawn_empty().id();
    let mut arena = Arena::new(index, 0, rig.settings.dt, rig.settings.gravity);
    let spawned = {
        let mut commands = world.commands();
        (rig.description.spawn)(&mut commands, entity, &mut arena, start)
    };
    world.flush();
    let entities: Vec<Entity> = rig
        .joints
        .iter()
        .map(|name| spawned.joint(name).unwrap_or_else(|| panic!("the rig spawned no joint '{name}'")))
        .collect();
    for &e in &entities {
        let joint = world.get::<Joint>(e).expect("a spawned joint has a Joint").clone();
        let mut dynamics = *world.get::<JointDynamics>(e).expect("a movable joint has JointDynamics");
        let mut motor = world.get::<Motor>(e).cloned();
        let privilege = world.resource::<twinbots_sim::SupervisorAccess>();
        apply_to_joint(arena.physics_mut(privilege), &joint, &mut dynamics, motor.as_mut(), params);
        world.entity_mut(e).insert(dynamics);
        if let Some(motor) = motor {
            world.entity_mut(e).insert(motor);
        }
    }
    world.entity_mut(entity).insert(arena);
    (entities, (entity, spawned.links))
}
