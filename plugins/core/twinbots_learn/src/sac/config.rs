//! SAC hyperparameters. Defaults are Stable-Baselines3's SAC defaults, plus how often a row of
//! `progress.csv` is written and the HER options.

use serde::{Deserialize, Serialize};

use crate::nn::PolicyKind;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SacConfig {
    /// Adam's learning rate for the actor, the critics and the entropy coefficient.
    pub learning_rate: f64,
    /// Transitions the replay buffer holds (the oldest are overwritten).
    pub buffer_size: usize,
    /// Env steps (summed over envs) of uniformly random actions before learning starts.
    pub learning_starts: u64,
    pub batch_size: usize,
    /// Polyak coefficient of the target critics: θ' ← τ θ + (1 − τ) θ'.
    pub tau: f32,
    pub gamma: f32,
    /// Train after every this many steps of each env…
    pub train_freq: usize,
    /// …with this many gradient steps.
    pub gradient_steps: usize,
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
            learning_rate: 3e-4,
            buffer_size: 1_000_000,
            learning_starts: 100,
            batch_size: 256,
            tau: 0.005,
            gamma: 0.99,
            train_freq: 1,
            gradient_steps: 1,
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
        let positive = |key: &str, v: f64| check(key, v, v.is_finite() && v > 0.0, "a finite number > 0");
        let count = |key: &str, v: usize, max: usize| {
            check(key, v, (1..=max).contains(&v), &format!("a whole number in 1..={max}"))
        };
        positive("learning_rate", self.learning_rate)?;
        count("buffer_size", self.buffer_size, 1 << 26)?;
        count("batch_size", self.batch_size, 1 << 16)?;
        check("learning_starts", self.learning_starts, self.learning_starts <= 1 << 40, "at most 2^40")?;
        check("tau", self.tau, self.tau > 0.0 && self.tau <= 1.0, "in (0, 1]")?;
        check("gamma", self.gamma, self.gamma > 0.0 && self.gamma <= 1.0, "in (0, 1]")?;
        count("train_freq", self.train_freq, 1 << 20)?;
        count("gradient_steps", self.gradient_steps, 10_000)?;
        positive("ent_coef_init", self.ent_coef_init as f64)?;
        if let Some(h) = self.target_entropy {
            check("target_entropy", h, h.is_finite() && h.abs() <= 1e6, "a finite number in [-1e6, 1e6]")?;
        }
        count("target_update_interval", self.target_update_interval, 1 << 20)?;
        let hidden = format!("{:?}", self.hidden);
        let sizes_ok = (1..=16).contains(&self.hidden.len()) && self.hidden.iter().all(|&n| (1..=4096).contains(&n));
        check("hidden", hidden, sizes_ok, "1 to 16 layer sizes, each in 1..=4096")?;
        check(
            "features_dim",
            self.features_dim,
            (1..=4096).contains(&self.features_dim),
            "a whole number in 1..=4096",
        )?;
        count("log_interval", self.log_interval, 1 << 24)?;
        check("her_goals", self.her_goals, self.her_goals <= 16, "a whole number in 0..=16")
    }
}

fn check(key: &str, value: impl std::fmt::Display, ok: bool, allowed: &str) -> anyhow::Result<()> {
    anyhow::ensure!(ok, "sac.{key} = {value}: must be {allowed}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_nonsense_is_named() {
        SacConfig::default().validate().unwrap();
        let cases: Vec<(SacConfig, &str)> = vec![
            (SacConfig { learning_rate: f64::NAN, ..Default::default() }, "sac.learning_rate = NaN"),
            (SacConfig { tau: 0.0, ..Default::default() }, "sac.tau = 0"),
            (SacConfig { gamma: 1.5, ..Default::default() }, "sac.gamma = 1.5"),
            (SacConfig { batch_size: 0, ..Default::default() }, "sac.batch_size = 0"),
            (SacConfig { buffer_size: 0, ..Default::default() }, "sac.buffer_size = 0"),
            (SacConfig { gradient_steps: 0, ..Default::default() }, "sac.gradient_steps = 0"),
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
