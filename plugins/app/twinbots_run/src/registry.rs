//! The robots this build knows: each robot plugin crate under `plugins/` describes itself
//! (`robot()`); registering it is one line here. A robot file is read where it is named.

use twinbots_task::Registry;
pub use twinbots_task::RobotDescription as RobotEntry;

/// Every robot of this build.
pub fn builtin() -> Registry {
    let mut registry = Registry::default();
    for robot in [cartpole::robot(), pioneer3at::robot(), ur5e::robot()] {
        registry.register(robot).expect("built-in robots have distinct names");
    }
    registry
}

/// Every robot of this build, in registration order.
pub fn robots() -> Vec<RobotEntry> {
    builtin().robots().to_vec()
}

/// Looks a robot up: a built-in name, or the path of a robot file (`*.toml`: any serial arm,
/// `twinbots_arm`); an unknown name lists the known ones.
pub fn find(name: &str) -> anyhow::Result<RobotEntry> {
    if twinbots_sim::urdf::robot_file::RobotFile::is_path(name) {
        return twinbots_arm::robot(std::path::Path::new(name));
    }
    builtin().find(name).cloned()
}
