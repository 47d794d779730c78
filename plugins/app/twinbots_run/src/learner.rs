//! The learner a run trains with (`algo` in its settings), found in `twinbots_learn::algos`:
//! made fresh, or taken from a run's newest checkpoint. Everything else about a run (the
//! callbacks, evaluation, the run directory) sees it as a `twinbots_learn::Agent`.

use std::path::PathBuf;

use twinbots_api::TaskSpec;
use twinbots_learn::{Learner, RunDir, algos};

use crate::settings::TrainSettings;

/// A new learner for the task `spec` (whose goal, if any, an algorithm with HER relabels with).
pub fn new(settings: &TrainSettings, spec: &TaskSpec) -> anyhow::Result<Box<dyn Learner>> {
    let algorithm = settings.algorithm()?;
    (algorithm.new)(&settings.table_of(algorithm.name)?, spec, settings.seed)
}

/// The newest checkpoint of `run` that loads, of the run's algorithm.
pub fn resume(run: &RunDir, settings: &TrainSettings, spec: &TaskSpec) -> anyhow::Result<(PathBuf, Box<dyn Learner>)> {
    let (dir, mut model) = algos::resume(run, settings.algorithm()?)?;
    model.set_goal(spec.goal)?;
    Ok((dir, model))
}

/// The model a run ended with (`model/`), else its newest checkpoint that loads: what more
/// training continues from.
pub fn trained(run: &RunDir, settings: &TrainSettings, spec: &TaskSpec) -> anyhow::Result<(PathBuf, Box<dyn Learner>)> {
    let (dir, mut model) = run.trained_with(settings.algorithm()?.load)?;
    model.set_goal(spec.goal)?;
    Ok((dir, model))
}

/// `--algo`'s value: a name of the algorithm table, or an error listing them.
pub fn parse_algo(name: &str) -> Result<String, String> {
    twinbots_learn::algos::find(name).map(|a| a.name.to_string()).map_err(|e| e.to_string())
}
