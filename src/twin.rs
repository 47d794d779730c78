//! The twin a command runs: a calibration over the robot's nominal physics (`--calibration`),
//! and a log of arena 0's episodes (`--log`, `robot_log`).

use std::path::Path;

use bevy::app::App;

use crate::registry::RobotEntry;
use crate::robot_log::RobotLogPlugin;
use crate::settings::CalibrationSetting;

/// Calibrates `app` (a twin of `entry`) by `calibration` and logs it to `log`, each if given.
/// The log's path is checked before anything is added.
pub fn configure(app: &mut App, entry: &RobotEntry, calibration: Option<&CalibrationSetting>, log: Option<&Path>) -> anyhow::Result<()> {
    let file = calibration.map(|c| Path::new(&c.file));
    let plugin = log.map(|path| RobotLogPlugin::new(entry, path.to_path_buf(), file)).transpose()?;
    if let Some(c) = calibration {
        twinbots_task::calibration::calibrate(app, &c.parameters());
    }
    if let Some(plugin) = plugin {
        app.add_plugins(plugin);
    }
    Ok(())
}
