//! twinbots_rl: the RL side of twinbots.
//!
//! Gymnasium-style [`spaces`], the [`task`] machinery robot plugins fill in (observation, reward
//! and termination terms, reset events), the vectorised [`env`] API over arenas, [`ppo`] and [`sac`] on
//! candle (both [`agent::Agent`]s) with its [`callbacks`] and [`evaluation`], the [`run_dir`] a training run leaves
//! behind with its [`tensorboard`] event files, and [`classic`] control envs for testing the
//! algorithms.

pub mod agent;
pub mod bridge;
pub mod callbacks;
pub mod classic;
pub mod env;
pub mod evaluation;
pub mod model_io;
pub mod nn;
pub mod normalize;
pub mod plot;
pub mod ppo;
pub mod randomization;
pub mod replay;
pub mod robot;
pub mod run_dir;
pub mod sac;
pub mod spaces;
pub mod task;
pub mod tensorboard;
pub mod threads;

pub use agent::{Agent, EpisodeHistory, LoadAgent, load_agent};
pub use callbacks::{Callback, CallbackList, Flow, SolvedBy, TrainingEnd};
pub use env::{AppVecEnv, Info, SingleEnv, StepResult, VecEnv};
pub use evaluation::{EvalResult, evaluate_policy};
pub use ppo::{Ppo, PpoConfig, UpdateStats};
pub use sac::{Sac, SacConfig};
pub use robot::{AppRequest, Registry, RobotDescription, SacDefaults, TaskDescription, TrainingDefaults};
pub use run_dir::RunDir;
pub use spaces::Space;
pub use task::{
    Action, DesignPattern, Episode, EpisodeSummary, GoalChange, GoalSpec, Measure, ObservationTerm, RewardTerm, SolvedCriterion, StartEvent, TaskPlugin,
    TaskDefinition, TaskSpec, TaskTerms, TaskTermsPlugin, TerminationTerm,
};
