//! What every run trains with and ends with, whoever drives its learner: its callbacks, the
//! evaluation envs (periodic, final, `twinbots eval`), and its end — the final model saved,
//! evaluated in-process into `eval.json` and summed up in `summary.json`.

use twinbots_api::{SolvedCriterion, VecEnv};
use twinbots_learn::callbacks::{
    CheckpointCallback, EvalCallback, LearningCurveCallback, ProgressBarCallback, ProgressCsvCallback,
    StopTrainingOnSolved, TensorBoardCallback,
};
use twinbots_learn::run_dir::{EVAL, Summary, TimeBreakdown};
use twinbots_learn::{Agent, CallbackList, EvalResult, RunDir, TrainingEnd, evaluate_policy};
use twinbots_task::AppVecEnv;

use crate::registry::RobotEntry;
use crate::settings::TrainSettings;

/// The end of a run: saves the final `model`, evaluates it in-process on the run's final
/// evaluation seed (a pattern-3 model under pattern 1: the same policy) into `eval.json`, and
/// writes `summary.json` (with the time breakdown when the simulation's share is known).
pub fn finish(
    settings: &TrainSettings,
    run: &RunDir,
    entry: &RobotEntry,
    model: &dyn Agent,
    end: &TrainingEnd,
    wall_s: f64,
    time: Option<TimeBreakdown>,
) -> anyhow::Result<(EvalResult, Summary)> {
    run.save_model(model)?;
    let seed = settings.final_eval_seed();
    let mut env = evaluation_env(
        entry,
        None,
        settings.arenas,
        settings.eval_episodes,
        seed,
        settings,
        &settings.calibration_parameters(),
    )?;
    let evaluation = evaluate_policy(settings.task_name(entry)?, model, &mut env, settings.eval_episodes, seed)?;
    run.write_json(EVAL, &evaluation)?;
    let mut summary = Summary::new(&settings.robot, settings.pattern, model, end, wall_s, Some(&evaluation));
    summary.time_breakdown = time;
    run.write_summary(&summary)?;
    Ok((evaluation, summary))
}

/// The callbacks of a run into `run`, in order: `progress.csv`, TensorBoard scalars, the
/// progress bar (or lines), the stop on solved training episodes, periodic evaluation
/// (which may stop training too; into `evaluations.csv` and TensorBoard), checkpoints, and
/// the learning curve (last: it draws what the others wrote).
pub fn callbacks(
    settings: &TrainSettings,
    run: &RunDir,
    entry: &RobotEntry,
    title: String,
    solved: Option<SolvedCriterion>,
) -> anyhow::Result<CallbackList> {
    let events = run.event_writer()?;
    let mut callbacks = CallbackList::new()
        .with(ProgressCsvCallback::new(run.clone()))
        .with(TensorBoardCallback::new(events.clone()))
        .with(ProgressBarCallback::new(settings.timesteps)?);
    if let Some(criterion) = solved {
        callbacks.push(StopTrainingOnSolved::new(criterion));
    }
    if settings.eval_every > 0 {
        let (arenas, episodes) = (settings.arenas, settings.eval_episodes);
        let (robot, run_settings) = (entry.clone(), settings.clone());
        let calibration = settings.calibration_parameters();
        let make_env = move |seed: u64| -> anyhow::Result<Box<dyn VecEnv>> {
            Ok(Box::new(evaluation_env(&robot, None, arenas, episodes, seed, &run_settings, &calibration)?))
        };
        let mut evaluation = EvalCallback::new(
            settings.task_name(entry)?,
            make_env,
            settings.eval_every,
            episodes,
            settings.periodic_eval_seed(),
        )
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

/// A fresh app of `arenas` arenas (no more than `episodes`) of the robot's `task` (`None`: the
/// run's own) to evaluate a run's model on: under the run's pattern (in this process), observing as
/// the run does, its twin calibrated with `calibration`.
pub fn evaluation_env(
    entry: &RobotEntry,
    task: Option<&str>,
    arenas: usize,
    episodes: usize,
    seed: u64,
    settings: &TrainSettings,
    calibration: &twinbots_sim::Parameters,
) -> anyhow::Result<AppVecEnv> {
    let arenas = arenas.clamp(1, episodes.max(1));
    Ok(AppVecEnv::new(evaluation_app(entry, task, arenas, seed, settings, calibration)?))
}

/// [`evaluation_env`]'s app before its start-up, `arenas` arenas: for callers that add to it first.
pub fn evaluation_app(
    entry: &RobotEntry,
    task: Option<&str>,
    arenas: usize,
    seed: u64,
    settings: &TrainSettings,
    calibration: &twinbots_sim::Parameters,
) -> anyhow::Result<bevy::app::App> {
    let mut app = entry.app(task.or(settings.task.as_deref()), arenas, seed, settings.in_process_pattern()?)?;
    twinbots_task::calibration::calibrate(&mut app, calibration);
    settings.observe(&mut app, entry, arenas)?;
    Ok(app)
}
