//! A twin's run as a robot log (docs/logs.md): what arena 0's controller measured (its joints'
//! positions, speeds and efforts) and the commands its motors were given, every control step.
//! `eval --log` writes one; `twinbots replay` reads it like a real robot's.

use bevy::prelude::*;
use twinbots_log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog};
use twinbots_sim::{InArena, Joint, JointState, Motor, MotorCommand, SimClock, SimSettings};

/// Samples one arena's joints into a log.
pub struct LogRecorder {
    arena: Entity,
    /// The simulated time (s) the log starts at.
    start: f64,
    /// The arena's movable joints, in the robot model's order.
    joints: Vec<Entity>,
    log: RobotLog,
}

impl LogRecorder {
    /// A recorder of `arena`'s robot joints, which start now (time 0 is this state), in the
    /// order of `order` (the robot's model; joints it does not name follow, by name).
    pub fn new(world: &mut World, robot: &str, arena: Entity, order: &[String], calibration: &str) -> Self {
        let mut joints: Vec<(Entity, String)> = world
            .query::<(Entity, &Joint, &InArena)>()
            .iter(world)
            .filter(|(_, _, a)| a.0 == arena)
            .map(|(e, j, _)| (e, j.name.clone()))
            .collect();
        joints.sort_by_key(|(_, name)| (order.iter().position(|n| n == name).unwrap_or(usize::MAX), name.clone()));
        let settings = *world.resource::<SimSettings>();
        let meta = LogMeta {
            robot: robot.to_string(),
            source: format!("twinbots {} twin", env!("CARGO_PKG_VERSION")),
            calibration: calibration.to_string(),
            control_period: settings.control_seconds(),
            extra: Default::default(),
        };
        let log = RobotLog { meta, joints: joints.iter().map(|(_, n)| n.clone()).collect(), ..Default::default() };
        let start = Self::time(world);
        let mut recorder = Self { arena, start, joints: joints.into_iter().map(|(e, _)| e).collect(), log };
        recorder.sample_state(world, 0.0);
        recorder
    }

    fn time(world: &World) -> f64 {
        world.resource::<SimClock>().control_steps as f64 * world.resource::<SimSettings>().control_seconds()
    }

    fn sample_state(&mut self, world: &World, time: f64) {
        let mut s = JointSample { time, position: vec![], velocity: vec![], effort: vec![] };
        for &e in &self.joints {
            let state = world.get::<JointState>(e).expect("a movable joint has a JointState");
            s.position.push(state.position as f64);
            s.velocity.push(state.velocity as f64);
            s.effort.push(state.effort as f64);
        }
        self.log.states.push(s);
    }

    /// After a control step: the commands it gave (at its start) and the state it ended in.
    pub fn sample(&mut self, world: &World) {
        let end = Self::time(world) - self.start;
        let step = world.resource::<SimSettings>().control_seconds();
        let mut command = CommandSample { time: end - step, joints: vec![], modes: vec![], values: vec![] };
        for (&e, name) in self.joints.iter().zip(&self.log.joints) {
            let (mode, value) = match world.get::<Motor>(e).map(|m| m.command) {
                Some(MotorCommand::Velocity(v)) => (CommandMode::Velocity, v),
                Some(MotorCommand::Position(p)) => (CommandMode::Position, p),
                Some(MotorCommand::Torque(t)) => (CommandMode::Torque, t),
                Some(MotorCommand::Off) | None => continue,
            };
            command.joints.push(name.clone());
            command.modes.push(mode);
            command.values.push(value as f64);
        }
        if !command.joints.is_empty() {
            self.log.commands.push(command);
        }
        self.sample_state(world, end);
    }

    /// The arena the recorder samples.
    pub fn arena(&self) -> Entity {
        self.arena
    }

    pub fn finish(self) -> RobotLog {
        self.log
    }
}
