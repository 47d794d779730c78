//! A run's calibration setting: `twinbots identify`'s file, read and recorded in the run.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};
use twinbots_task::randomization::{FitSpread, Randomization};

use crate::registry::RobotEntry;

/// The twin's calibration (`twinbots identify`'s file), recorded in full in the run's
/// `config.toml`: the run does not depend on the file afterwards.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSetting {
    /// The file it was read from.
    pub file: String,
    /// Its `[parameters]`, over the robot's nominal ones.
    pub parameters: BTreeMap<String, f64>,
    /// Its `[spread]`: each fitted value's standard deviation, which
    /// `randomization.calibration_spread` draws with (none in a hand-written file).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub spread: BTreeMap<String, f64>,
}

impl CalibrationSetting {
    /// Reads a calibration file, checked against the robot's parameters.
    pub fn read(entry: &RobotEntry, path: &Path) -> anyhow::Result<Self> {
        let rig = twinbots_sysid::Rig::of(entry)?;
        let calibration = twinbots_task::calibration::Calibration::read(path, &rig.catalogue, rig.robot)?;
        Ok(Self {
            file: path.display().to_string(),
            parameters: calibration.parameters.0,
            spread: calibration.spread.0,
        })
    }

    /// [`CalibrationSetting::read`] of the file, if one is given.
    pub fn read_optional(entry: &RobotEntry, path: Option<&Path>) -> anyhow::Result<Option<Self>> {
        path.map(|path| Self::read(entry, path)).transpose()
    }

    /// The parameters as the resource apps take.
    pub fn parameters(&self) -> twinbots_sim::Parameters {
        twinbots_sim::Parameters(self.parameters.clone())
    }

    /// Puts the calibration over the twin's nominal parameters in `app`, before its start-up
    /// applies them, and its spread where randomization can draw with it.
    pub fn configure(&self, app: &mut bevy::prelude::App) {
        twinbots_task::calibration::calibrate(app, &self.parameters());
        app.insert_resource(FitSpread(twinbots_sim::Parameters(self.spread.clone())));
    }

    /// `randomization`'s check that a spread it draws with is there.
    pub fn check_randomization(calibration: Option<&Self>, randomization: &Randomization) -> anyhow::Result<()> {
        randomization.check_spread(calibration.is_some_and(|c| !c.spread.is_empty()))
    }
}
