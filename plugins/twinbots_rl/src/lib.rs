//! twinbots_rl: the RL side of twinbots.
//!
//! Gymnasium-style [`spaces`], the [`task`] machinery robot plugins fill in (observation, reward
//! and termination terms, reset events), the vectorised [`env`] API over arenas, [`ppo`] on
//! candle, and [`classic`] control envs for testing the algorithms.

pub mod bridge;
pub mod classic;
pub mod env;
pub mod normalize;
pub mod plot;
pub mod randomization;
pub mod ppo;
pub mod spaces;
pub mod task;
pub mod threads;

pub use env::{AppVecEnv, Info, SingleEnv, StepResult, VecEnv};
pub use ppo::{Callback, Flow, Ppo, PpoConfig, UpdateStats};
pub use spaces::Space;
pub use task::{Action, DesignPattern, Episode, EpisodeSummary, Measure, SolvedCriterion, TaskPlugin, TaskSpec};
