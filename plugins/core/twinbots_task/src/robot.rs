//! Robots that describe themselves: each robot plugin says once what it is (its tasks with
//! their spaces and solved criteria, the design patterns it supports, its training defaults,
//! how cameras frame it) and how to build an app of it. Every front (the CLI, the RobotServer's
//! handshake, evaluation) reads that description from a [`Registry`]; none keeps its own copy.

use std::borrow::Cow;
use std::sync::Arc;

use bevy::prelude::*;
use twinbots_sim::urdf::RobotModel;
use twinbots_sim::{Arena, ArenaConfig, Framing, OperatorAccess, Parameters, SimPlugin, SimSettings, SpawnedRobot};

use twinbots_api::{DesignPattern, TaskSpec};

/// What an app is asked for: a task of the robot, under a design pattern, with N arenas.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AppRequest<'a> {
    pub task: &'a str,
    pub arenas: usize,
    pub seed: u64,
    pub pattern: DesignPattern,
}

/// Builds a headless app for a request the description allows. Under design pattern 3 it is a
/// robot process (no Supervisor): the caller inserts the server's address
/// (`twinbots_link::robot::ServerAddress`) before start-up. A closure, so that a robot read from
/// a file (`twinbots_arm`) builds from what it read.
pub type BuildApp = Arc<dyn Fn(&AppRequest) -> App + Send + Sync>;
/// A task's spaces and solved criterion, built from its terms (a closure, as [`BuildApp`]).
pub type SpecFn = Arc<dyn Fn() -> TaskSpec + Send + Sync>;
/// A robot's timing (a closure, as [`BuildApp`]).
pub type SettingsFn = Arc<dyn Fn() -> SimSettings + Send + Sync>;

/// A task of a robot's cell.
#[derive(Clone)]
pub struct TaskDescription {
    pub name: &'static str,
    pub description: &'static str,
    /// Its spaces and solved criterion, built from its terms.
    pub spec: SpecFn,
    /// Whether design pattern 3 runs this task (a robot process that homes itself).
    pub server: bool,
    /// A task with spaces of its own, which `train --task` learns with these defaults; `None`:
    /// the main task is learnt with the robot's defaults, any other task runs its model.
    pub training: Option<fn() -> TrainingDefaults>,
    /// A scripted controller of this task (its observation in, its action out), what
    /// `classic` names for it; the main task's is the robot's [`RobotDescription::feedback`]
    /// unless given here.
    pub scripted: Option<Feedback>,
}

impl std::fmt::Debug for TaskDescription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TaskDescription")
            .field("name", &self.name)
            .field("server", &self.server)
            .finish_non_exhaustive()
    }
}

/// How `train` trains the robot unless told otherwise, as RL Zoo's hyperparameter files do:
/// the algorithm it picks, the size of its evaluations, and, per algorithm the robot is tuned
/// for, the run's shape and the keys of the algorithm's `[<algo>]` table. The robot names
/// algorithms and keys only; the learners (`twinbots_learn`'s algorithm table) read them, so
/// a robot crate needs no learner.
#[derive(Clone, Debug)]
pub struct TrainingDefaults {
    /// The algorithm `train` uses without `--algo`.
    pub algo: &'static str,
    /// Episodes of an evaluation (periodic and final).
    pub eval_episodes: usize,
    /// The robot's tuning per algorithm; an algorithm without an entry runs on
    /// [`AlgoDefaults::new`]'s shape and the algorithm's own hyperparameters.
    pub algos: Vec<AlgoDefaults>,
}

impl Default for TrainingDefaults {
    fn default() -> Self {
        Self { algo: "ppo", eval_episodes: 10, algos: Vec::new() }
    }
}

impl TrainingDefaults {
    /// The robot's tuning of `algo` (lower case, as in `--algo`), or the plain shape.
    pub fn of(&self, algo: &'static str) -> AlgoDefaults {
        self.algos.iter().find(|a| a.algo == algo).cloned().unwrap_or_else(|| AlgoDefaults::new(algo))
    }
}

/// One algorithm's tuning for a robot.
#[derive(Clone, Debug)]
pub struct AlgoDefaults {
    /// The algorithm's name, lower case (`ppo`, `sac`).
    pub algo: &'static str,
    pub arenas: usize,
    /// Training budget (env steps summed over arenas).
    pub timesteps: u64,
    /// Periodic evaluation every this many of the algorithm's log rows (0: never).
    pub eval_every: usize,
    /// Keys of the algorithm's `[<algo>]` table, as TOML, over the algorithm's own defaults
    /// (RL Zoo's `hyperparams/<algo>.yml` entry for this env).
    pub hyperparams: &'static str,
}

impl AlgoDefaults {
    /// 8 arenas, a budget of a million steps, no periodic evaluation, the algorithm's own
    /// hyperparameters.
    pub fn new(algo: &'static str) -> Self {
        Self { algo, arenas: 8, timesteps: 1_000_000, eval_every: 0, hyperparams: "" }
    }

    /// The robot's hyperparameters for the algorithm: the keys of its `[<algo>]` table.
    pub fn keys(&self) -> anyhow::Result<toml::Table> {
        toml::from_str(self.hyperparams)
            .map_err(|e| anyhow::anyhow!("[{}] hyperparameters do not read: {}", self.algo, e.message()))
    }

    /// The algorithm's config `T` with this robot's hyperparameters over `T::default()`; an
    /// unknown key or a wrong value is an error naming the algorithm and the key.
    pub fn config<T: serde::Serialize + serde::de::DeserializeOwned + Default>(&self) -> anyhow::Result<T> {
        let mut table = toml::Table::try_from(T::default())?;
        table.extend(self.keys()?);
        table.try_into().map_err(|e: toml::de::Error| anyhow::anyhow!("[{}]: {}", self.algo, e.message()))
    }
}

/// A robot as its plugin describes it.
#[derive(Clone)]
pub struct RobotDescription {
    pub name: &'static str,
    pub description: &'static str,
    /// Its tasks; the first is the one `train` learns, the others run a model trained on it
    /// unchanged (the same spaces), such as the UR5e's pick-and-place driven by its reach model.
    pub tasks: Vec<TaskDescription>,
    /// The design patterns (paper §3) its in-process tasks support (1 and/or 2); pattern 3 is
    /// wherever a task says `server`.
    pub patterns: Vec<DesignPattern>,
    pub framing: Framing,
    pub defaults: TrainingDefaults,
    /// The twin's timing: its physics step and control step (`build` runs the app with them).
    pub settings: SettingsFn,
    pub build: BuildApp,
    /// The robot on a test stand, for robot logs: recording, replay and calibration (`None`:
    /// the robot does not support them).
    pub rig: Option<RigDescription>,
    /// The robot's classical feedback controller, if it has one: one observation of its main
    /// task in, that step's action out. What studies set learnt policies beside (`classic`).
    pub feedback: Option<Feedback>,
    /// How the robot's cell is laid out by a file (`None`: its cell is code only).
    pub cell: Option<CellDescription>,
}

impl std::fmt::Debug for RobotDescription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RobotDescription")
            .field("name", &self.name)
            .field("tasks", &self.tasks)
            .field("patterns", &self.patterns)
            .finish_non_exhaustive()
    }
}

/// A robot whose cell is data: its default layout file and how an app takes another.
#[derive(Clone, Copy, Debug)]
pub struct CellDescription {
    /// The default layout's TOML text (a file under `assets/cells`, compiled in).
    pub default: &'static str,
    /// Checks a layout's TOML text (errors name `file` and the entry) and makes it every
    /// arena's in `app`, before the app's start-up builds the cells.
    pub install: fn(app: &mut App, text: &str, file: &str) -> Result<(), String>,
}

/// A classical controller: an observation in, an action out. Shared, as it may hold its robot's
/// data (a robot file's arm: its chain and limits).
pub type Feedback = Arc<dyn Fn(&[f32]) -> Vec<f32> + Send + Sync>;

/// A robot alone on a test stand (no cell, no task): what `record`, `replay` and `identify`
/// drive with logged or generated commands, one parameter set per arena. Data, so a robot
/// file's arm has one as a built-in robot does.
#[derive(Clone)]
pub struct RigDescription {
    /// The robot's model (its URDF).
    pub model: Arc<dyn Fn() -> RobotModel + Send + Sync>,
    /// The twin's timing (the physics step is the rig's).
    pub settings: SimSettings,
    /// Nominal values of parameters beyond the URDF's `<dynamics>`, as a calibration file's
    /// TOML (`[parameters]`, `name = value`): the twin always runs with them (its plugin inserts
    /// them), and calibrations start there.
    pub nominal: Cow<'static, str>,
    /// Where a calibration starts, over `nominal` (same format): a robot's published orders of
    /// magnitude where the twin runs with lighter placeholders; empty: from `nominal`.
    pub prior: Cow<'static, str>,
    /// The parameters `identify` fits unless told which.
    pub fit: Vec<String>,
    /// Spawns the robot and what it stands on into an arena, its joints at the positions given
    /// (by name; the others where the rig starts them).
    pub spawn: RigSpawn,
    /// The commanded joints and how excitation moves them.
    pub excitation: Vec<JointExcitation>,
    /// The controller's command period, in physics steps.
    pub command_steps: u32,
}

/// How a rig spawns its robot: commands, the arena's entity, the arena, the joints' start.
pub type RigSpawn = Arc<dyn Fn(&mut Commands, Entity, &mut Arena, &[(String, f32)]) -> SpawnedRobot + Send + Sync>;

impl std::fmt::Debug for RigDescription {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RigDescription")
            .field("fit", &self.fit)
            .field("excitation", &self.excitation)
            .field("command_steps", &self.command_steps)
            .finish_non_exhaustive()
    }
}

/// How an excitation program may drive one joint: by speed, up to `speed` (rad/s or m/s),
/// and at most `travel` (rad or m) either side of where it starts. Joints on the same
/// `channel` get the same signal (a vehicle's wheels, so it drives straight).
#[derive(Clone, Debug)]
pub struct JointExcitation {
    pub joint: Cow<'static, str>,
    pub channel: u8,
    pub speed: f32,
    pub travel: f32,
}

impl RigDescription {
    /// The nominal parameters as a resource; a built-in table that does not read is a bug.
    pub fn nominal_parameters(&self) -> Parameters {
        nominal_parameters(&self.nominal)
    }

    /// Where a calibration starts: the nominal parameters with the prior's over them.
    pub fn prior_parameters(&self) -> Parameters {
        let mut out = self.nominal_parameters();
        if !self.prior.is_empty() {
            out.extend(&nominal_parameters(&self.prior));
        }
        out
    }
}

/// Parses a robot's built-in nominal parameters (a calibration file's `[parameters]`; none
/// for an empty text).
pub fn nominal_parameters(text: &str) -> Parameters {
    if text.trim().is_empty() {
        return Parameters::default();
    }
    crate::calibration::Calibration::parse(text)
        .map(|c| c.parameters)
        .expect("a robot's nominal parameters read (checked by the tests)")
}

impl RobotDescription {
    /// The task `train` learns.
    pub fn main_task(&self) -> &TaskDescription {
        &self.tasks[0]
    }

    /// How often the robot acts: its control step, in seconds (`welcome.task.control_period_s`).
    pub fn control_period_s(&self) -> f64 {
        f64::from((self.settings)().control_dt())
    }

    /// The spec of the task `train` learns.
    pub fn task(&self) -> TaskSpec {
        (self.main_task().spec)()
    }

    /// The named task `train` learns (`None`: the main one) and the defaults it is trained with:
    /// the main task's are the robot's, another's its own; a task that runs the main task's
    /// model is refused, naming the tasks that train.
    pub fn trained_task(&self, name: Option<&str>) -> anyhow::Result<(&TaskDescription, TrainingDefaults)> {
        let task = self.find_task(name)?;
        if task.name == self.main_task().name {
            return Ok((task, self.defaults.clone()));
        }
        let trainable = || {
            let mut names = vec![self.main_task().name];
            names.extend(self.tasks.iter().filter(|t| t.training.is_some()).map(|t| t.name));
            names.join(", ")
        };
        let training = task.training.ok_or_else(|| {
            anyhow::anyhow!(
                "{}'s task '{}' runs a model of its task '{}' and is not trained itself; tasks that train: {}",
                self.name,
                task.name,
                self.main_task().name,
                trainable()
            )
        })?;
        Ok((task, training()))
    }

    /// The named task's (`None`: the main one's) classical or scripted controller: its own
    /// [`TaskDescription::scripted`], else the robot's feedback for its main task.
    pub fn classic(&self, task: Option<&str>) -> anyhow::Result<Feedback> {
        let found = self.find_task(task)?;
        let main = found.name == self.main_task().name;
        found.scripted.clone().or_else(|| if main { self.feedback.clone() } else { None }).ok_or_else(|| {
            anyhow::anyhow!("{}'s task '{}' has no classical or scripted controller", self.name, found.name)
        })
    }

    pub fn task_names(&self) -> Vec<&'static str> {
        self.tasks.iter().map(|t| t.name).collect()
    }

    /// The named task (`None`: the main one); an unknown name lists the known ones.
    pub fn find_task(&self, name: Option<&str>) -> anyhow::Result<&TaskDescription> {
        let Some(name) = name else { return Ok(self.main_task()) };
        self.tasks.iter().find(|t| t.name == name).ok_or_else(|| {
            anyhow::anyhow!("{} has no task '{name}'; its tasks: {}", self.name, self.task_names().join(", "))
        })
    }

    /// Every design pattern some task of the robot supports.
    pub fn all_patterns(&self) -> Vec<DesignPattern> {
        let mut all = self.patterns.clone();
        if self.tasks.iter().any(|t| t.server) {
            all.push(DesignPattern::Server);
        }
        all
    }

    /// Whether the named task (`None`: the main one) runs under `pattern`.
    pub fn supports(&self, task: Option<&str>, pattern: DesignPattern) -> anyhow::Result<bool> {
        let task = self.find_task(task)?;
        Ok(match pattern {
            DesignPattern::Server => task.server,
            p => self.patterns.contains(&p),
        })
    }

    /// An error naming the supported patterns unless the named task (`None`: the main one)
    /// runs under `pattern`.
    pub fn check_supports(&self, task: Option<&str>, pattern: DesignPattern) -> anyhow::Result<()> {
        if self.supports(task, pattern)? {
            return Ok(());
        }
        let supported: Vec<String> = self.all_patterns().iter().map(|p| p.number().to_string()).collect();
        anyhow::bail!(
            "{} ({}) does not support design pattern {} (supported: {})",
            self.name,
            self.find_task(task)?.name,
            pattern.number(),
            supported.join(", ")
        )
    }

    /// A headless app of the named task (`None`: the main one) under `pattern`; an unknown
    /// task or an unsupported pattern is an error.
    pub fn app(&self, task: Option<&str>, arenas: usize, seed: u64, pattern: DesignPattern) -> anyhow::Result<App> {
        let description = self.find_task(task)?;
        self.check_supports(task, pattern)?;
        anyhow::ensure!(arenas > 0, "an app needs at least one arena");
        Ok((self.build)(&AppRequest { task: description.name, arenas, seed, pattern }))
    }
}

/// The robots a program knows. The application registers the built-in ones; a program (or a
/// test) can register its own beside them.
#[derive(Clone, Debug, Default)]
pub struct Registry {
    robots: Vec<RobotDescription>,
}

impl Registry {
    /// Adds a robot; a name already taken is an error.
    pub fn register(&mut self, robot: RobotDescription) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.robots.iter().all(|r| r.name != robot.name),
            "a robot named '{}' is already registered",
            robot.name
        );
        anyhow::ensure!(!robot.tasks.is_empty(), "robot '{}' has no task", robot.name);
        self.robots.push(robot);
        Ok(())
    }

    /// Registered robots, in registration order.
    pub fn robots(&self) -> &[RobotDescription] {
        &self.robots
    }

    /// Looks a robot up by name; the error lists the known ones.
    pub fn find(&self, name: &str) -> anyhow::Result<&RobotDescription> {
        self.robots.iter().find(|r| r.name == name).ok_or_else(|| {
            let known: Vec<&str> = self.robots.iter().map(|r| r.name).collect();
            anyhow::anyhow!("unknown robot '{name}'; known robots: {}", known.join(", "))
        })
    }
}

/// The headless app every robot builds on: Bevy's minimal plugins, the simulation with the
/// robot's timing (the Supervisor only outside pattern 3, where the lab operator is allowed
/// instead), the request's arenas, and the robot's own plugin.
pub fn headless_app(settings: SimSettings, request: &AppRequest, robot: impl Plugin) -> App {
    let server = request.pattern == DesignPattern::Server;
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(SimPlugin { settings, supervisor: !server })
        .insert_resource(ArenaConfig { count: request.arenas, seed: request.seed, first: 0 });
    if server {
        app.insert_resource(OperatorAccess);
    }
    app.add_plugins(robot);
    app
}
