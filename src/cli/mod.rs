//! The subcommands.

pub mod algos;
pub mod bench;
pub mod capture;
pub mod deploy;
pub mod eval;
pub mod export;
pub mod identify;
pub mod learner;
pub mod record;
pub mod replay;
pub mod robot;
pub mod robots;
pub mod serve;
pub mod view;
pub mod train;
pub mod ur_sim;
