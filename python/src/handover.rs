//! Run directories written from Python (the RLlib path, `twinbots.rllib`): the robot's
//! training defaults, `config.toml`, `progress.csv` rows, the learning curve, and a policy
//! trained elsewhere saved as a twinbots model, so that `twinbots eval`, `load_policy` and the
//! rest of the project read it like one `twinbots train` wrote.

use std::collections::HashMap;
use std::path::PathBuf;

use numpy::{PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use twinbots_rl::callbacks::draw_learning_curve;
use twinbots_rl::normalize::RunningMeanStd;
use twinbots_rl::{Measure, Ppo, RunDir, UpdateStats};

use crate::convert::{runtime_error, space_dict, value_error};

/// The robot's tuned settings: `{"ppo": {...}, "arenas", "timesteps", "action_space",
/// "solved": {"measure": "score"|"success", "threshold", "window"} | None}`; the action space
/// is `task`'s (default: the main task's), the solved criterion the main task's.
#[pyfunction]
#[pyo3(signature = (robot, task=None))]
pub fn training_defaults<'py>(py: Python<'py>, robot: &str, task: Option<&str>) -> PyResult<Bound<'py, PyDict>> {
    let entry = twinbots::registry::find(robot).map_err(value_error)?;
    let spec = (entry.find_task(task).map_err(value_error)?.spec)();
    let d = PyDict::new(py);
    d.set_item("action_space", space_dict(py, &spec.action_space)?)?;
    let ppo = serde_json::to_string(&entry.defaults.ppo).map_err(|e| runtime_error(e.into()))?;
    d.set_item("ppo", py.import("json")?.call_method1("loads", (ppo,))?)?;
    d.set_item("arenas", entry.defaults.arenas)?;
    d.set_item("timesteps", entry.defaults.timesteps)?;
    let solved = entry.task().solved.map(|c| {
        let measure = match c.measure {
            Measure::Score => "score",
            Measure::Success => "success",
        };
        (measure, c.threshold, c.window)
    });
    match solved {
        Some((measure, threshold, window)) => {
            let s = PyDict::new(py);
            s.set_item("measure", measure)?;
            s.set_item("threshold", threshold)?;
            s.set_item("window", window)?;
            d.set_item("solved", s)?;
        }
        None => d.set_item("solved", py.None())?,
    }
    Ok(d)
}

/// Creates `run_dir` with the `config.toml` of a pattern-1 run of `robot` (its training
/// defaults; `arenas` = env runners × envs per runner), as `twinbots train` writes it.
#[pyfunction]
pub fn create_run(run_dir: PathBuf, robot: &str, seed: u64, arenas: usize, timesteps: u64) -> PyResult<()> {
    let entry = twinbots::registry::find(robot).map_err(value_error)?;
    let run = RunDir::new(&run_dir);
    if run.holds_run() {
        return Err(value_error(anyhow::anyhow!("{} already holds a run", run_dir.display())));
    }
    run.create().map_err(runtime_error)?;
    // The fields of the CLI's `TrainSettings` (src/cli/runs.rs); `twinbots eval` parses them
    // back, which the Python tests check.
    let mut settings = toml::Table::new();
    settings.insert("robot".into(), robot.into());
    settings.insert("timesteps".into(), (timesteps as i64).into());
    settings.insert("arenas".into(), (arenas as i64).into());
    settings.insert("seed".into(), (seed as i64).into());
    settings.insert("pattern".into(), 1.into());
    settings.insert("checkpoint_every".into(), 10.into());
    settings.insert("eval_every".into(), 0.into());
    settings.insert("eval_episodes".into(), (entry.defaults.eval_episodes as i64).into());
    // RLlib's minibatch is at most its train batch (n_steps × arenas); so is the run's.
    let mut ppo = entry.defaults.ppo.clone();
    ppo.batch_size = ppo.batch_size.min(ppo.n_steps * arenas.max(1));
    let ppo = toml::Table::try_from(&ppo).map_err(|e| runtime_error(e.into()))?;
    settings.insert("ppo".into(), ppo.into());
    run.write_config(&settings).map_err(runtime_error)
}

/// Appends a row to the run's `progress.csv`; `row` holds any of its columns by name (the
/// rest stay empty as NaN or 0), an unknown name is an error.
#[pyfunction]
pub fn append_progress(run_dir: PathBuf, row: HashMap<String, f64>) -> PyResult<()> {
    let nan = f32::NAN;
    let mut s = UpdateStats {
        mean_reward: nan, min_reward: nan, max_reward: nan, mean_length: nan, success_rate: nan,
        policy_loss: nan, value_loss: nan, entropy: nan, approx_kl: nan, clip_fraction: nan,
        learning_rate: f64::NAN, steps_per_s: nan,
        ..Default::default()
    };
    for (name, value) in row {
        let v = value as f32;
        match name.as_str() {
            "update" => s.update = value as usize,
            "timesteps" => s.timesteps = value as u64,
            "episodes" => s.episodes = value as u64,
            "mean_reward" => s.mean_reward = v,
            "min_reward" => s.min_reward = v,
            "max_reward" => s.max_reward = v,
            "mean_length" => s.mean_length = v,
            "policy_loss" => s.policy_loss = v,
            "value_loss" => s.value_loss = v,
            "entropy" => s.entropy = v,
            "approx_kl" => s.approx_kl = v,
            "clip_fraction" => s.clip_fraction = v,
            "learning_rate" => s.learning_rate = value,
            "steps_per_s" => s.steps_per_s = v,
            "success_rate" => s.success_rate = v,
            other => return Err(value_error(anyhow::anyhow!("progress.csv has no column '{other}'"))),
        }
    }
    RunDir::new(run_dir).append_progress(&s).map_err(runtime_error)
}

/// Draws the run's `learning_curve.png` from its `progress.csv`, with the robot's solved
/// criterion, as `twinbots train` does.
#[pyfunction]
pub fn draw_curve(run_dir: PathBuf, robot: &str, title: &str) -> PyResult<()> {
    let entry = twinbots::registry::find(robot).map_err(value_error)?;
    draw_learning_curve(&RunDir::new(run_dir), title, entry.task().solved).map_err(runtime_error)
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
    let entry = twinbots::registry::find(robot).map_err(value_error)?;
    let spec = (entry.find_task(task).map_err(value_error)?.spec)();
    let mut config = entry.defaults.ppo.clone();
    config.normalize_observations = obs_mean.is_some();
    let mut model = Ppo::new(config, spec.observation_space.clone(), spec.action_space.clone(), seed).map_err(runtime_error)?;
    let expected: Vec<String> = model.policy.named_vars().into_iter().map(|(n, _)| n).collect();
    for name in weights.keys() {
        if !expected.contains(name) {
            return Err(value_error(anyhow::anyhow!("unknown tensor '{name}'; the model has {}", expected.join(", "))));
        }
    }
    for (name, var) in model.policy.named_vars() {
        let array = weights.get(&name).ok_or_else(|| value_error(anyhow::anyhow!("missing tensor '{name}'")))?;
        let shape: Vec<usize> = array.shape().to_vec();
        if shape != var.shape().dims() {
            return Err(value_error(anyhow::anyhow!("tensor '{name}' has shape {shape:?}, the model needs {:?}", var.shape().dims())));
        }
        let values: Vec<f32> = array.as_array().iter().copied().collect();
        let tensor = candle_core::Tensor::from_vec(values, var.shape(), var.device()).map_err(|e| runtime_error(e.into()))?;
        var.set(&tensor).map_err(|e| runtime_error(e.into()))?;
    }
    model.obs_rms = match (obs_mean, obs_var) {
        (Some(mean), Some(var)) => {
            let dim = spec.observation_space.dim();
            if mean.len() != dim || var.len() != dim {
                return Err(value_error(anyhow::anyhow!("observation statistics of {} and {} values; the task has {dim} observations", mean.len(), var.len())));
            }
            Some(RunningMeanStd { mean, var, count: obs_count.unwrap_or(1.0) })
        }
        (None, None) => None,
        _ => return Err(value_error(anyhow::anyhow!("give both obs_mean and obs_var, or neither"))),
    };
    model.timesteps = timesteps;
    model.episodes = episodes;
    RunDir::new(run_dir).save_model(&model).map_err(runtime_error)
}
