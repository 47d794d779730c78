//! SAC hyperparameters. Defaults are Stable-Baselines3's SAC defaults, plus how often a row of
//! `progress.csv` is written and the HER options.

use serde::{Deserialize, Serialize};

use crate::config_checks::Checks;
use crate::nn::PolicyKind;
use crate::off_policy::config::OffPolicyConfig;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
// Unknown keys are refused by `config_from` (serde's `deny_unknown_fields` does not work with
// `flatten`).
#[serde(default)]
pub struct SacConfig {
    /// The learning rate (of the actor, the critics and the entropy coefficient), the replay
    /// buffer, the batch, τ, γ and the training frequency.
    #[serde(flatten)]
    pub off_policy: OffPolicyConfig,
    /// Learn the entropy coefficient α towards the target entropy (SB3's `ent_coef = "auto"`);
    /// false keeps it at `ent_coef_init`.
    pub learn_ent_coef: bool,
    pub ent_coef_init: f32,
    /// The entropy α is tuned towards (`None`: −dim(actions), SB3's "auto").
    pub target_entropy: Option<f32>,
    /// Update the targets every this many gradient steps.
    pub target_update_interval: usize,
    /// Hidden layers (ReLU) of the actor and of each critic.
    pub hidden: Vec<usize>,
    /// What the actor and the critics read: `auto` (a NatureCNN's features for camera images,
    /// the observation otherwise), `mlp` or `cnn` (as PPO's).
    pub policy: PolicyKind,
    /// Features each CNN hands its MLPs.
    pub features_dim: usize,
    /// Running mean/std normalisation of observations, saved with the model. The buffer keeps
    /// raw observations and normalises them when sampled, with the statistics then in force.
    pub normalize_observations: bool,
    /// Steps of each env between rows of `progress.csv` (and callback calls: `eval_every` and
    /// `checkpoint_every` count these rows as updates).
    pub log_interval: usize,
    /// Hindsight experience replay for goal-conditioned tasks: this many of every 1 + n sampled
    /// transitions get a goal the episode achieved later ("future" strategy). 0: off.
    pub her_goals: usize,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            off_policy: OffPolicyConfig::default(),
            learn_ent_coef: true,
            ent_coef_init: 1.0,
            target_entropy: None,
            target_update_interval: 1,
            hidden: vec![256, 256],
            policy: PolicyKind::Auto,
            features_dim: 512,
            normalize_observations: false,
            log_interval: 1000,
            her_goals: 0,
        }
    }
}

impl SacConfig {
    /// A clear error naming the first setting outside its range (`sac.<key> = value: allowed
    /// range`).
    pub fn validate(&self) -> anyhow::Result<()> {
        let checks = Checks(super::NAME);
        self.off_policy.validate(&checks)?;
        checks.positive("ent_coef_init", self.ent_coef_init as f64)?;
        if let Some(h) = self.target_entropy {
            checks.check("target_entropy", h, h.is_finite() && h.abs() <= 1e6, "a finite number in [-1e6, 1e6]")?;
        }
        checks.count("target_update_interval", self.target_update_interval, 1 << 20)?;
        checks.hidden(&self.hidden)?;
        checks.count("features_dim", self.features_dim, 4096)?;
        checks.count("log_interval", self.log_interval, 1 << 24)?;
        checks.check("her_goals", self.her_goals, self.her_goals <= 16, "a whole number in 0..=16")
    }
}

impl crate::learner::LearnerConfig for SacConfig {
    fn check(&self) -> anyhow::Result<()> {
        self.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_nonsense_is_named() {
        SacConfig::default().validate().unwrap();
        let cases: Vec<(SacConfig, &str)> = vec![
            (
                SacConfig {
                    off_policy: OffPolicyConfig { learning_rate: f64::NAN, ..Default::default() },
                    ..Default::default()
                },
                "sac.learning_rate = NaN",
            ),
            (
                SacConfig { off_policy: OffPolicyConfig { tau: 0.0, ..Default::default() }, ..Default::default() },
                "sac.tau = 0",
            ),
            (
                SacConfig { off_policy: OffPolicyConfig { gamma: 1.5, ..Default::default() }, ..Default::default() },
                "sac.gamma = 1.5",
            ),
            (
                SacConfig { off_policy: OffPolicyConfig { batch_size: 0, ..Default::default() }, ..Default::default() },
                "sac.batch_size = 0",
            ),
            (
                SacConfig {
                    off_policy: OffPolicyConfig { buffer_size: 0, ..Default::default() },
                    ..Default::default()
                },
                "sac.buffer_size = 0",
            ),
            (
                SacConfig {
                    off_policy: OffPolicyConfig { gradient_steps: 0, ..Default::default() },
                    ..Default::default()
                },
                "sac.gradient_steps = 0",
            ),
            (SacConfig { ent_coef_init: -1.0, ..Default::default() }, "sac.ent_coef_init = -1"),
            (SacConfig { hidden: vec![], ..Default::default() }, "sac.hidden = []"),
            (SacConfig { her_goals: 100, ..Default::default() }, "sac.her_goals = 100"),
        ];
        for (config, expected) in cases {
            let message = config.validate().unwrap_err().to_string();
            assert!(message.starts_with(expected), "{message:?} does not start with {expected:?}");
        }
    }
}
