//! The subcommands.

pub mod bench;
pub mod eval;
pub mod robots;
pub mod run_log;
pub mod serve;
pub mod train;
