//! What the commands share about training runs: the env a model is evaluated on, the callbacks
//! `train` and `serve` train with, and the default run directory. The settings a run is made of
//! (its `config.toml`) are `twinbots::settings`, shared with the Python extension. It imports no
//! other command, so every command can import it.

use std::path::PathBuf;

use twinbots_learn::callbacks::{
    CheckpointCallback, EvalCallback, LearningCurveCallback, ProgressBarCallback, ProgressCsvCallback, StopTrainingOnSolved,
    TensorBoardCallback,
};
use twinbots_api::{DesignPattern, SolvedCriterion, VecEnv};
use twinbots_learn::{CallbackList, RunDir};
use twinbots_task::AppVecEnv;

pub use twinbots::settings::{ConfigFile, TrainSettings};

use crate::registry::RobotEntry;

/// The callbacks of a run into `run`, in order: `progress.csv`, TensorBoard scalars, the
/// progress bar (or lines), the stop on solved training episodes, periodic evaluation
/// (which may stop training too; into `evaluations.csv` and TensorBoard), checkpoints, and
/// the learning curve (last: it draws what the others wrote).
pub fn callbacks(settings: &TrainSettings, run: &RunDir, entry: &RobotEntry, title: String, solved: Option<SolvedCriterion>) -> anyhow::Result<CallbackList> {
    let events = run.event_writer()?;
    let mut callbacks = CallbackList::new()
        .with(ProgressCsvCallback::new(run.clone()))
        .with(TensorBoardCallback::new(events.clone()))
        .with(ProgressBarCallback::new(settings.timesteps)?);
    if let Some(criterion) = solved {
        callbacks.push(StopTrainingOnSolved::new(criterion));
    }
    if settings.eval_every > 0 {
        let (arenas, episodes, pattern) = (settings.arenas, settings.eval_episodes, settings.in_process_pattern()?);
        let robot = entry.clone();
        let make_env = move |seed: u64| -> anyhow::Result<Box<dyn VecEnv>> {
            Ok(Box::new(evaluation_env(&robot, None, arenas, episodes, seed, pattern)?))
        };
        let mut evaluation = EvalCallback::new(entry.main_task().name, make_env, settings.eval_every, episodes, settings.periodic_eval_seed())
            .log_to(run.clone())
            .events_to(events);
        if let Some(criterion) = solved {
            evaluation = evaluation.stop_when_solved(criterion);
        }
        callbacks.push(evaluation);
    }
    callbacks.push(CheckpointCallback::new(run.clone(), settings.checkpoint_every));
    callbacks.push(LearningCurveCallback::new(run.clone(), title, solved, settings.checkpoint_every));
    Ok(callbacks)
}

/// A fresh app of `arenas` arenas (no more than `episodes`) of the robot's `task` (`None`: its
/// own) to evaluate a model on.
pub fn evaluation_env(
    entry: &RobotEntry,
    task: Option<&str>,
    arenas: usize,
    episodes: usize,
    seed: u64,
    pattern: DesignPattern,
) -> anyhow::Result<AppVecEnv> {
    let arenas = arenas.clamp(1, episodes.max(1));
    Ok(AppVecEnv::new(entry.app(task, arenas, seed, pattern)?))
}

/// Default run directory: `runs/<robot>-<unix seconds>`.
pub fn default_run_dir(robot: &str) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    PathBuf::from("runs").join(format!("{robot}-{secs}"))
}
