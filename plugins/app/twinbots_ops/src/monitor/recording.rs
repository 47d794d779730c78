//! `monitor ROBOT.toml --replay LOG`: a recording played back as the robot would stream it (in
//! real time, or faster), each sample's efforts judged by the calibrated shadow as it arrives
//! ([`ShadowStream`]): what `monitor` does beside a live arm, on a recording, and flagging what
//! `replay` flags on the whole of it.

use std::time::{Duration, Instant};

use serde::Serialize;
use twinbots_sim::urdf::dynamics::Dynamics;
use twinbots_sysid::effort_model::{ArmCalibration, FlagReport, Motion};
use twinbots_sysid::shadow_stream::{Judged, Sample, ShadowStream};

/// What following a recording found (`monitor.json`).
#[derive(Clone, Debug, Serialize)]
pub struct RecordingReport {
    pub robot: String,
    pub log: String,
    pub joints: Vec<String>,
    /// Samples played back, and judged (all but the first and last few).
    pub samples: usize,
    pub judged: usize,
    /// Recording time played back (s).
    pub seconds: f64,
    /// What ended it early (Ctrl-C, SIGTERM), if anything did.
    pub ended: Option<String>,
    pub flagged: Vec<FlagReport>,
}

/// The judged samples' residuals and thresholds, for the plot.
#[derive(Clone, Debug, Default)]
pub struct Trace {
    pub time: Vec<f64>,
    pub residual: Vec<Vec<f64>>,
    pub threshold: Vec<Vec<f64>>,
}

/// Plays `motion` back at `speed` × real time (0: as fast as it goes) through the shadow of
/// `calibration`; `each` sees every sample as it arrives and the judgement it made possible (a
/// new flag is an alarm). Ctrl-C or SIGTERM ends it early, with what was followed.
pub fn follow(
    robot: &str,
    joints: &[String],
    dynamics: &Dynamics,
    calibration: &ArmCalibration,
    motion: &Motion,
    speed: f64,
    mut each: impl FnMut(&Sample, Option<&Judged>),
) -> anyhow::Result<(RecordingReport, Trace)> {
    anyhow::ensure!(
        speed >= 0.0 && speed.is_finite(),
        "--speed must be 0 (as fast as it goes) or positive, not {speed}"
    );
    let mut stream = ShadowStream::new(dynamics, &calibration.model, &calibration.shadow);
    let mut trace = Trace::default();
    let started = Instant::now();
    let t0 = motion.time.first().copied().unwrap_or(0.0);
    let mut ended = None;
    let mut played = 0;
    for k in 0..motion.time.len() {
        if let Some(signal) = crate::stop_signal::requested() {
            ended = Some(format!("stopped by {signal}"));
            break;
        }
        if speed > 0.0 {
            let due = Duration::from_secs_f64((motion.time[k] - t0) / speed);
            if let Some(wait) = due.checked_sub(started.elapsed()) {
                std::thread::sleep(wait);
            }
        }
        let sample = Sample {
            time: motion.time[k],
            q: motion.q[k].clone(),
            qd: motion.qd[k].clone(),
            effort: motion.effort[k].clone(),
        };
        let judged = stream.push(sample.clone());
        if let Some(j) = &judged {
            trace.time.push(j.time);
            trace.residual.push(j.residual.clone());
            trace.threshold.push(j.threshold.clone());
        }
        each(&sample, judged.as_ref());
        played += 1;
    }
    let report = RecordingReport {
        robot: robot.to_string(),
        log: motion.name.clone(),
        joints: joints.to_vec(),
        samples: played,
        judged: trace.time.len(),
        seconds: motion.time.get(played.saturating_sub(1)).map_or(0.0, |t| t - t0),
        ended,
        flagged: stream.flags().iter().map(|f| FlagReport::of(f, joints)).collect(),
    };
    Ok((report, trace))
}

/// `/shadow` of the live view: each judged sample's residual (measured less predicted effort)
/// and its threshold, per joint.
pub const SHADOW: twinbots_live::JsonSchema = twinbots_live::JsonSchema {
    name: "twinbots/Shadow",
    schema: r#"{"title":"twinbots/Shadow","type":"object","properties":{"time":{"type":"number"},"name":{"type":"array","items":{"type":"string"}},"residual":{"type":"array","items":{"type":"number"}},"threshold":{"type":"array","items":{"type":"number"}}}}"#,
};
