//! The subcommands.

pub mod bench;
pub mod robots;
pub mod train;
