//! Saving and loading a model: `model.safetensors` (weights) and `model.json` (spaces,
//! normalisation, hyperparameters, counters, episode history, the action stream's position,
//! versions), and what a resumed run needs to go on exactly: `optimizer.safetensors` (Adam's
//! moments) and `env_state.json` (the envs' running episodes, `crate::replay`). Each file is
//! written atomically.

use std::collections::HashMap;
use std::path::Path;

use candle_core::Tensor;
use serde::{Deserialize, Serialize};

use super::{Ppo, PpoConfig};
use crate::model_header::ModelHeader;
use crate::model_io::{self, METADATA_FILE, ModelError, OPTIMIZER_FILE, WEIGHTS_FILE, file_error};
use twinbots_api::env_state::StreamState;

const FORMAT: u32 = 1;

#[derive(Serialize, Deserialize)]
struct Metadata {
    #[serde(flatten)]
    header: ModelHeader,
    hyperparameters: PpoConfig,
    /// Where the action-sampling and minibatch stream stands (absent in older models: it
    /// restarts from the seed).
    #[serde(default)]
    action_stream: Option<StreamState>,
    /// The reward scaling's statistics and running returns (`normalize_rewards`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    reward_scale: Option<super::RewardScale>,
    /// Adam's step count (its moments are in `optimizer.safetensors`).
    #[serde(default)]
    optimizer_steps: u64,
}

impl Ppo {
    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
        let named = self.policy.named_vars();
        model_io::save_tensors(&model_io::var_tensors(&named), &dir.join(WEIGHTS_FILE))?;
        let mut moments = HashMap::new();
        let optimizer_steps = model_io::moment_tensors(&self.optimizer, &named, &mut moments, dir)?;
        model_io::save_tensors(&moments, &dir.join(OPTIMIZER_FILE))?;
        model_io::save_env_state(dir, self.state.env_state.as_ref())?;
        let meta = Metadata {
            header: self.state.header(super::SAVED_AS, FORMAT),
            hyperparameters: self.config.clone(),
            action_stream: Some(StreamState::of(&self.rng)),
            reward_scale: self.reward_scale.clone(),
            optimizer_steps,
        };
        model_io::save_metadata(dir, &meta)
    }

    /// Loads a model saved by [`Ppo::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Ppo, ModelError> {
        let dir = dir.as_ref();
        let path = dir.join(METADATA_FILE);
        let meta: Metadata = model_io::load_metadata(dir, super::SAVED_AS, FORMAT)?;
        let h = meta.header;
        h.check(&path)?;
        let saved_env_state = h.env_state;
        let mut model = Ppo::new(meta.hyperparameters, h.observation_space.clone(), h.action_space.clone(), h.seed)
            .map_err(|e| file_error(&path, e))?;
        let weights = dir.join(WEIGHTS_FILE);
        let tensors: HashMap<String, Tensor> = model_io::load_tensors(&weights)?;
        model.policy.set_weights(&tensors).map_err(|e| file_error(&weights, e))?;
        model.state.take_saved(h);
        if let Some(scale) = &meta.reward_scale {
            scale.check_finite().map_err(|e| file_error(&path, e))?;
        }
        if model.config.normalize_rewards {
            model.reward_scale = meta.reward_scale.or(model.reward_scale);
        }
        if let Some(stream) = meta.action_stream {
            model.rng = stream.to_rng().map_err(|e| file_error(&path, e))?;
        }
        // Older models have no optimiser file: Adam then starts afresh.
        let optimizer = dir.join(OPTIMIZER_FILE);
        if optimizer.is_file() {
            let moments = model_io::load_tensors(&optimizer)?;
            model_io::restore_moments(
                &mut model.optimizer,
                &model.policy.named_vars(),
                &moments,
                meta.optimizer_steps,
                &optimizer,
            )?;
        }
        model.state.env_state = model_io::load_env_state(dir, saved_env_state)?;
        Ok(model)
    }
}
