//! TD3 hyperparameters. Defaults are Stable-Baselines3's TD3 defaults, with Gaussian
//! exploration noise of 0.1 (SB3 has none by default; RL Zoo's tuned runs use 0.1), and how
//! often a row of `progress.csv` is written.

use serde::{Deserialize, Serialize};

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Td3Config {
    /// Adam's learning rate for the actor and the critics.
    pub learning_rate: f64,
    /// Transitions the replay buffer holds (the oldest are overwritten).
    pub buffer_size: usize,
    /// Env steps (summed over envs) of uniformly random actions before learning starts.
    pub learning_starts: u64,
    pub batch_size: usize,
    /// Polyak coefficient of the targets: θ' ← τ θ + (1 − τ) θ'.
    pub tau: f32,
    pub gamma: f32,
    /// Train after every this many steps of each env…
    pub train_freq: usize,
    /// …with this many gradient steps.
    pub gradient_steps: usize,
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
            learning_rate: 1e-3,
            buffer_size: 1_000_000,
            learning_starts: 100,
            batch_size: 256,
            tau: 0.005,
            gamma: 0.99,
            train_freq: 1,
            gradient_steps: 1,
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
        let positive = |key: &str, v: f64| check(key, v, v.is_finite() && v > 0.0, "a finite number > 0");
        let non_negative = |key: &str, v: f64| check(key, v, v.is_finite() && v >= 0.0, "a finite number ≥ 0");
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
        count("policy_delay", self.policy_delay, 1000)?;
        non_negative("target_policy_noise", self.target_policy_noise as f64)?;
        non_negative("target_noise_clip", self.target_noise_clip as f64)?;
        non_negative("action_noise", self.action_noise as f64)?;
        let hidden = format!("{:?}", self.hidden);
        let sizes_ok = (1..=16).contains(&self.hidden.len()) && self.hidden.iter().all(|&n| (1..=4096).contains(&n));
        check("hidden", hidden, sizes_ok, "1 to 16 layer sizes, each in 1..=4096")?;
        count("log_interval", self.log_interval, 1 << 24)
    }
}

fn check(key: &str, value: impl std::fmt::Display, ok: bool, allowed: &str) -> anyhow::Result<()> {
    anyhow::ensure!(ok, "td3.{key} = {value}: must be {allowed}");
    Ok(())
}
