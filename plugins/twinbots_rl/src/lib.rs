//! twinbots_rl: the RL side of twinbots.
//!
//! Gymnasium-style [`spaces`], the [`task`] machinery robot plugins fill in (observation, reward
//! and termination terms, reset events), and the vectorised [`env`] API over arenas.

pub mod env;
pub mod spaces;
pub mod task;

pub use env::{AppVecEnv, StepResult, VecEnv};
pub use spaces::Space;
pub use task::{Action, Episode, EpisodeSummary, SolvedCriterion, TaskPlugin, TaskSpec};
