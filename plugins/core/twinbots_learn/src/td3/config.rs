//! TD3 hyperparameters. Defaults are Stable-Baselines3's TD3 defaults, with Gaussian
//! exploration noise of 0.1 (SB3 has none by default; RL Zoo's tuned runs use 0.1), and how
//! often a row of `progress.csv` is written.

use serde::{Deserialize, Serialize};

use crate::config_checks::Checks;
use crate::off_policy::config::OffPolicyConfig;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
// Unknown keys are refused by `config_from` (serde's `deny_unknown_fields` does not work with
// `flatten`).
#[serde(default)]
pub struct Td3Config {
    /// The learning rate (of the actor and the critics), the replay buffer, the batch, τ, γ and
    /// the training frequency.
    #[serde(flatten)]
    pub off_policy: OffPolicyConfig,
    /// The actor and the targets are updated every this many critic updates.
    pub policy_delay: usize,
    /// Standard deviation of the noise on the target actor's actions (target policy smoothing),
    /// in units of half the action range…
    pub target_policy_noise: f32,
    /// …clipped to ± this.
    pub target_noise_clip: f32,
    /// Standard deviation of the Gaussian exploration noise, in units of half the action range.
    pub action_noise: f32,
    /// Hidden layers (ReLU) of the actor and of each critic.
    pub hidden: Vec<usize>,
    /// Running mean/std normalisation of observations, saved with the model.
    pub normalize_observations: bool,
    /// Steps of each env between rows of `progress.csv` (and callback calls).
    pub log_interval: usize,
}

impl Default for Td3Config {
    fn default() -> Self {
        Self {
            off_policy: OffPolicyConfig { learning_rate: 1e-3, ..OffPolicyConfig::default() },
            policy_delay: 2,
            target_policy_noise: 0.2,
            target_noise_clip: 0.5,
            action_noise: 0.1,
            hidden: vec![400, 300],
            normalize_observations: false,
            log_interval: 1000,
        }
    }
}

impl Td3Config {
    /// A clear error naming the first setting outside its range (`td3.<key> = value: allowed
    /// range`).
    pub fn validate(&self) -> anyhow::Result<()> {
        let checks = Checks(super::NAME);
        self.off_policy.validate(&checks)?;
        checks.count("policy_delay", self.policy_delay, 1000)?;
        checks.non_negative("target_policy_noise", self.target_policy_noise as f64)?;
        checks.non_negative("target_noise_clip", self.target_noise_clip as f64)?;
        checks.non_negative("action_noise", self.action_noise as f64)?;
        checks.hidden(&self.hidden)?;
        checks.count("log_interval", self.log_interval, 1 << 24)
    }
}
impl crate::learner::LearnerConfig for Td3Config {
    fn check(&self) -> anyhow::Result<()> {
        self.validate()
    }
}
