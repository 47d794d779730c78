//! twinbots as a library: the registry of the robots this build knows and the settings of a
//! training run and the run itself (its directory, callbacks and end), shared by the CLI
//! (`src/main.rs`) and the Python extension (`python/`).

pub mod bundle;
pub mod deploy;
pub mod distill;
pub mod monitor;
pub mod pacer;
pub mod realtime;
pub mod registry;
pub mod robot_log;
#[cfg(feature = "ros2")]
pub mod ros2;
pub mod run;
pub mod settings;
pub mod study;
pub mod twin;
pub mod ur_sim;
pub mod urdf_check;
