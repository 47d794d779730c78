//! A twin's run as robot logs (docs/logs.md): what arena 0's controller measured (its joints'
//! positions, speeds and efforts) and the commands its motors were given, every control step.
//! [`RobotLogPlugin`] is `--log FILE` of `eval`, `robot` and `capture`, and Python's
//! `make_vec(log=FILE)`; `twinbots replay` reads the file like a real robot's.
//!
//! A log is continuous motion. Under design patterns 1 and 2 a reset puts the robot back
//! without moving it there, which no replay of the commands could follow: there FILE holds
//! arena 0's latest episode, rewritten (atomically) as each one ends, and at the run's end with
//! the one then running ([`finish_log`]); an episode of no steps is not written. A pattern-3
//! robot homes itself with its own motors, as a real one does: its log is the whole run,
//! written when the run ends.

use std::path::PathBuf;

use bevy::prelude::*;
use twinbots_log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog};
use twinbots_sim::{Arena, InArena, Joint, JointState, Motor, MotorCommand, SimSet, SimSettings, physics::sim_started};
use twinbots_task::task::{EnvReset, ResetSet, Resetting};

/// Samples one arena's joints into a log, one control step at a time.
pub struct LogRecorder {
    /// The arena's movable joints, in the robot model's order.
    joints: Vec<Entity>,
    /// Control steps sampled, and the seconds of one.
    steps: u64,
    control: f64,
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
        let control = world.resource::<SimSettings>().control_seconds();
        let meta = LogMeta {
            robot: robot.to_string(),
            source: format!("twinbots {} twin", env!("CARGO_PKG_VERSION")),
            calibration: calibration.to_string(),
            control_period: control,
            extra: Default::default(),
        };
        let log = RobotLog { meta, joints: joints.iter().map(|(_, n)| n.clone()).collect(), ..Default::default() };
        let mut recorder = Self { joints: joints.into_iter().map(|(e, _)| e).collect(), steps: 0, control, log };
        recorder.sample_state(world, 0.0);
        recorder
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
        let start = self.steps as f64 * self.control;
        self.steps += 1;
        let mut command = CommandSample { time: start, joints: vec![], modes: vec![], values: vec![] };
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
        self.sample_state(world, self.steps as f64 * self.control);
    }

    /// Control steps sampled so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    pub fn finish(self) -> RobotLog {
        self.log
    }
}

/// Logs arena 0's episodes to `path` (see the module's docs).
#[derive(Clone)]
pub struct RobotLogPlugin {
    pub path: PathBuf,
    pub robot: String,
    /// The robot model's joint order (the log's).
    pub order: Vec<String>,
    /// The calibration file the twin runs with ("" for none), for the log's metadata.
    pub calibration: String,
}

impl RobotLogPlugin {
    /// The plugin for `robot`'s twin, its joints in the robot's own (rig's) order.
    /// The path must name an `.mcap` or `.csv` file.
    pub fn new(
        entry: &crate::registry::RobotEntry,
        path: PathBuf,
        calibration: Option<&std::path::Path>,
    ) -> anyhow::Result<Self> {
        twinbots_log::Format::of(&path)?;
        let order = twinbots_sysid::Rig::of(entry).map(|rig| rig.joints).unwrap_or_default();
        let calibration = calibration.map(|p| p.display().to_string()).unwrap_or_default();
        Ok(Self { path, robot: entry.name.to_string(), order, calibration })
    }
}

/// What [`RobotLogPlugin`] is logging and has done: the episode being recorded, the states and
/// commands of the last one written, and the first error writing one (logging stops there; the
/// run goes on, and [`finish_log`] returns it).
#[derive(Resource)]
pub struct RobotLogging {
    plugin: RobotLogPlugin,
    recorder: Option<LogRecorder>,
    pub last: Option<(usize, usize)>,
    pub error: Option<String>,
}

impl Plugin for RobotLogPlugin {
    fn build(&self, app: &mut App) {
        app.insert_resource(RobotLogging { plugin: self.clone(), recorder: None, last: None, error: None })
            .add_systems(Update, start_recording.before(SimSet::Radio).run_if(sim_started))
            .add_systems(Update, sample_step.after(SimSet::Sense).before(SimSet::Reset).run_if(sim_started))
            .add_systems(EnvReset, begin_episode.after(ResetSet::Observe));
    }
}

/// Arena 0's entity.
fn arena_zero(world: &mut World) -> Option<Entity> {
    world.query::<(Entity, &Arena)>().iter(world).find(|(_, a)| a.index == 0).map(|(e, _)| e)
}

/// Before a control step, with nothing recorded yet (no reset began an episode): the
/// recording starts from the state the robot is in.
fn start_recording(world: &mut World) {
    if world.resource::<RobotLogging>().recorder.is_some() || world.resource::<RobotLogging>().error.is_some() {
        return;
    }
    let Some(arena) = arena_zero(world) else { return };
    world.resource_scope(|world, mut logging: Mut<RobotLogging>| logging.begin(world, arena));
}

fn sample_step(world: &mut World) {
    world.resource_scope(|world, mut logging: Mut<RobotLogging>| {
        if let Some(recorder) = &mut logging.recorder {
            recorder.sample(world);
        }
    });
}

impl RobotLogging {
    /// Starts recording `arena` from the state it is in.
    fn begin(&mut self, world: &mut World, arena: Entity) {
        let plugin = &self.plugin;
        self.recorder = Some(LogRecorder::new(world, &plugin.robot, arena, &plugin.order, &plugin.calibration));
    }

    /// Writes the episode being recorded, if it has a step (the recorder is then done).
    fn write_current(&mut self) -> anyhow::Result<()> {
        if let Some(e) = &self.error {
            anyhow::bail!("{e}");
        }
        let Some(recorder) = self.recorder.take().filter(|r| r.steps() > 0) else { return Ok(()) };
        let log = recorder.finish();
        match twinbots_log::write(&log, &self.plugin.path) {
            Ok(()) => {
                self.last = Some((log.states.len(), log.commands.len()));
                Ok(())
            }
            Err(e) => {
                let e = format!("{e:#}");
                self.error = Some(e.clone());
                anyhow::bail!(e)
            }
        }
    }
}

/// At the end of a run: writes arena 0's running episode (if it had a step) and returns the
/// states and commands of the last episode written (`None`: none was), or logging's error.
pub fn finish_log(world: &mut World) -> anyhow::Result<Option<(usize, usize)>> {
    let Some(mut logging) = world.get_resource_mut::<RobotLogging>() else { return Ok(None) };
    logging.write_current()?;
    Ok(logging.last)
}

/// Arena 0 was reset: its episode so far is written (if it had a step), the next one begins.
fn begin_episode(world: &mut World) {
    let Some(arena) = arena_zero(world).filter(|&a| world.get::<Resetting>(a).is_some()) else { return };
    world.resource_scope(|world, mut logging: Mut<RobotLogging>| {
        if logging.error.is_some() {
            return;
        }
        if let Err(e) = logging.write_current() {
            eprintln!("warning: robot log not written, logging stops: {e:#}");
            return;
        }
        logging.begin(world, arena);
    });
}
