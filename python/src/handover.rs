//! Run directories written from Python (the RLlib path, `twinbots.rllib`): the robot's
//! training defaults, `config.toml`, `progress.csv` rows, the learning curve, and a policy
//! trained elsewhere saved as a twinbots model, so that `twinbots eval`, `load_policy` and the
//! rest of the project read it like one `twinbots train` wrote.

use std::collections::HashMap;
use std::path::PathBuf;

use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use twinbots_api::Measure;
use twinbots_learn::callbacks::draw_learning_curve;
use twinbots_learn::normalize::RunningMeanStd;
use twinbots_learn::{Ppo, PpoConfig, RunDir, SolvedBy, TrainingEnd, ppo};
use twinbots_run::settings::{ConfigFile, TrainSettings};

use crate::convert::{runtime_error, space_dict, value_error};

/// The robot's tuned settings: `{"ppo": {...}, "arenas", "timesteps", "action_space",
/// "solved": {"measure": "score"|"success", "threshold", "window"} | None}`; the action space
/// is `task`'s (default: the main task's), the solved criterion the main task's.
#[pyfunction]
#[pyo3(signature = (robot, task=None))]
pub fn training_defaults<'py>(py: Python<'py>, robot: &str, task: Option<&str>) -> PyResult<Bound<'py, PyDict>> {
    let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
    let spec = (entry.find_task(task).map_err(value_error)?.spec)();
    let d = PyDict::new(py);
    d.set_item("action_space", space_dict(py, &spec.action_space)?)?;
    let defaults = entry.defaults.of(ppo::NAME);
    let config: PpoConfig = defaults.config().map_err(runtime_error)?;
    let ppo = serde_json::to_string(&config).map_err(|e| runtime_error(e.into()))?;
    d.set_item(ppo::NAME, py.import("json")?.call_method1("loads", (ppo,))?)?;
    d.set_item("arenas", defaults.arenas)?;
    d.set_item("timesteps", defaults.timesteps)?;
    match entry.task().solved {
        Some(c) => {
            let s = PyDict::new(py);
            s.set_item("measure", if c.measure == Measure::Score { "score" } else { "success" })?;
            s.set_item("threshold", c.threshold)?;
            s.set_item("window", c.window)?;
            d.set_item("solved", s)?;
        }
        None => d.set_item("solved", py.None())?,
    }
    Ok(d)
}

/// Creates `run_dir` with the `config.toml` of a pattern-1 run of `robot`: its training
/// defaults with `seed`, `arenas` (= env runners × envs per runner) and `timesteps`, resolved and
/// validated as `twinbots train` does (`twinbots_run::settings`).
#[pyfunction]
pub fn create_run(run_dir: PathBuf, robot: &str, seed: u64, arenas: usize, timesteps: u64) -> PyResult<()> {
    let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
    let run = RunDir::new(&run_dir);
    if run.holds_run() {
        return Err(value_error(anyhow::anyhow!("{} already holds a run", run_dir.display())));
    }
    // RLlib's minibatch is at most its train batch (n_steps × arenas); so is the run's.
    let tuned: PpoConfig = entry.defaults.of(ppo::NAME).config().map_err(runtime_error)?;
    let batch_size = tuned.batch_size.min(tuned.n_steps * arenas.max(1));
    let mut ppo = toml::Table::new();
    ppo.insert("batch_size".into(), (batch_size as i64).into());
    // RLlib runs make no periodic twinbots evaluations.
    let flags = ConfigFile {
        timesteps: Some(timesteps),
        arenas: Some(arenas),
        seed: Some(seed),
        pattern: Some(1),
        eval_every: Some(0),
        hyperparams: [(ppo::NAME.to_string(), toml::Value::Table(ppo))].into(),
        ..Default::default()
    };
    let settings = TrainSettings::resolve(&entry, ConfigFile::default(), flags).map_err(value_error)?;
    run.create().map_err(runtime_error)?;
    run.write_config(&settings).map_err(runtime_error)
}

/// Appends a row to the run's `progress.csv`; `row` holds any of its columns by name (the
/// rest stay empty as NaN or 0), an unknown name is an error.
#[pyfunction]
pub fn append_progress(run_dir: PathBuf, row: HashMap<String, f64>) -> PyResult<()> {
    // RLlib trains PPO: its rows carry PPO's figures.
    RunDir::new(run_dir).append_progress_columns(&row, ppo::TRAIN_FIGURES).map_err(value_error)
}

/// Drops the rows of the run's `progress.csv` (and `evaluations.csv`) logged after
/// `timesteps`, and rows cut short by a kill: a resumed run logs them again.
#[pyfunction]
pub fn truncate_progress(run_dir: PathBuf, timesteps: u64) -> PyResult<()> {
    RunDir::new(run_dir).truncate_after(timesteps).map_err(value_error)
}

/// Draws the run's `learning_curve.png` from its `progress.csv`, with the robot's solved
/// criterion, as `twinbots train` does.
#[pyfunction]
pub fn draw_curve(run_dir: PathBuf, robot: &str, title: &str) -> PyResult<()> {
    let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
    draw_learning_curve(&RunDir::new(run_dir), title, entry.task().solved).map_err(runtime_error)
}

/// Ends the run in `run_dir` as every twinbots run ends (`twinbots_run::run::finish`): its model
/// (`model/`) evaluated in-process into `eval.json` and summed up in `summary.json`; `solved`:
/// whether training stopped on the task's criterion, `wall_s` its wall-clock seconds. Returns
/// the evaluation's one-line description.
#[pyfunction]
pub fn finish_run(py: Python<'_>, run_dir: PathBuf, solved: bool, wall_s: f64) -> PyResult<String> {
    let run = RunDir::new(&run_dir);
    let settings = TrainSettings::of_run(&run).map_err(value_error)?;
    let entry = twinbots_run::registry::find(&settings.robot).map_err(value_error)?;
    py.detach(|| {
        let model = twinbots_learn::algos::load_run(&run)?;
        let timesteps = model.timesteps();
        let end = if solved {
            TrainingEnd::Solved { timesteps, by: SolvedBy::TrainingEpisodes }
        } else {
            TrainingEnd::BudgetSpent { timesteps }
        };
        let (evaluation, _) = twinbots_run::run::finish(&settings, &run, &entry, model.as_ref(), &end, wall_s, None)?;
        Ok(evaluation.describe())
    })
    .map_err(runtime_error)
}

/// Saves a policy trained outside twinbots as the run's model (`model/`): `weights` maps the
/// model's tensor names (`pi.0.weight`, …, `vf.2.bias`, `log_std` for box actions; see
/// docs/rllib.md) to float32 arrays; `obs_mean`/`obs_var`/`obs_count` are the observation
/// normaliser's statistics when the policy was trained on normalised observations.
#[pyfunction]
#[pyo3(signature = (run_dir, robot, task, weights, seed, timesteps, episodes, obs_mean=None, obs_var=None, obs_count=None))]
#[allow(clippy::too_many_arguments)]
pub fn save_model(
    run_dir: PathBuf,
    robot: &str,
    task: Option<&str>,
    weights: HashMap<String, PyReadonlyArrayDyn<'_, f32>>,
    seed: u64,
    timesteps: u64,
    episodes: u64,
    obs_mean: Option<Vec<f64>>,
    obs_var: Option<Vec<f64>>,
    obs_count: Option<f64>,
) -> PyResult<()> {
    let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
    let spec = (entry.find_task(task).map_err(value_error)?.spec)();
    let mut config: PpoConfig = entry.defaults.of(ppo::NAME).config().map_err(runtime_error)?;
    config.normalize_observations = obs_mean.is_some();
    let mut model =
        Ppo::new(config, spec.observation_space.clone(), spec.action_space.clone(), seed).map_err(runtime_error)?;
    let expected: Vec<String> = model.policy.named_vars().into_iter().map(|(n, _)| n).collect();
    for name in weights.keys() {
        if !expected.contains(name) {
            return Err(value_error(anyhow::anyhow!("unknown tensor '{name}'; the model has {}", expected.join(", "))));
        }
    }
    let tensors = weights
        .iter()
        .map(|(name, array)| {
            let values: Vec<f32> = array.as_array().iter().copied().collect();
            Ok((name.clone(), candle_core::Tensor::from_vec(values, array.shape(), &candle_core::Device::Cpu)?))
        })
        .collect::<anyhow::Result<HashMap<_, _>>>()
        .map_err(runtime_error)?;
    model.policy.set_weights(&tensors).map_err(value_error)?;
    model.state.obs_rms = match (obs_mean, obs_var) {
        (Some(mean), Some(var)) => {
            let dim = spec.observation_space.dim();
            if mean.len() != dim || var.len() != dim {
                return Err(value_error(anyhow::anyhow!(
                    "observation statistics of {} and {} values; the task has {dim} observations",
                    mean.len(),
                    var.len()
                )));
            }
            Some(RunningMeanStd { mean, var, count: obs_count.unwrap_or(1.0) })
        }
        (None, None) => None,
        _ => return Err(value_error(anyhow::anyhow!("give both obs_mean and obs_var, or neither"))),
    };
    model.state.timesteps = timesteps;
    model.state.episodes = episodes;
    RunDir::new(run_dir).save_model(&model).map_err(runtime_error)
}
