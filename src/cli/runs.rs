//! What the commands share about training runs: `twinbots::run` (the run directory, its
//! callbacks, its end) and `twinbots::settings` (its `config.toml`). It imports no other
//! command, so every command can import it.

pub use twinbots::run::{callbacks, create, default_run_dir, evaluation_env, finish};
pub use twinbots::settings::{ConfigFile, TrainSettings};
