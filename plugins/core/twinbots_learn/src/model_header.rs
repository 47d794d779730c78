//! What every `model.json` holds, whatever the algorithm (its own fields follow).

use std::path::Path;

use twinbots_api::spaces::Space;

use crate::history::EpisodeHistory;
use crate::model_io::{ModelError, file_error};
use crate::normalize::RunningMeanStd;

#[derive(serde::Serialize, serde::Deserialize)]
pub struct ModelHeader {
    pub format: u32,
    pub twinbots_version: String,
    pub algorithm: String,
    pub observation_space: Space,
    pub action_space: Space,
    pub obs_rms: Option<RunningMeanStd>,
    pub seed: u64,
    pub timesteps: u64,
    pub episodes: u64,
    pub updates: u64,
    /// Whether `env_state.json` was saved beside it (a checkpoint's running episodes): a
    /// model that says so and lacks the file is incomplete (absent in older models: unchecked).
    #[serde(default)]
    pub env_state: bool,
    #[serde(flatten)]
    pub history: EpisodeHistory,
}

impl ModelHeader {
    /// An error unless the observation statistics are finite.
    pub fn check(&self, path: &Path) -> Result<(), ModelError> {
        match &self.obs_rms {
            Some(rms) => rms.check_finite().map_err(|e| file_error(path, e)),
            None => Ok(()),
        }
    }
}
