//! The Rust side of `python/benchmarks/vec_env_speed.py`: the same arenas stepped by a plain
//! Rust loop, so the Python layer's overhead can be measured against them.

use std::time::Instant;

use numpy::PyReadonlyArray2;
use pyo3::prelude::*;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_task::AppVecEnv;

use crate::convert::{OnThisThread, no_panic, runtime_error, value_error};

/// `RustLoop(robot, num_envs, actions, seed=0)`: `robot`'s arenas, reset with `seed`, stepped
/// by a Rust loop with the given actions, one row `(num_envs × action_dim)` per step, cycled.
/// `run(steps)` steps on from where the last call stopped and returns the seconds the steps
/// took, so a benchmark can alternate short blocks of it with blocks of the Python env (a
/// shared VM's speed drifts over seconds: blocks of milliseconds see the same machine).
#[pyclass(unsendable)]
pub struct RustLoop {
    env: Option<AppVecEnv>,
    rows: Vec<Vec<f32>>,
    next_row: usize,
}

#[pymethods]
impl RustLoop {
    #[new]
    #[pyo3(signature = (robot, num_envs, actions, seed=0))]
    fn new(
        py: Python<'_>,
        robot: &str,
        num_envs: usize,
        actions: PyReadonlyArray2<'_, f32>,
        seed: u64,
    ) -> PyResult<Self> {
        let entry = twinbots_run::registry::find(robot).map_err(value_error)?;
        let rows: Vec<Vec<f32>> = actions.as_array().rows().into_iter().map(|r| r.to_vec()).collect();
        if rows.is_empty() {
            return Err(value_error(anyhow::anyhow!("need at least one action row")));
        }
        let app = entry.app(None, num_envs, seed, DesignPattern::Supervised).map_err(value_error)?;
        let app = OnThisThread(app);
        let env = py
            .detach(move || {
                let app = app;
                no_panic("bench", || {
                    let mut env = AppVecEnv::new(app.0);
                    env.reset(Some(seed))?;
                    Ok(OnThisThread(env))
                })
            })
            .map_err(runtime_error)?;
        Ok(Self { env: Some(env.0), rows, next_row: 0 })
    }

    /// Steps `steps` times with the GIL released; returns the seconds they took.
    fn run(&mut self, py: Python<'_>, steps: usize) -> PyResult<f64> {
        let env =
            OnThisThread(self.env.as_mut().ok_or_else(|| runtime_error(anyhow::anyhow!("a step failed earlier")))?);
        let (rows, first) = (&self.rows, self.next_row);
        let result = py.detach(move || {
            let env = env;
            no_panic("bench", || {
                let start = Instant::now();
                for t in first..first + steps {
                    env.0.step(&rows[t % rows.len()])?;
                }
                Ok(start.elapsed().as_secs_f64())
            })
        });
        self.next_row = (first + steps) % self.rows.len();
        if result.is_err() {
            self.env = None;
        }
        result.map_err(runtime_error)
    }
}
