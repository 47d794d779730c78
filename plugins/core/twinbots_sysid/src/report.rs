//! What a fit leaves behind: the held-out logs' error before and after ([`validate`]) and the
//! calibration file it makes ([`calibration_of`]).

use std::path::Path;

use twinbots_sim::Parameters;
use twinbots_task::calibration::{Calibration, FitRecord};

use crate::identify::{Fit, position_rmse};
use crate::replay::PreparedLog;
use crate::rig::{Rig, run};

/// Held-out logs before and after.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Validation {
    pub logs: Vec<String>,
    /// The joint-position RMSE (rad) of the starting twin, and of the calibrated one.
    pub nominal: f64,
    pub calibrated: f64,
    /// (calibrated − nominal) / nominal.
    pub change: f64,
}

/// The held-out `logs`' joint-position error with the `nominal` and the `calibrated` parameters,
/// and a plot of the first log replayed by both (`validation_png`); none without logs.
pub fn validate(
    rig: &Rig,
    logs: &[PreparedLog],
    nominal: &Parameters,
    calibrated: &Parameters,
    validation_png: &Path,
) -> anyhow::Result<Option<Validation>> {
    let Some(first) = logs.first() else { return Ok(None) };
    let before = position_rmse(rig, logs, nominal, 0.05);
    let after = position_rmse(rig, logs, calibrated, 0.05);
    let twins = run(rig, &first.start_positions(rig, nominal), &first.program, &[nominal.clone(), calibrated.clone()]);
    let twins =
        [("twin (nominal)", &twins[0], rig.biases(nominal)), ("twin (calibrated)", &twins[1], rig.biases(calibrated))];
    crate::plot::replay_png(validation_png, rig, &first.plot(rig, &twins))?;
    Ok(Some(Validation {
        logs: logs.iter().map(|l| l.name.clone()).collect(),
        nominal: before,
        calibrated: after,
        change: (after - before) / before.max(1e-12),
    }))
}

impl Validation {
    /// Records the held-out errors in a calibration's `[fit]`.
    pub fn note(&self, calibration: &mut Calibration) {
        if let Some(fit) = calibration.fit.as_mut() {
            fit.validation_position_rmse_nominal = Some(self.nominal);
            fit.validation_position_rmse_calibrated = Some(self.calibrated);
        }
    }
}

/// The calibration file `fit` makes: the fitted values over `base` (the calibration it started
/// from), their spreads and flags, and how the fit went ([`Validation::note`] adds the held-out
/// errors).
pub fn calibration_of(fit: &Fit, base: &Parameters) -> Calibration {
    let mut parameters = base.clone();
    parameters.extend(&fit.values());
    Calibration {
        parameters,
        spread: Parameters(fit.parameters.iter().map(|p| (p.name.clone(), p.spread)).collect()),
        not_identifiable: fit
            .parameters
            .iter()
            .filter_map(|p| p.not_identifiable.as_ref().map(|why| (p.name.clone(), why.clone())))
            .collect(),
        fit: Some(FitRecord {
            robot: fit.robot.clone(),
            twinbots: env!("CARGO_PKG_VERSION").into(),
            logs: fit.logs.clone(),
            tracking_error_nominal: fit.cost_nominal,
            tracking_error_calibrated: fit.cost_fitted,
            replay_noise: fit.replay_noise,
            candidates: fit.candidates as u64,
            seconds: fit.seconds,
            validation_position_rmse_nominal: None,
            validation_position_rmse_calibrated: None,
        }),
    }
}
