//! Rust values as Python ones: errors as exceptions, spaces, episode summaries, the registry.

use std::panic::{AssertUnwindSafe, catch_unwind};

use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use twinbots_api::{EpisodeSummary, Space, TaskSpec};
use twinbots_task::RobotDescription;

/// The app moves into `py.detach` (which needs `Send`) while the GIL is released. A Bevy `App`
/// is not `Send` (its runner is a plain boxed closure), but `detach` runs the closure on this
/// same thread, and `Arenas` is `unsendable` (pyo3 refuses to use it from any other thread),
/// so the app never leaves the thread that built it.
pub struct OnThisThread<T>(pub T);
unsafe impl<T> Send for OnThisThread<T> {}

/// A failure of the simulation (or of loading a file) as a `RuntimeError` with its whole cause
/// chain.
pub fn runtime_error(e: anyhow::Error) -> PyErr {
    PyRuntimeError::new_err(format!("{e:#}"))
}

/// What the caller asked for is wrong: a `ValueError`.
pub fn value_error(e: anyhow::Error) -> PyErr {
    PyValueError::new_err(format!("{e:#}"))
}

/// Runs `f`, turning a panic into an error so that it never unwinds into the interpreter
/// (pyo3 would raise `PanicException`, which `except Exception` does not catch).
pub fn no_panic<T>(what: &str, f: impl FnOnce() -> anyhow::Result<T>) -> anyhow::Result<T> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(result) => result,
        Err(payload) => {
            let reason = payload
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown panic".into());
            Err(anyhow::anyhow!("{what} failed: {reason}"))
        }
    }
}

/// `{"kind": "box", "low": [...], "high": [...]}`, `{"kind": "discrete", "n": n}`,
/// `{"kind": "multi_discrete", "nvec": [...]}` or `{"kind": "image", "shape": (h, w, c)}`; Python builds the Gymnasium space from it.
pub fn space_dict<'py>(py: Python<'py>, space: &Space) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    match space {
        Space::Box { low, high } => {
            d.set_item("kind", "box")?;
            d.set_item("low", low.clone())?;
            d.set_item("high", high.clone())?;
        }
        Space::Discrete { n } => {
            d.set_item("kind", "discrete")?;
            d.set_item("n", *n)?;
        }
        Space::MultiDiscrete { nvec } => {
            d.set_item("kind", "multi_discrete")?;
            d.set_item("nvec", nvec.clone())?;
        }
        Space::Image { height, width, channels } => {
            d.set_item("kind", "image")?;
            d.set_item("shape", (*height, *width, *channels))?;
        }
        Space::ImageAndState { height, width, channels, low, high } => {
            d.set_item("kind", "image_and_state")?;
            d.set_item("shape", (*height, *width, *channels))?;
            d.set_item("low", low.clone())?;
            d.set_item("high", high.clone())?;
        }
    }
    Ok(d)
}

/// The task's promise: spaces, value names, reward terms, solved criterion.
pub fn task_dict<'py>(py: Python<'py>, spec: &TaskSpec) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("name", &spec.name)?;
    d.set_item("observation_space", space_dict(py, &spec.observation_space)?)?;
    d.set_item("action_space", space_dict(py, &spec.action_space)?)?;
    d.set_item("observation_names", spec.observation_names.clone())?;
    d.set_item("reward_terms", spec.reward_terms.clone())?;
    match &spec.solved {
        Some(s) => {
            let solved = PyDict::new(py);
            solved.set_item("window", s.window)?;
            solved.set_item("threshold", s.threshold)?;
            solved.set_item("measure", format!("{:?}", s.measure).to_lowercase())?;
            d.set_item("solved", solved)?;
        }
        None => d.set_item("solved", py.None())?,
    }
    Ok(d)
}

/// A finished episode: score, length, success (None for tasks without a goal), the task's
/// figures (`metrics`) and each reward term's sum (`rewards`).
pub fn episode_dict<'py>(py: Python<'py>, e: &EpisodeSummary) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("score", e.score)?;
    d.set_item("length", e.length)?;
    d.set_item("success", e.success)?;
    d.set_item("metrics", e.metrics.clone())?;
    d.set_item("rewards", e.rewards.clone())?;
    Ok(d)
}

pub fn robot_dict<'py>(py: Python<'py>, r: &RobotDescription) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("name", r.name)?;
    d.set_item("description", r.description)?;
    let tasks: Vec<(&str, &str)> = r.tasks.iter().map(|t| (t.name, t.description)).collect();
    d.set_item("tasks", tasks)?;
    let patterns: Vec<u8> = r.patterns.iter().map(|p| p.number()).collect();
    d.set_item("patterns", patterns)?;
    Ok(d)
}
