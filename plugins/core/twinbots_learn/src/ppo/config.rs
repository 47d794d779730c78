//! PPO hyperparameters. Defaults are Stable-Baselines3's PPO defaults.

use serde::{Deserialize, Serialize};

use crate::config_checks::Checks;
use crate::nn::PolicyKind;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    pub learning_rate: f64,
    /// Anneal the learning rate linearly to 0 over the run's whole budget of steps (SB3: constant).
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
    /// Rewards divided by the running standard deviation of the discounted return, clipped to
    /// ±10 (SB3's `VecNormalize(norm_reward=True)`, which RL Zoo turns on for its continuous
    /// tasks): the value loss then stays near 1 whatever the reward's scale, so it cannot take
    /// over the gradient norm `max_grad_norm` clips. Episode scores stay raw.
    pub normalize_rewards: bool,
    pub hidden: Vec<usize>,
    /// What the MLPs read: `auto` (a NatureCNN's features for camera images, the observation
    /// otherwise), `mlp` or `cnn` (SB3's `MlpPolicy` / `CnnPolicy`).
    pub policy: PolicyKind,
    /// Features the CNN hands the MLPs (SB3's `features_dim`).
    pub features_dim: usize,
    /// One CNN for the policy and the value (SB3's on-policy default), or one each (`false`:
    /// twice the CNN's work, and the value's regression no longer reshapes the policy's
    /// features).
    pub share_features_extractor: bool,
    /// Starting log standard deviation of a Gaussian policy (SB3's `log_std_init`).
    pub log_std_init: f32,
    /// A safetensors file whose `features.*` tensors a new model's image encoder starts from
    /// (the value's own one too), e.g. an encoder trained on labelled images by
    /// `examples/pixel_probe.rs --save`; as SB3's `features_extractor.load_state_dict`.
    pub features_from: Option<std::path::PathBuf>,
    /// The image encoders (the policy's, and the value's own) stay as they start: no gradient
    /// reaches them, and an update reads each sample's features once rather than once an epoch.
    /// With `features_from`, a frozen encoder fitted to labelled images (Isaac Lab's frozen
    /// `image_features`; SB3: `features_extractor.requires_grad_(False)`). Camera images only.
    pub freeze_features: bool,
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
            normalize_rewards: false,
            hidden: vec![64, 64],
            policy: PolicyKind::Auto,
            features_dim: 512,
            share_features_extractor: true,
            log_std_init: 0.0,
            features_from: None,
            freeze_features: false,
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

impl PpoConfig {
    /// A clear error naming the first setting outside its range (`ppo.<key> = value: allowed
    /// range`), so that nonsense never reaches the learner.
    pub fn validate(&self) -> anyhow::Result<()> {
        let checks = Checks(super::NAME);
        checks.positive("learning_rate", self.learning_rate)?;
        checks.count("n_steps", self.n_steps, MAX_ROLLOUT)?;
        checks.check("batch_size", self.batch_size, self.batch_size >= 1, "a whole number ≥ 1")?;
        checks.count("n_epochs", self.n_epochs, 10_000)?;
        checks.fraction("gamma", self.gamma)?;
        checks.check("gae_lambda", self.gae_lambda, (0.0..=1.0).contains(&self.gae_lambda), "in [0, 1]")?;
        checks.positive("clip_range", self.clip_range as f64)?;
        checks.non_negative("ent_coef", self.ent_coef as f64)?;
        checks.non_negative("vf_coef", self.vf_coef as f64)?;
        checks.positive("max_grad_norm", self.max_grad_norm as f64)?;
        if let Some(kl) = self.target_kl {
            checks.positive("target_kl", kl as f64)?;
        }
        checks.hidden(&self.hidden)?;
        checks.count("features_dim", self.features_dim, 4096)?;
        checks.check(
            "log_std_init",
            self.log_std_init,
            self.log_std_init.is_finite() && self.log_std_init.abs() <= 20.0,
            "a finite number in [-20, 20]",
        )
    }
}

/// The most samples a rollout may hold (n_steps × envs).
pub const MAX_ROLLOUT: usize = 1 << 24;

impl crate::learner::LearnerConfig for PpoConfig {
    fn check(&self) -> anyhow::Result<()> {
        self.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_tuned_settings_are_valid_and_nonsense_is_named() {
        PpoConfig::default().validate().unwrap();
        PpoConfig::zoo_cartpole().validate().unwrap();
        let cases: Vec<(PpoConfig, &str)> = vec![
            (PpoConfig { learning_rate: f64::NAN, ..Default::default() }, "ppo.learning_rate = NaN"),
            (PpoConfig { learning_rate: -1.0, ..Default::default() }, "ppo.learning_rate = -1"),
            (PpoConfig { gamma: 2.0, ..Default::default() }, "ppo.gamma = 2: must be in (0, 1]"),
            (PpoConfig { clip_range: -0.5, ..Default::default() }, "ppo.clip_range = -0.5"),
            (PpoConfig { n_epochs: 0, ..Default::default() }, "ppo.n_epochs = 0"),
            (PpoConfig { batch_size: 0, ..Default::default() }, "ppo.batch_size = 0"),
            (PpoConfig { n_steps: 0, ..Default::default() }, "ppo.n_steps = 0"),
            (PpoConfig { max_grad_norm: f32::NAN, ..Default::default() }, "ppo.max_grad_norm = NaN"),
            (PpoConfig { hidden: vec![], ..Default::default() }, "ppo.hidden = []"),
            (PpoConfig { target_kl: Some(f32::INFINITY), ..Default::default() }, "ppo.target_kl = inf"),
        ];
        for (config, expected) in cases {
            let message = config.validate().unwrap_err().to_string();
            assert!(message.starts_with(expected), "{message:?} does not start with {expected:?}");
        }
    }
}
