//! The subcommands.

pub mod bench;
pub mod eval;
pub mod robots;
pub mod train;
