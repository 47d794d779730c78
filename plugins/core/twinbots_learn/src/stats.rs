//! What a learner reports, whichever algorithm it is: a row of statistics per update, where its
//! time went, and why training ended.

/// One row of `progress.csv`: what an update saw and did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct UpdateStats {
    pub update: usize,
    pub timesteps: u64,
    pub episodes: u64,
    /// Over the last 100 finished episodes.
    pub mean_reward: f32,
    pub min_reward: f32,
    pub max_reward: f32,
    pub mean_length: f32,
    /// Share of the last 100 finished episodes that reported success (NaN: none reported).
    pub success_rate: f32,
    /// The algorithm's own figures of the update, by name, in the order it always gives them
    /// (SB3's `logger.record("train/<name>", …)`): PPO's `policy_loss`, `value_loss`, `entropy`,
    /// `approx_kl`, `clip_fraction`; SAC's and TD3's `actor_loss`, `critic_loss`, …. Each is a
    /// column of `progress.csv` (NaN where an update has none).
    pub train: Vec<(String, f32)>,
    pub learning_rate: f64,
    pub steps_per_s: f32,
    /// Gradient steps of this update that were skipped because the loss or a gradient was not
    /// finite (the weights stayed as they were).
    pub skipped_steps: usize,
    /// Gradient steps of this update that were applied (not a column: a session that applied
    /// none learnt nothing, see `callbacks::GradientStepTally`).
    pub applied_steps: usize,
}

impl UpdateStats {
    /// The algorithm's figure `name` (NaN if it gave none).
    pub fn train(&self, name: &str) -> f32 {
        self.train.iter().find(|(n, _)| n == name).map_or(f32::NAN, |(_, v)| *v)
    }
}

/// An algorithm's figures `names` (its `TRAIN_FIGURES`) with their `values`, as
/// [`UpdateStats::train`] holds them.
pub fn figures(names: &[&str], values: &[f32]) -> Vec<(String, f32)> {
    debug_assert_eq!(names.len(), values.len());
    names.iter().zip(values).map(|(n, v)| (n.to_string(), *v)).collect()
}

/// Seconds the learner spent on each part of training, summed since the model was made or
/// loaded: what `train` reports at its end and in `summary.json`.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TrainingTimes {
    /// Policy forward passes of the rollouts (actions, values, bootstrap values, normalising).
    pub inference_s: f64,
    /// Waiting for the env's steps and resets: the simulation, and for a bridged env the
    /// channel around it.
    pub env_s: f64,
    /// Advantages and the gradient steps of the updates.
    pub update_s: f64,
    /// The callbacks: progress logs, the curve, evaluations, checkpoints.
    pub callbacks_s: f64,
}

/// What a callback tells training after an update.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    Continue,
    /// Stop, for the callback's own reason.
    Stop,
    /// Stop: the task's solved criterion holds, judged on this.
    Solved(SolvedBy),
}

/// What a solved criterion was judged on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SolvedBy {
    /// The last training episodes (the stochastic policy, as it learns).
    TrainingEpisodes,
    /// An evaluation of the deterministic policy.
    Evaluation,
}

impl std::fmt::Display for SolvedBy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SolvedBy::TrainingEpisodes => "training episodes",
            SolvedBy::Evaluation => "evaluation",
        })
    }
}

/// Why training ended.
#[derive(Clone, Debug, PartialEq)]
pub enum TrainingEnd {
    /// The timestep budget is spent.
    BudgetSpent { timesteps: u64 },
    /// The task's solved criterion held.
    Solved { timesteps: u64, by: SolvedBy },
    /// A callback stopped it.
    Stopped { timesteps: u64 },
}

impl TrainingEnd {
    /// How training ends after an update that left the model at `timesteps`, by a callback's
    /// word (`None`: it goes on, unless its budget is spent).
    pub fn after(flow: Flow, timesteps: u64) -> Option<Self> {
        match flow {
            Flow::Continue => None,
            Flow::Stop => Some(Self::Stopped { timesteps }),
            Flow::Solved(by) => Some(Self::Solved { timesteps, by }),
        }
    }

    pub fn is_solved(&self) -> bool {
        matches!(self, Self::Solved { .. })
    }
}

impl std::fmt::Display for TrainingEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::BudgetSpent { timesteps } => write!(f, "budget spent after {timesteps} steps"),
            Self::Solved { timesteps, by } => write!(f, "solved ({by}) after {timesteps} steps"),
            Self::Stopped { timesteps } => write!(f, "stopped by a callback after {timesteps} steps"),
        }
    }
}
