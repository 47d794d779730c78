//! PPO hyperparameters. Defaults are Stable-Baselines3's PPO defaults.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    pub learning_rate: f64,
    /// Anneal the learning rate linearly to 0 over `total_timesteps` (SB3: constant).
    pub linear_lr: bool,
    /// Steps per env per update.
    pub n_steps: usize,
    pub batch_size: usize,
    pub n_epochs: usize,
    pub gamma: f32,
    pub gae_lambda: f32,
    pub clip_range: f32,
    pub ent_coef: f32,
    pub vf_coef: f32,
    pub max_grad_norm: f32,
    /// Stop an update's epochs early once the approximate KL exceeds 1.5 × this.
    pub target_kl: Option<f32>,
    pub normalize_advantage: bool,
    /// Running mean/std normalisation of observations (SB3's VecNormalize), saved with the model.
    pub normalize_observations: bool,
    pub hidden: Vec<usize>,
    /// Starting log standard deviation of a Gaussian policy (SB3's `log_std_init`).
    pub log_std_init: f32,
}

impl Default for PpoConfig {
    fn default() -> Self {
        Self {
            learning_rate: 3e-4,
            linear_lr: false,
            n_steps: 2048,
            batch_size: 64,
            n_epochs: 10,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip_range: 0.2,
            ent_coef: 0.0,
            vf_coef: 0.5,
            max_grad_norm: 0.5,
            target_kl: None,
            normalize_advantage: true,
            normalize_observations: false,
            hidden: vec![64, 64],
            log_std_init: 0.0,
        }
    }
}

impl PpoConfig {
    /// RL Zoo's tuned CartPole-v1 settings for SB3's PPO: short rollouts, many epochs, linear
    /// learning-rate decay.
    pub fn zoo_cartpole() -> Self {
        Self {
            n_steps: 32,
            batch_size: 256,
            gae_lambda: 0.8,
            gamma: 0.98,
            n_epochs: 20,
            learning_rate: 1e-3,
            linear_lr: true,
            ..Self::default()
        }
    }
}
