//! twinbots as a library: the registry of the robots this build knows and the settings of a
//! training run, shared by the CLI (`src/main.rs`) and the Python extension (`python/`).

pub mod registry;
pub mod settings;
