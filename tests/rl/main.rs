//! End-to-end tests of the RL side (one test binary).

mod model;
mod ppo;
mod train_cli;
