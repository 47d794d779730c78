//! Callbacks: what runs around training, in Stable-Baselines3's shape. A [`Callback`] hears
//! when training starts, after every update, and when it ends; after an update it may stop
//! training. A [`CallbackList`] composes them, and `Ppo::learn` and the RobotServer call the
//! same lists.
//!
//! - [`ProgressCsvCallback`]: a row of `progress.csv` per update;
//! - [`ProgressBarCallback`]: the terminal's progress bar, or a line now and then where stderr
//!   is not a terminal;
//! - [`EvalCallback`]: evaluates the deterministic policy every N updates into
//!   `evaluations.csv`, and may stop training once an evaluation meets the solved criterion;
//! - [`StopTrainingOnSolved`]: stops once the training episodes meet the solved criterion;
//! - [`CheckpointCallback`]: saves a checkpoint every N updates;
//! - [`LearningCurveCallback`]: redraws `learning_curve.png` every N updates and at the end;
//! - [`TensorBoardCallback`]: TensorBoard scalars under SB3's tag names every update;
//! - [`GradientStepTally`]: counts applied and skipped gradient steps, so a session that
//!   learnt nothing ends with an error rather than a useless model.

mod eval;
mod logging;
mod tensorboard;

pub use eval::{EvalCallback, evaluation_seed};
pub use logging::{
    CheckpointCallback, LearningCurveCallback, ProgressBarCallback, ProgressCsvCallback, draw_learning_curve,
};
pub use tensorboard::{TensorBoardCallback, evaluation_scalars, training_scalars};

use crate::agent::Agent;
use crate::stats::UpdateStats;
pub use crate::stats::{Flow, SolvedBy, TrainingEnd};
use twinbots_api::SolvedCriterion;

/// Hears training as it goes. Only `on_update` is required; a closure
/// `|stats: &UpdateStats, model: &dyn Agent| -> anyhow::Result<Flow>` is a callback.
pub trait Callback {
    /// Before the first update.
    fn on_training_start(&mut self, _model: &dyn Agent) -> anyhow::Result<()> {
        Ok(())
    }
    /// After every update, with its row of statistics and the updated model.
    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow>;
    /// Once training has ended, however it ended (but not after an error).
    fn on_training_end(&mut self, _model: &dyn Agent) -> anyhow::Result<()> {
        Ok(())
    }
}

impl<F: FnMut(&UpdateStats, &dyn Agent) -> anyhow::Result<Flow>> Callback for F {
    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        self(stats, model)
    }
}

/// Callbacks called in order. After an update every one runs (a checkpoint is still saved on
/// the update that solves the task); the first that asks to stop gives the reason.
#[derive(Default)]
pub struct CallbackList {
    callbacks: Vec<Box<dyn Callback + Send>>,
}

impl CallbackList {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `callback` at the end of the list.
    pub fn with(mut self, callback: impl Callback + Send + 'static) -> Self {
        self.callbacks.push(Box::new(callback));
        self
    }

    pub fn push(&mut self, callback: impl Callback + Send + 'static) {
        self.callbacks.push(Box::new(callback));
    }

    pub fn len(&self) -> usize {
        self.callbacks.len()
    }

    pub fn is_empty(&self) -> bool {
        self.callbacks.is_empty()
    }
}

impl Callback for CallbackList {
    fn on_training_start(&mut self, model: &dyn Agent) -> anyhow::Result<()> {
        self.callbacks.iter_mut().try_for_each(|c| c.on_training_start(model))
    }

    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        let mut flow = Flow::Continue;
        for callback in &mut self.callbacks {
            let said = callback.on_update(stats, model)?;
            if flow == Flow::Continue {
                flow = said;
            }
        }
        Ok(flow)
    }

    fn on_training_end(&mut self, model: &dyn Agent) -> anyhow::Result<()> {
        self.callbacks.iter_mut().try_for_each(|c| c.on_training_end(model))
    }
}

/// Stops training once the last training episodes meet the task's solved criterion (e.g. the
/// cart-pole's mean score of the last 100 episodes above 1950).
pub struct StopTrainingOnSolved {
    pub criterion: SolvedCriterion,
}

impl StopTrainingOnSolved {
    pub fn new(criterion: SolvedCriterion) -> Self {
        Self { criterion }
    }
}

impl Callback for StopTrainingOnSolved {
    fn on_update(&mut self, _stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        Ok(if model.history().is_solved(&self.criterion) {
            Flow::Solved(SolvedBy::TrainingEpisodes)
        } else {
            Flow::Continue
        })
    }
}

/// Gradient steps applied and skipped over a training session (shared between its clones: push
/// one into the list, ask another after training).
#[derive(Clone, Debug, Default)]
pub struct GradientStepTally(std::sync::Arc<std::sync::Mutex<(u64, u64)>>);

impl GradientStepTally {
    /// (applied, skipped) so far.
    pub fn counts(&self) -> (u64, u64) {
        *self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// An error when steps were skipped and none applied: the loss or a gradient was never
    /// finite, so the model learnt nothing in this session.
    pub fn check(&self) -> anyhow::Result<()> {
        let (applied, skipped) = self.counts();
        anyhow::ensure!(
            applied > 0 || skipped == 0,
            "every gradient step of this session ({skipped}) was skipped: the loss or a gradient was never finite \
             (see the warnings above), so the model learnt nothing; no final model was saved"
        );
        Ok(())
    }
}

impl Callback for GradientStepTally {
    fn on_update(&mut self, stats: &UpdateStats, _model: &dyn Agent) -> anyhow::Result<Flow> {
        let mut counts = self.0.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        counts.0 += stats.applied_steps as u64;
        counts.1 += stats.skipped_steps as u64;
        Ok(Flow::Continue)
    }
}
