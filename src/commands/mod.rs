//! The subcommands, one file each: its `Args` and its `exec`.

pub mod algos;
pub mod bench;
pub mod capture;
pub mod compare;
pub mod demos;
pub mod deploy;
pub mod distill;
pub mod eval;
pub mod export;
pub mod identify;
pub mod monitor;
pub mod record;
pub mod replay;
pub mod robot;
pub mod robots;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod serve;
pub mod study;
pub mod train;
pub mod ur_sim;
pub mod urdf;
pub mod view;
