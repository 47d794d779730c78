//! The Rust side of `python/bench.py`: the same arenas stepped by a plain Rust loop, so the
//! Python layer's overhead can be measured against them.

use std::time::Instant;

use numpy::PyReadonlyArray2;
use pyo3::prelude::*;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_task::AppVecEnv;

use crate::convert::{OnThisThread, no_panic, runtime_error, value_error};

/// Env steps per second (steps × envs / s) of `robot`'s arenas stepped in Rust with the given
/// actions, one row `(num_envs × action_dim)` per step, cycled for `steps` steps.
#[pyfunction]
#[pyo3(signature = (robot, num_envs, actions, steps, seed=0))]
pub fn rust_steps_per_second(
    py: Python<'_>,
    robot: &str,
    num_envs: usize,
    actions: PyReadonlyArray2<'_, f32>,
    steps: usize,
    seed: u64,
) -> PyResult<f64> {
    let entry = twinbots::registry::find(robot).map_err(value_error)?;
    let rows: Vec<Vec<f32>> = actions.as_array().rows().into_iter().map(|r| r.to_vec()).collect();
    if rows.is_empty() || steps == 0 {
        return Err(value_error(anyhow::anyhow!("need at least one action row and one step")));
    }
    let app = entry.app(None, num_envs, seed, DesignPattern::Supervised).map_err(value_error)?;
    let app = OnThisThread(app);
    py.detach(move || {
        let app = app;
        no_panic("bench", || {
            let mut env = AppVecEnv::new(app.0);
            env.reset(Some(seed))?;
            let start = Instant::now();
            for t in 0..steps {
                env.step(&rows[t % rows.len()])?;
            }
            Ok((steps * num_envs) as f64 / start.elapsed().as_secs_f64())
        })
    })
    .map_err(runtime_error)
}
