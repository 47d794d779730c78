//! twinbots_learn: the learners of twinbots, on candle. No Bevy: they see an env only through
//! `twinbots_api::VecEnv`.
//!
//! [`ppo`], [`sac`], [`td3`] and [`bc`] (behaviour cloning; all [`agent::Agent`]s) on the [`nn`] pieces, with their [`callbacks`]
//! and [`evaluation`], the [`run_dir`] a training run leaves behind with its [`tensorboard`]
//! event files and [`plot`]s, [`classic`] control envs for testing the algorithms, and the
//! process's [`threads`].

pub mod agent;
pub mod algos;
pub mod bc;
pub mod callbacks;
pub mod classic;
pub mod config_checks;
pub mod evaluation;
pub mod history;
pub mod learner;
pub mod learner_state;
pub mod model_dir;
pub mod model_header;
pub mod model_io;
pub mod nn;
pub mod normalize;
pub mod off_policy;
pub mod plot;
pub mod policy_net;
pub mod ppo;
pub mod replay_buffer;
pub mod run_dir;
pub mod sac;
pub mod seeds;
pub mod stats;
pub mod td3;
pub mod tensorboard;
pub mod threads;
pub mod tuning;

pub use agent::{Agent, LoadAgent};
pub use algos::{ALGOS, load_agent};
pub use bc::{Bc, BcConfig};
pub use callbacks::{Callback, CallbackList};
pub use evaluation::{EvalResult, evaluate_against, evaluate_policy};
pub use history::EpisodeHistory;
pub use learner::{Algorithm, Learner, RobotStep, ServedLearner};
pub use off_policy::config::OffPolicyConfig;
pub use policy_net::PolicyNet;
pub use ppo::{Ppo, PpoConfig};
pub use run_dir::RunDir;
pub use sac::{Sac, SacConfig};
pub use stats::UpdateStats;
pub use stats::{Flow, SolvedBy, TrainingEnd, TrainingTimes};
pub use td3::{Td3, Td3Config};
pub use twinbots_api as api;
