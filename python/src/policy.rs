//! `Policy`: a model that `twinbots train` wrote, for acting from Python exactly as Rust does.

use std::path::{Path, PathBuf};

use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray2, PyReadonlyArray2, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use twinbots_learn::Ppo;

use crate::convert::{no_panic, runtime_error, space_dict, value_error};

#[pyclass(unsendable, module = "twinbots._native")]
pub struct Policy {
    model: Ppo,
    /// The directory the weights came from.
    dir: PathBuf,
}

/// A run directory's final model (`model/`), else its newest checkpoint, else `path` itself if
/// it is a model directory; the same choice as `twinbots eval`.
fn model_dir(path: &Path) -> anyhow::Result<PathBuf> {
    if path.join("model").join("model.json").is_file() {
        return Ok(path.join("model"));
    }
    let newest_checkpoint = std::fs::read_dir(path.join("checkpoints")).ok().and_then(|entries| {
        let mut dirs: Vec<PathBuf> = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("model.json").is_file() && p.join("model.safetensors").is_file())
            .collect();
        dirs.sort();
        dirs.pop()
    });
    if let Some(dir) = newest_checkpoint {
        return Ok(dir);
    }
    if path.join("model.json").is_file() {
        return Ok(path.to_path_buf());
    }
    anyhow::bail!("{}: no model (expected a run directory of `twinbots train`, with model/ or checkpoints/)", path.display())
}

#[pymethods]
impl Policy {
    #[new]
    fn new(path: PathBuf) -> PyResult<Self> {
        let dir = model_dir(&path).map_err(value_error)?;
        let model = no_panic("loading the model", || Ok(Ppo::load(&dir)?)).map_err(runtime_error)?;
        Ok(Self { model, dir })
    }

    #[getter]
    fn path(&self) -> PathBuf {
        self.dir.clone()
    }

    #[getter]
    fn observation_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, &self.model.observation_space)
    }

    #[getter]
    fn action_space<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        space_dict(py, &self.model.action_space)
    }

    /// Actions for a batch of observations `(batch, obs_dim)` (float32), as `(batch,
    /// action_dim)` float32: the policy's mean (deterministic) or a sample, normalised and
    /// clipped as in Rust.
    #[pyo3(signature = (obs, deterministic=true))]
    fn predict<'py>(&mut self, py: Python<'py>, obs: PyReadonlyArray2<'py, f32>, deterministic: bool) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let (rows, cols) = (obs.shape()[0], obs.shape()[1]);
        let dim = self.model.observation_space.dim();
        if cols != dim {
            return Err(value_error(anyhow::anyhow!("observations have {cols} values, the model expects {dim}")));
        }
        let flat = obs.as_array().iter().copied().collect::<Vec<f32>>();
        if flat.iter().any(|x| !x.is_finite()) {
            return Err(value_error(anyhow::anyhow!("observations contain NaN or infinity")));
        }
        let model = &mut self.model;
        let actions = no_panic("predict", || {
            if deterministic { model.predict_deterministic(&flat) } else { model.predict(&flat, false) }
        })
        .map_err(runtime_error)?;
        let action_dim = actions.len() / rows.max(1);
        let array = Array2::from_shape_vec((rows, action_dim), actions).map_err(|e| runtime_error(e.into()))?;
        Ok(array.into_pyarray(py))
    }
}
