//! The settings every off-policy learner has (SB3's `OffPolicyAlgorithm` arguments): SAC's and
//! TD3's tables hold them flattened, so a settings file writes `[sac] batch_size = 64` as before.

use serde::{Deserialize, Serialize};

use crate::config_checks::Checks;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct OffPolicyConfig {
    /// Adam's learning rate for every network the algorithm trains.
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
}

impl Default for OffPolicyConfig {
    /// SB3's defaults (SAC's learning rate).
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
        }
    }
}

impl OffPolicyConfig {
    /// The first of these settings outside its range, named under the algorithm's table.
    pub fn validate(&self, checks: &Checks) -> anyhow::Result<()> {
        checks.positive("learning_rate", self.learning_rate)?;
        checks.count("buffer_size", self.buffer_size, 1 << 26)?;
        checks.count("batch_size", self.batch_size, 1 << 16)?;
        checks.check("learning_starts", self.learning_starts, self.learning_starts <= 1 << 40, "at most 2^40")?;
        checks.fraction("tau", self.tau)?;
        checks.fraction("gamma", self.gamma)?;
        checks.count("train_freq", self.train_freq, 1 << 20)?;
        checks.count("gradient_steps", self.gradient_steps, 10_000)
    }
}
