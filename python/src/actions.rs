//! The checks every action passes before an arena sees it. They run here rather than in Python
//! because a loop over a few floats costs nanoseconds in Rust and microseconds in numpy calls,
//! and the Python layer's overhead per step is what users pay.

use numpy::{Element, PyArrayDyn, PyArrayMethods};
use pyo3::prelude::*;
use twinbots_api::Space;

/// The values of `actions`, a numpy array of float32, float64, int64 or int32 of any shape
/// (the Python side has checked it), in row-major order as float32 (what numpy's
/// `astype(np.float32)` gives). Each dtype is tried by a type check, not by extraction, whose
/// failures build Python errors: that cost more than the numpy calls it replaces.
pub fn action_values(actions: &Bound<'_, PyAny>) -> PyResult<Vec<f32>> {
    fn values<T: Element + Copy>(a: &Bound<'_, PyArrayDyn<T>>, to_f32: impl Fn(T) -> f32) -> PyResult<Vec<f32>> {
        Ok(a.try_readonly()?.as_array().iter().map(|&v| to_f32(v)).collect())
    }
    if let Ok(a) = actions.cast::<PyArrayDyn<f32>>() {
        values(a, |v| v)
    } else if let Ok(a) = actions.cast::<PyArrayDyn<i64>>() {
        values(a, |v| v as f32)
    } else if let Ok(a) = actions.cast::<PyArrayDyn<f64>>() {
        values(a, |v| v as f32)
    } else if let Ok(a) = actions.cast::<PyArrayDyn<i32>>() {
        values(a, |v| v as f32)
    } else {
        Err(pyo3::exceptions::PyTypeError::new_err("actions must be a numpy array of float32, float64, int64 or int32"))
    }
}

/// Refuses NaN and infinite values and choices that are fractional or out of range (naming the
/// env), and clips box actions to their bounds (as Stable-Baselines3 does before stepping).
pub fn check_and_clip(space: &Space, actions: &mut [f32]) -> anyhow::Result<()> {
    let dim = space.dim();
    for (i, a) in actions.iter_mut().enumerate() {
        let (env, k) = (i / dim, i % dim);
        anyhow::ensure!(a.is_finite(), "action of env {env} is {a} (NaN or infinite)");
        match space {
            Space::Box { low, high } => *a = a.clamp(low[k], high[k]),
            Space::Discrete { n } => choice(*a, *n, env, space)?,
            Space::MultiDiscrete { nvec } => choice(*a, nvec[k], env, space)?,
            Space::Image { .. } => choice(*a, 256, env, space)?,
            // No task acts with images: the image's values are whole numbers, the rest as given.
            Space::ImageAndState { .. } if k < dim - space.state_dim() => choice(*a, 256, env, space)?,
            Space::ImageAndState { .. } => {}
        }
    }
    Ok(())
}

fn choice(a: f32, n: usize, env: usize, space: &Space) -> anyhow::Result<()> {
    anyhow::ensure!(a.fract() == 0.0, "action of env {env} is {a}: actions of {space} must be whole numbers");
    anyhow::ensure!(a >= 0.0 && (a as usize) < n, "action {a} of env {env} is out of {space}");
    Ok(())
}
