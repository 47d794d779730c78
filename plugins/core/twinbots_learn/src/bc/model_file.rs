//! Saving and loading a BC model, in the files of the others (`model_dir`): `model.safetensors`
//! (the policy), `model.json` (the header with the demonstrations' observation statistics, the
//! settings with the dataset's path, and the fields below), `optimizer.safetensors` (Adam's
//! moments, prefixed `policy.`). The dataset itself is not copied: a resumed run reads it again
//! from `bc.demos` (and refuses one that changed size); a model evaluates, exports and serves
//! without it.

use std::path::Path;

use serde::{Deserialize, Serialize};
use twinbots_api::env_state::StreamState;

use super::{Bc, BcConfig, POLICY};
use crate::model_dir::{SavedModel, load_model, save_model, saved_model_basics};
use crate::model_io::{self, METADATA_FILE, ModelError, file_error};

/// BC's own fields of `model.json`.
#[derive(Serialize, Deserialize)]
struct Own {
    gradient_steps: u64,
    /// The minibatches' stream.
    sampling_stream: StreamState,
    /// Adam's step count.
    optimizer_steps: [u64; 1],
    /// Frames of the dataset it learnt from (none before it learnt).
    demonstration_frames: Option<usize>,
}

impl SavedModel for Bc {
    saved_model_basics!(Bc, BcConfig);
    const FORMAT: u32 = 1;
    fn weights(&self) -> Vec<(String, candle_core::Var)> {
        Bc::weights(self)
    }
}

impl Bc {
    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        save_model(self, dir.as_ref(), |dir| {
            let steps = model_io::save_optimizers(vec![(POLICY, self.weights(), &self.optimizer)], dir)?;
            Ok(Own {
                gradient_steps: self.gradient_steps,
                sampling_stream: StreamState::of(&self.rng),
                optimizer_steps: [steps[0]],
                demonstration_frames: self.learnt_frames,
            })
        })
    }

    /// Loads a model saved by [`Bc::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Bc, ModelError> {
        let dir = dir.as_ref();
        let (mut model, own): (Bc, Own) = load_model(dir)?;
        model.gradient_steps = own.gradient_steps;
        model.rng = own.sampling_stream.to_rng().map_err(|e| file_error(&dir.join(METADATA_FILE), e))?;
        model.learnt_frames = own.demonstration_frames;
        let weights = model.weights();
        model_io::restore_optimizers(vec![(POLICY, weights, &mut model.optimizer)], &own.optimizer_steps, dir)?;
        Ok(model)
    }
}
