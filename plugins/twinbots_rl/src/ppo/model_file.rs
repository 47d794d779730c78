//! Saving and loading a model: `model.safetensors` (weights) and `model.json` (spaces,
//! normalisation, hyperparameters, counters, versions), each written atomically.

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};

use super::{Ppo, PpoConfig};
use crate::normalize::RunningMeanStd;
use crate::spaces::Space;

const FORMAT: u32 = 1;
pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const METADATA_FILE: &str = "model.json";

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("the model was trained for {what} {model}, but this robot has {robot}")]
    SpaceMismatch { what: &'static str, model: String, robot: String },
}

#[derive(Serialize, Deserialize)]
struct Metadata {
    format: u32,
    twinbots_version: String,
    algorithm: String,
    observation_space: Space,
    action_space: Space,
    hyperparameters: PpoConfig,
    obs_rms: Option<RunningMeanStd>,
    seed: u64,
    timesteps: u64,
    episodes: u64,
    updates: u64,
    recent_scores: Vec<f32>,
    #[serde(default)]
    recent_successes: Vec<f32>,
}

fn file_error(path: &Path, e: impl std::fmt::Display) -> ModelError {
    ModelError::File { path: path.to_path_buf(), message: e.to_string() }
}

/// Writes `bytes` to `path` through a temporary file and a rename, so a crash never leaves a
/// half-written file under the final name.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = path.with_extension("tmp");
    {
        use std::io::Write;
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
}

impl Ppo {
    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
        let tensors: HashMap<String, Tensor> = self
            .policy
            .named_vars()
            .into_iter()
            .map(|(name, var)| (name, var.as_tensor().clone()))
            .collect();
        let weights = dir.join(WEIGHTS_FILE);
        let tmp = weights.with_extension("tmp");
        candle_core::safetensors::save(&tensors, &tmp).map_err(|e| file_error(&tmp, e))?;
        std::fs::rename(&tmp, &weights).map_err(|e| file_error(&weights, e))?;
        let meta = Metadata {
            format: FORMAT,
            twinbots_version: env!("CARGO_PKG_VERSION").into(),
            algorithm: "PPO".into(),
            observation_space: self.observation_space.clone(),
            action_space: self.action_space.clone(),
            hyperparameters: self.config.clone(),
            obs_rms: self.obs_rms.clone(),
            seed: self.seed,
            timesteps: self.timesteps,
            episodes: self.episodes,
            updates: self.updates,
            recent_scores: self.recent_scores.iter().copied().collect(),
            recent_successes: self.recent_successes.iter().copied().collect(),
        };
        let json = serde_json::to_vec_pretty(&meta).map_err(|e| file_error(dir, e))?;
        let path = dir.join(METADATA_FILE);
        write_atomic(&path, &json).map_err(|e| file_error(&path, e))
    }

    /// Loads a model saved by [`Ppo::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Ppo, ModelError> {
        let dir = dir.as_ref();
        let path = dir.join(METADATA_FILE);
        let text = std::fs::read_to_string(&path).map_err(|e| file_error(&path, e))?;
        let meta: Metadata = serde_json::from_str(&text).map_err(|e| file_error(&path, e))?;
        if meta.format != FORMAT {
            return Err(file_error(&path, format!("model format {} (this build reads {FORMAT})", meta.format)));
        }
        let mut model = Ppo::new(meta.hyperparameters, meta.observation_space, meta.action_space, meta.seed)
            .map_err(|e| file_error(&path, e))?;
        let weights = dir.join(WEIGHTS_FILE);
        let tensors = candle_core::safetensors::load(&weights, &Device::Cpu).map_err(|e| file_error(&weights, e))?;
        model.policy.set_weights(&tensors).map_err(|e| file_error(&weights, e))?;
        model.obs_rms = meta.obs_rms;
        model.timesteps = meta.timesteps;
        model.episodes = meta.episodes;
        model.updates = meta.updates;
        model.recent_scores = VecDeque::from(meta.recent_scores);
        model.recent_successes = VecDeque::from(meta.recent_successes);
        Ok(model)
    }

    /// A clear error when this model cannot drive a robot with these spaces.
    pub fn check_spaces(&self, observation: &Space, action: &Space) -> Result<(), ModelError> {
        if observation.dim() != self.observation_space.dim() {
            return Err(ModelError::SpaceMismatch {
                what: "observations of dimension",
                model: self.observation_space.dim().to_string(),
                robot: observation.dim().to_string(),
            });
        }
        if action != &self.action_space {
            return Err(ModelError::SpaceMismatch {
                what: "actions",
                model: self.action_space.to_string(),
                robot: action.to_string(),
            });
        }
        Ok(())
    }
}
