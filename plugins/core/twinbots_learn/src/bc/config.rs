//! Behaviour cloning's settings: the demonstrations to clone (a LeRobot dataset and which of its
//! features are the observation and the action), and the supervised fit's network, batch and
//! learning rate. Adam at 1e-3 as `imitation`'s `BC` (the library SB3 users clone with);
//! batches of 256 and two 256-unit ReLU layers as twinbots' off-policy learners have.

use serde::{Deserialize, Serialize};

use crate::config_checks::Checks;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BcConfig {
    /// The LeRobot dataset (a directory) of demonstrations (`--demos DIR`; `twinbots demos`
    /// writes one). Kept absolute, so a run resumes from wherever it is started.
    pub demos: String,
    /// The dataset's feature the policy reads: the robot's observation, value for value.
    pub observation_key: String,
    /// The dataset's feature the policy outputs: the robot's action (a discrete action's index
    /// as a number).
    pub action_key: String,
    /// Adam's learning rate.
    pub learning_rate: f64,
    /// Frames per gradient step, drawn uniformly (with replacement) from the whole dataset.
    pub batch_size: usize,
    /// Hidden layers (ReLU) of the policy.
    pub hidden: Vec<usize>,
    /// Observations normalised with the dataset's mean and standard deviation, saved with the
    /// model.
    pub normalize_observations: bool,
    /// Gradient steps between rows of `progress.csv` (and callback calls: evaluations,
    /// checkpoints).
    pub log_interval: usize,
}

impl Default for BcConfig {
    fn default() -> Self {
        Self {
            demos: String::new(),
            observation_key: "observation.state".into(),
            action_key: "action".into(),
            learning_rate: 1e-3,
            batch_size: 256,
            hidden: vec![256, 256],
            normalize_observations: true,
            log_interval: 100,
        }
    }
}

impl BcConfig {
    /// A clear error naming the first setting outside its range (`bc.<key> = value: …`).
    pub fn validate(&self) -> anyhow::Result<()> {
        let checks = Checks(super::NAME);
        checks.positive("learning_rate", self.learning_rate)?;
        checks.count("batch_size", self.batch_size, 1 << 16)?;
        checks.hidden(&self.hidden)?;
        checks.count("log_interval", self.log_interval, 1 << 24)?;
        checks.check("observation_key", &self.observation_key, !self.observation_key.is_empty(), "a feature's name")?;
        checks.check("action_key", &self.action_key, !self.action_key.is_empty(), "a feature's name")
    }
}

impl crate::learner::LearnerConfig for BcConfig {
    fn check(&self) -> anyhow::Result<()> {
        self.validate()
    }
}
