//! The algorithms, in one table (RL Zoo's `ALGOS`): the only place an algorithm is named.
//! Training, resuming, loading, evaluating, exporting, serving, the settings' `[<algo>]` tables
//! and Python's `load_policy` all find an algorithm here, by its name or by what its models
//! say they are. A new algorithm is a folder defining its [`Algorithm`] and a line below.

use std::path::{Path, PathBuf};

use crate::learner::{Algorithm, Learner};
use crate::model_io::{METADATA_FILE, ModelError, file_error};
use crate::run_dir::RunDir;

pub const ALGOS: &[Algorithm] =
    &[crate::ppo::ALGORITHM, crate::sac::ALGORITHM, crate::td3::ALGORITHM, crate::bc::ALGORITHM];

/// The algorithm named `name` (lower case, as `--algo` takes it); an unknown name is an error
/// listing the known ones.
pub fn find(name: &str) -> anyhow::Result<&'static Algorithm> {
    ALGOS
        .iter()
        .find(|a| a.name == name)
        .ok_or_else(|| anyhow::anyhow!("unknown algorithm '{name}'; known: {}", names().join(", ")))
}

/// The names `--algo` takes.
pub fn names() -> Vec<&'static str> {
    ALGOS.iter().map(|a| a.name).collect()
}

/// The algorithm whose models say `saved_as` in `model.json`.
fn saved(saved_as: &str, path: &Path) -> Result<&'static Algorithm, ModelError> {
    ALGOS.iter().find(|a| a.saved_as == saved_as).ok_or_else(|| {
        let known: Vec<&str> = ALGOS.iter().map(|a| a.saved_as).collect();
        file_error(path, format!("algorithm '{saved_as}' is unknown to this build (it reads {})", known.join(", ")))
    })
}

/// The algorithm a saved model was trained with (its `model.json`'s `algorithm`).
pub fn saved_algorithm(dir: &Path) -> Result<&'static Algorithm, ModelError> {
    #[derive(serde::Deserialize)]
    struct Header {
        algorithm: String,
    }
    let path = dir.join(METADATA_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| file_error(&path, e))?;
    let header: Header = serde_json::from_str(&text).map_err(|e| file_error(&path, e))?;
    saved(&header.algorithm, &path)
}

/// Loads a model of whichever algorithm saved it.
pub fn load_agent(dir: &Path) -> Result<Box<dyn Learner>, ModelError> {
    (saved_algorithm(dir)?.load)(dir)
}

/// A run's trained model, of whichever algorithm: its final model, else its newest checkpoint
/// that loads (a damaged one is reported and passed over). The algorithm is the one the final
/// model, else the newest checkpoint whose `model.json` reads, names.
pub fn load_run(run: &RunDir) -> anyhow::Result<Box<dyn Learner>> {
    Ok(load_run_from(run)?.1)
}

/// [`load_run`], with the directory the model came from.
pub fn load_run_from(run: &RunDir) -> anyhow::Result<(PathBuf, Box<dyn Learner>)> {
    let algorithm = run
        .saved_models()
        .iter()
        .find_map(|dir| saved_algorithm(dir).ok())
        .ok_or_else(|| anyhow::anyhow!("{}: no model or checkpoint that reads", run.path().display()))?;
    run.trained_with(algorithm.load)
}

/// The newest checkpoint of `run` that loads, as `algorithm` (the run's): to resume from.
pub fn resume(run: &RunDir, algorithm: &Algorithm) -> anyhow::Result<(PathBuf, Box<dyn Learner>)> {
    run.newest_checkpoint_with(algorithm.load)
}

/// A model directory's model, or a run directory's trained model ([`load_run`]), with the
/// directory it came from (what Python's `load_policy` takes).
pub fn load_path(path: &Path) -> anyhow::Result<(PathBuf, Box<dyn Learner>)> {
    let run = RunDir::new(path);
    if run.saved_models().iter().any(|dir| dir.join(METADATA_FILE).is_file()) {
        return load_run_from(&run);
    }
    anyhow::ensure!(
        path.join(METADATA_FILE).is_file(),
        "{}: no model (expected a run directory of `twinbots train`, with model/ or checkpoints/, or a model directory)",
        path.display()
    );
    Ok((path.to_path_buf(), load_agent(path)?))
}

#[cfg(test)]
mod tests {
    use crate::PpoConfig;
    use crate::agent::Agent;
    use crate::callbacks::{Callback, CallbackList};
    use crate::ppo::Ppo;
    use crate::stats::{Flow, SolvedBy, TrainingEnd, UpdateStats};
    use twinbots_api::spaces::Space;

    #[test]
    fn every_callback_of_a_list_runs_and_the_first_to_stop_says_why() {
        let model =
            Ppo::new(PpoConfig::default(), Space::uniform_box(2, -1.0, 1.0), Space::Discrete { n: 2 }, 0).unwrap();
        let calls = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
        let counter = |answer: Flow| {
            let calls = calls.clone();
            move |_: &UpdateStats, _: &dyn Agent| {
                calls.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                Ok(answer)
            }
        };
        let mut list = CallbackList::new()
            .with(counter(Flow::Continue))
            .with(counter(Flow::Solved(SolvedBy::Evaluation)))
            .with(counter(Flow::Stop));
        let flow = list.on_update(&UpdateStats::default(), &model).unwrap();
        assert_eq!(flow, Flow::Solved(SolvedBy::Evaluation));
        assert_eq!(calls.load(std::sync::atomic::Ordering::Relaxed), 3);
        let end = TrainingEnd::after(flow, 640).unwrap();
        assert_eq!(end.to_string(), "solved (evaluation) after 640 steps");
    }
}
