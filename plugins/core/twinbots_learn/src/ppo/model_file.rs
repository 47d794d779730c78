//! Saving and loading a model: `model.safetensors` (weights) and `model.json` (spaces,
//! normalisation, hyperparameters, counters, episode history, the action stream's position,
//! versions), and what a resumed run needs to go on exactly: `optimizer.safetensors` (Adam's
//! moments) and `env_state.json` (the envs' running episodes, `crate::replay`). Each file is
//! written atomically.

use std::collections::HashMap;
use std::path::Path;

use candle_core::Var;
use serde::{Deserialize, Serialize};

use super::{Ppo, PpoConfig};
use crate::model_dir::{SavedModel, load_model, save_model, saved_model_basics};
use crate::model_io::{self, METADATA_FILE, ModelError, OPTIMIZER_FILE, file_error};
use twinbots_api::env_state::StreamState;

/// PPO's own fields of `model.json`.
#[derive(Serialize, Deserialize)]
struct Own {
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

impl SavedModel for Ppo {
    saved_model_basics!(Ppo, PpoConfig);
    const FORMAT: u32 = 1;
    fn weights(&self) -> Vec<(String, Var)> {
        self.policy.named_vars()
    }
}

impl Ppo {
    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        save_model(self, dir.as_ref(), |dir| {
            let mut moments = HashMap::new();
            let optimizer_steps = model_io::moment_tensors(&self.optimizer, &self.weights(), &mut moments, dir)?;
            model_io::save_tensors(&moments, &dir.join(OPTIMIZER_FILE))?;
            Ok(Own {
                action_stream: Some(StreamState::of(&self.rng)),
                reward_scale: self.reward_scale.clone(),
                optimizer_steps,
            })
        })
    }

    /// Loads a model saved by [`Ppo::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Ppo, ModelError> {
        let dir = dir.as_ref();
        let path = dir.join(METADATA_FILE);
        let (mut model, own): (Ppo, Own) = load_model(dir)?;
        if let Some(scale) = &own.reward_scale {
            scale.check_finite().map_err(|e| file_error(&path, e))?;
        }
        if model.config.normalize_rewards {
            model.reward_scale = own.reward_scale.or(model.reward_scale);
        }
        if let Some(stream) = own.action_stream {
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
                own.optimizer_steps,
                &optimizer,
            )?;
        }
        Ok(model)
    }
}
