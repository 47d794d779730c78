//! `Policy`: a model that `twinbots train` wrote, for acting from Python exactly as Rust does.

use std::path::PathBuf;

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use twinbots_learn::{Learner, algos};

use crate::convert::{no_panic, runtime_error, space_dict, value_error};

#[pyclass(unsendable, module = "twinbots._native")]
pub struct Policy {
    model: Box<dyn Learner>,
    /// The directory the weights came from.
    dir: PathBuf,
}

#[pymethods]
impl Policy {
    #[new]
    fn new(path: PathBuf) -> PyResult<Self> {
        // The same choice as `twinbots eval`: the final model, else the newest checkpoint that
        // loads (a damaged one is passed over), of whichever algorithm saved it.
        let (dir, model) = no_panic("loading the model", || algos::load_path(&path)).map_err(value_error)?;
        Ok(Self { model, dir })
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.dir.clone()
    }

    /// The algorithm that trained it, as its model file says (`"PPO"`, `"SAC"`, `"TD3"`).
    #[getter]
    fn algorithm(&self) -> &'static str {
        self.model.algorithm()
    }

    #[getter]
    fn observation_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, self.model.observation_space())
    }

    #[getter]
    fn action_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, self.model.action_space())
    }

    /// Actions for a batch of observations `(batch, obs_dim)` (float32), as `(batch,
    /// action_dim)` float32: the policy's mean (deterministic) or a sample, normalised and
    /// clipped as in Rust.
    #[pyo3(signature = (obs, deterministic=true))]
    fn predict<'py>(
        &mut self,
        py: Python<'py>,
        obs: PyReadonlyArray2<'py, f32>,
        deterministic: bool,
    ) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (rows, cols) = (obs.shape()[0], obs.shape()[1]);
        let dim = self.model.observation_space().dim();
        if cols != dim {
            return Err(value_error(anyhow::anyhow!("observations have {cols} values, the model expects {dim}")));
        }
        let flat = obs.as_array().iter().copied().collect::<Vec<f32>>();
        if flat.iter().any(|x| !x.is_finite()) {
            return Err(value_error(anyhow::anyhow!("observations contain NaN or infinity")));
        }
        let model = &mut self.model;
        let actions = no_panic("predict", || model.predict(&flat, deterministic)).map_err(runtime_error)?;
        let action_dim = actions.len() / rows.max(1);
        let array = Array2::from_shape_vec((rows, action_dim), actions).map_err(|e| runtime_error(e.into()))?;
        Ok(array.into_pyarray(py))
    }
}
