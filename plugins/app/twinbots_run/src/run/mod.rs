//! One training run, whoever drives its learner (`twinbots train`, `twinbots serve`, Python's
//! hand-over): a [`Run`] is made fresh ([`Run::create`]), taken up from its newest checkpoint
//! ([`Run::resume`]) or given more steps ([`Run::extend`]); then it trains in this process on
//! its arenas ([`Run::train`]) or hosted by a RobotServer that robots reach over the network
//! ([`Run::host`]); either way it trains with the same callbacks and ends the same way
//! ([`finish`]: the final model, `eval.json`, `summary.json`).

mod evaluation;
mod hosted;
mod in_process;

use std::path::{Path, PathBuf};

use twinbots_api::{DesignPattern, TaskSpec};
use twinbots_learn::callbacks::GradientStepTally;
use twinbots_learn::{CallbackList, Learner, RunDir};

pub use self::evaluation::{callbacks, evaluation_app, evaluation_env, finish};
pub use self::hosted::Hosting;

use crate::learner;
use crate::registry::{self, RobotEntry};
use crate::settings::TrainSettings;

/// A run about to train: its settings, its directory, its robot, its task and its learner.
pub struct Run {
    pub settings: TrainSettings,
    pub dir: RunDir,
    pub entry: RobotEntry,
    /// The task the learner learns (`settings.task`, observed as `[pixels]` says).
    pub spec: TaskSpec,
    pub learner: Box<dyn Learner>,
    /// Taken up from a checkpoint or a final model: the rows logged after it are dropped once
    /// everything is checked, just before training.
    pub resumed: bool,
    /// Callbacks called after the run's own (tests use them to fail an update on purpose).
    pub extra_callbacks: CallbackList,
}

impl Run {
    /// A fresh run of `settings` into `out`. Everything that can be checked before it runs is
    /// (the pattern the robot supports for the task, the learner), so an error leaves no run
    /// directory behind; a directory that already holds a run is refused.
    pub fn create(settings: TrainSettings, out: &Path) -> anyhow::Result<Self> {
        let entry = registry::find(&settings.robot)?;
        entry.check_supports(settings.task.as_deref(), settings.design_pattern()?)?;
        anyhow::ensure!(settings.arenas > 0, "arenas must be at least 1");
        let spec = settings.task(&entry)?;
        let learner = learner::new(&settings, &spec)?;
        let dir = create(&settings, out)?;
        Ok(Self { settings, dir, entry, spec, learner, resumed: false, extra_callbacks: CallbackList::new() })
    }

    /// The run in `dir`, from its newest checkpoint that loads, with its counters; and that
    /// checkpoint's path.
    pub fn resume(dir: &Path) -> anyhow::Result<(Self, PathBuf)> {
        let dir = RunDir::new(dir);
        let settings = TrainSettings::of_run(&dir)?;
        let entry = registry::find(&settings.robot)?;
        let spec = settings.task(&entry)?;
        let (checkpoint, learner) = learner::resume(&dir, &settings, &spec)?;
        dir.check_progress_columns(learner.train_figures())?;
        let run = Self { settings, dir, entry, spec, learner, resumed: true, extra_callbacks: CallbackList::new() };
        Ok((run, checkpoint))
    }

    /// The run in `dir`, to train `more` steps beyond its model (its final one, else its newest
    /// checkpoint); its `config.toml` records the new budget before anything runs. After a final
    /// model the envs start fresh episodes (a checkpoint's are replayed, as [`Run::resume`]'s
    /// are); the run's stop criteria still apply (a solved run stops at its next check). Also
    /// the path of the model it continues from.
    pub fn extend(dir: &Path, more: u64) -> anyhow::Result<(Self, PathBuf)> {
        anyhow::ensure!(more >= 1, "--timesteps {more}: must be at least 1 more step");
        let dir = RunDir::new(dir);
        let mut settings = TrainSettings::of_run(&dir)?;
        anyhow::ensure!(
            settings.design_pattern()? != DesignPattern::Server,
            "{}: more training of a pattern-3 run is not supported yet; `train --resume` without --timesteps finishes one",
            dir.path().display()
        );
        let entry = registry::find(&settings.robot)?;
        let spec = settings.task(&entry)?;
        let (source, learner) = learner::trained(&dir, &settings, &spec)?;
        dir.check_progress_columns(learner.train_figures())?;
        settings.timesteps = learner.timesteps() + more;
        settings.validate()?;
        dir.write_config(&settings)?;
        let run = Self { settings, dir, entry, spec, learner, resumed: true, extra_callbacks: CallbackList::new() };
        Ok((run, source))
    }

    /// The run's callbacks ([`callbacks`]) under `title`, then its extra ones, and a tally of
    /// the gradient steps they saw (checked at the end).
    fn callbacks(&mut self, title: String) -> anyhow::Result<(CallbackList, GradientStepTally)> {
        let mut list = callbacks(&self.settings, &self.dir, &self.entry, title, self.spec.solved)?;
        let tally = GradientStepTally::default();
        list.push(tally.clone());
        if !self.extra_callbacks.is_empty() {
            list.push(std::mem::take(&mut self.extra_callbacks));
        }
        Ok((list, tally))
    }

    /// Drops what was logged after the learner's checkpoint (a resumed run redoes it): called
    /// once everything is checked, just before training.
    fn truncate_if_resumed(&self) -> anyhow::Result<()> {
        if self.resumed {
            self.dir.truncate_after(self.learner.timesteps())?;
        }
        Ok(())
    }
}

/// Makes the run directory `out` for `settings` (`config.toml` written); a directory that
/// already holds a run is refused.
pub fn create(settings: &TrainSettings, out: &Path) -> anyhow::Result<RunDir> {
    let run = RunDir::new(out);
    anyhow::ensure!(
        !run.holds_run(),
        "{} already holds a run (resume it with --resume, or choose another --out)",
        out.display()
    );
    run.create()?;
    run.write_config(settings)?;
    Ok(run)
}

/// Who watches a run train: a window on arena 0, and/or the live view of every arena.
#[derive(Default)]
pub struct Watch {
    pub window: bool,
    pub live: Option<std::sync::Arc<twinbots_live::LiveServer>>,
}

/// Default run directory: `runs/<robot>-<unix seconds>` (a robot file by its name, `panda` for
/// `assets/robots/panda.toml`).
pub fn default_run_dir(robot: &str) -> PathBuf {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs());
    let robot = Path::new(robot).file_stem().map_or(robot.into(), |s| s.to_string_lossy());
    PathBuf::from("runs").join(format!("{robot}-{secs}"))
}

/// A panic's message, for the error that reports it.
fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
