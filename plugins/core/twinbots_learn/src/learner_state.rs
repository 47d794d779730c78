//! What every learner keeps alike, whatever its algorithm: the spaces it learns on, its
//! observation normaliser, its seed, its counters, its last episodes, where its envs stood at its
//! last row (for an exact resume), and where its time went. Held once as a [`LearnerState`]
//! (the `state` field of `Ppo`, `Sac`, `Td3`), saved as the header of every `model.json`
//! ([`ModelHeader`]), and read by [`crate::agent::Agent`]'s accessors.

use twinbots_api::EnvState;
use twinbots_api::spaces::Space;

use crate::history::EpisodeHistory;
use crate::model_header::ModelHeader;
use crate::normalize::RunningMeanStd;
use crate::stats::TrainingTimes;

#[derive(Clone, Debug)]
pub struct LearnerState {
    pub observation_space: Space,
    pub action_space: Space,
    /// Observation statistics, when the learner normalises observations.
    pub obs_rms: Option<RunningMeanStd>,
    pub seed: u64,
    /// Env steps learnt from (summed over envs).
    pub timesteps: u64,
    /// Training episodes finished.
    pub episodes: u64,
    /// Rows written (the callbacks' updates).
    pub updates: u64,
    /// The last 100 finished training episodes.
    pub history: EpisodeHistory,
    /// Where the envs of `learn` stood after the last row, as their running episodes: a
    /// checkpoint keeps it, so a resumed `learn` restores them and goes on as if never stopped.
    pub env_state: Option<EnvState>,
    /// Where this process's training time went (not saved with the model).
    pub times: TrainingTimes,
}

impl LearnerState {
    /// A learner's state before it has learnt anything.
    pub fn new(observation_space: Space, action_space: Space, obs_rms: Option<RunningMeanStd>, seed: u64) -> Self {
        Self {
            observation_space,
            action_space,
            obs_rms,
            seed,
            timesteps: 0,
            episodes: 0,
            updates: 0,
            history: EpisodeHistory::default(),
            env_state: None,
            times: TrainingTimes::default(),
        }
    }

    /// Rows of raw observations, normalised with the statistics in force, as a tensor of
    /// `[rows, observation dim]` for the networks.
    pub fn batch(&self, obs: &[f32]) -> candle_core::Result<candle_core::Tensor> {
        let dim = self.observation_space.dim();
        candle_core::Tensor::from_vec(
            crate::normalize::normalized(self.obs_rms.as_ref(), obs),
            (obs.len() / dim, dim),
            &candle_core::Device::Cpu,
        )
    }

    /// The header of the learner's `model.json`.
    pub fn header(&self, algorithm: &str, format: u32) -> ModelHeader {
        ModelHeader {
            format,
            twinbots_version: env!("CARGO_PKG_VERSION").into(),
            algorithm: algorithm.into(),
            observation_space: self.observation_space.clone(),
            action_space: self.action_space.clone(),
            obs_rms: self.obs_rms.clone(),
            seed: self.seed,
            timesteps: self.timesteps,
            episodes: self.episodes,
            updates: self.updates,
            env_state: self.env_state.is_some(),
            history: self.history.clone(),
        }
    }

    /// Takes the normaliser, counters and history a saved header holds (checked by the
    /// loader); the spaces and seed are the ones the learner was made with from that header.
    pub fn take_saved(&mut self, header: ModelHeader) {
        (self.obs_rms, self.timesteps, self.episodes, self.updates, self.history) =
            (header.obs_rms, header.timesteps, header.episodes, header.updates, header.history);
    }
}
