//! Saving and loading a model: `model.safetensors` (weights) and `model.json` (spaces,
//! normalisation, hyperparameters, counters, episode history, the action stream's position,
//! versions), and what a resumed run needs to go on exactly: `optimizer.safetensors` (Adam's
//! moments) and `env_state.json` (the envs' running episodes, `crate::replay`). Each file is
//! written atomically.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};

use super::{Ppo, PpoConfig};
use crate::normalize::RunningMeanStd;
use crate::replay::{EnvState, StreamState};
use crate::spaces::Space;

const FORMAT: u32 = 1;
pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const METADATA_FILE: &str = "model.json";
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
pub const ENV_STATE_FILE: &str = "env_state.json";

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
    #[serde(default)]
    recent_lengths: Vec<f32>,
    #[serde(default)]
    recent_metrics: BTreeMap<String, Vec<f32>>,
    /// Where the action-sampling and minibatch stream stands (absent in older models: it
    /// restarts from the seed).
    #[serde(default)]
    action_stream: Option<StreamState>,
    /// Adam's step count (its moments are in `optimizer.safetensors`).
    #[serde(default)]
    optimizer_steps: u64,
}

fn file_error(path: &Path, e: impl std::fmt::Display) -> ModelError {
    ModelError::File { path: path.to_path_buf(), message: e.to_string() }
}

/// Writes tensors as safetensors to `path` through a temporary file and a rename.
fn save_tensors(tensors: &HashMap<String, Tensor>, path: &Path) -> Result<(), ModelError> {
    let tmp = path.with_extension("tmp");
    candle_core::safetensors::save(tensors, &tmp).map_err(|e| file_error(&tmp, e))?;
    std::fs::rename(&tmp, path).map_err(|e| file_error(path, e))
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
        save_tensors(&tensors, &dir.join(WEIGHTS_FILE))?;
        let (first, second, optimizer_steps) = self.optimizer.moments();
        let mut moments = HashMap::new();
        for (((name, var), m), v) in self.policy.named_vars().into_iter().zip(first).zip(second) {
            let shape = var.shape().clone();
            let tensor = |x: &Vec<f32>| Tensor::from_vec(x.clone(), shape.clone(), &Device::Cpu).map_err(|e| file_error(dir, e));
            moments.insert(format!("m.{name}"), tensor(m)?);
            moments.insert(format!("v.{name}"), tensor(v)?);
        }
        save_tensors(&moments, &dir.join(OPTIMIZER_FILE))?;
        let env_state = dir.join(ENV_STATE_FILE);
        match &self.env_state {
            Some(state) => {
                let json = serde_json::to_vec(state).map_err(|e| file_error(&env_state, e))?;
                write_atomic(&env_state, &json).map_err(|e| file_error(&env_state, e))?;
            }
            None => {
                let _ = std::fs::remove_file(&env_state);
            }
        }
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
            recent_lengths: self.recent_lengths.iter().copied().collect(),
            recent_metrics: self.recent_metrics.iter().map(|(k, v)| (k.clone(), v.iter().copied().collect())).collect(),
            action_stream: Some(StreamState::of(&self.rng)),
            optimizer_steps,
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
        model.recent_lengths = VecDeque::from(meta.recent_lengths);
        model.recent_metrics = meta.recent_metrics.into_iter().map(|(k, v)| (k, VecDeque::from(v))).collect();
        if let Some(stream) = meta.action_stream {
            model.rng = stream.to_rng().map_err(|e| file_error(&path, e))?;
        }
        if let Some(rms) = &model.obs_rms {
            let finite = rms.mean.iter().chain(&rms.var).all(|x| x.is_finite()) && rms.count.is_finite();
            if !finite {
                return Err(file_error(&path, "the observation statistics are not finite: the model is unusable"));
            }
        }
        // Older models have no optimiser file: Adam then starts afresh.
        let optimizer = dir.join(OPTIMIZER_FILE);
        if optimizer.is_file() {
            let moments = candle_core::safetensors::load(&optimizer, &Device::Cpu).map_err(|e| file_error(&optimizer, e))?;
            let named = model.policy.named_vars();
            let take = |prefix: &str| -> Result<Vec<Vec<f32>>, ModelError> {
                named
                    .iter()
                    .map(|(name, _)| {
                        let t = moments.get(&format!("{prefix}.{name}")).ok_or_else(|| file_error(&optimizer, format!("missing tensor '{prefix}.{name}'")))?;
                        t.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|e| file_error(&optimizer, e))
                    })
                    .collect()
            };
            let (first, second) = (take("m")?, take("v")?);
            model.optimizer.restore_moments(first, second, meta.optimizer_steps).map_err(|e| file_error(&optimizer, e))?;
        }
        let env_state = dir.join(ENV_STATE_FILE);
        if env_state.is_file() {
            let text = std::fs::read_to_string(&env_state).map_err(|e| file_error(&env_state, e))?;
            model.env_state = Some(serde_json::from_str::<EnvState>(&text).map_err(|e| file_error(&env_state, e))?);
        }
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
