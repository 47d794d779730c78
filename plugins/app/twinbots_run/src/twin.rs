//! The twin a command runs: a calibration over the robot's nominal physics (`--calibration`),
//! and a log of arena 0's episodes (`--log`, `robot_log`).

use std::path::{Path, PathBuf};

use bevy::app::App;

use crate::registry::RobotEntry;
use crate::robot_log::RobotLogPlugin;
use crate::settings::CalibrationSetting;

/// The twin an app runs, and where it is logged.
#[derive(Clone, Debug, Default)]
pub struct Twin {
    pub calibration: Option<CalibrationSetting>,
    pub log: Option<PathBuf>,
}

impl Twin {
    /// The twin of the files given: a calibration file (read and checked against `entry`'s
    /// parameters) and a log path.
    pub fn of_files(entry: &RobotEntry, calibration: Option<&Path>, log: Option<&Path>) -> anyhow::Result<Self> {
        Ok(Self {
            calibration: CalibrationSetting::read_optional(entry, calibration)?,
            log: log.map(Path::to_path_buf),
        })
    }

    /// Calibrates `app` (a twin of `entry`) and logs it, each if asked for. The log's path is
    /// checked before anything is added.
    pub fn configure(&self, app: &mut App, entry: &RobotEntry) -> anyhow::Result<()> {
        let file = self.calibration.as_ref().map(|c| Path::new(&c.file));
        let plugin = self.log.as_ref().map(|path| RobotLogPlugin::new(entry, path.clone(), file)).transpose()?;
        if let Some(c) = &self.calibration {
            c.configure(app);
        }
        if let Some(plugin) = plugin {
            app.add_plugins(plugin);
        }
        Ok(())
    }
}
