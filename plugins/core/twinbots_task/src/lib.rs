//! twinbots_task: the Bevy task layer of twinbots.
//!
//! The [`task`] machinery robot plugins fill in (observation, reward and termination terms,
//! reset events) evaluated per arena, the vectorised [`env`] over a Bevy app whose arenas are
//! the envs, the channel [`bridge`] a learner thread steps it through, domain [`randomization`],
//! episode [`replay`] for checkpoints, the assembly [`cell`] and its pick-and-place program, and
//! the [`robot`] registry every front reads. The API types it works with are `twinbots_api`'s,
//! re-exported here.

pub mod bridge;
pub mod calibration;
pub mod cell;
pub mod env;
pub mod on_robot;
pub mod randomization;
pub mod replay;
pub mod robot;
pub mod safety;
pub mod shadow;
pub mod task;

pub use env::AppVecEnv;
pub use robot::{AlgoDefaults, AppRequest, Registry, RobotDescription, TaskDescription, TrainingDefaults};
pub use task::{
    Action, ActiveTask, EndedEpisode, Episode, EpisodeFigures, ObservationTerm, RewardTerm, StartEvent, TaskDefinition,
    TaskPlugin, TaskTerms, TaskTermsPlugin, TerminationTerm,
};
pub use twinbots_api as api;
pub use twinbots_api::{
    DesignPattern, EnvState, EpisodeSummary, GoalChange, GoalSpec, Info, Measure, SingleEnv, SolvedCriterion, Space,
    StepResult, StreamState, TaskSpec, VecEnv, spaces,
};
