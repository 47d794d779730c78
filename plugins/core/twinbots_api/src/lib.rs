//! twinbots_api: what every layer of twinbots agrees on, and nothing else (no Bevy, no candle).
//!
//! Gymnasium-style [`spaces`], the vectorised [`env`] API with its step results, finished
//! [`episode`]s and when a task counts as solved, the [`goal`] interface of goal-conditioned
//! tasks, a [`task`]'s spec and design pattern, and the [`env_state`] a checkpoint keeps.

pub mod env;
pub mod env_state;
pub mod episode;
pub mod files;
pub mod goal;
pub mod restore;
pub mod seeds;
pub mod spaces;
pub mod task;

pub use env::{Info, SingleEnv, StepResult, Transition, VecEnv};
pub use env_state::{EnvState, RunningEpisode, StreamState};
pub use episode::{EpisodeSummary, Measure, SolvedCriterion};
pub use goal::{GoalChange, GoalSpec};
pub use restore::restore;
pub use spaces::Space;
pub use task::{DesignPattern, TaskSpec};
