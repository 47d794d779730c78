//! What a real arm's joints should exert, and the shadow that notices when they exert more.
//!
//! The twin's effort model of an arm from a robot file: inverse dynamics of its chain (the URDF's
//! links, [`Dynamics`]) plus, per joint, Coulomb friction (`tanh(q̇ / COULOMB_SPEED)`), viscous
//! friction and the rotor's inertia (armature). Calibrating it to logs is linear least squares —
//! the efforts are linear in all of these — with a ridge towards the URDF's inertial parameters,
//! so what the logs cannot tell (the base-parameter combinations they never excite) stays the
//! vendor's. Accelerations come from the measured speeds, differentiated and averaged over
//! [`ACCELERATION_WINDOW`] samples.
//!
//! The [`Shadow`] compares, along a recording, the measured efforts with the model's along the
//! measured motion (as a UR's own collision detection does), each residual averaged over
//! [`RESIDUAL_WINDOW`] samples. Its threshold per joint is learned from undisturbed logs: the
//! largest residual while the arm is calm (its quietest tenth of samples), plus a share of the acceleration
//! (the model is least exact when it accelerates), times a margin. Where a residual exceeds its
//! threshold it flags an interval: a collision, or a person pushing the arm.

use serde::{Deserialize, Serialize};
use twinbots_log::RobotLog;
use twinbots_sim::rapier::na::{DMatrix, DVector};
use twinbots_sim::urdf::dynamics::{Dynamics, GRAVITY, PARAMS_PER_BODY};
use twinbots_sim::urdf::robot_file::RobotFile;

/// Speed (rad/s) over which Coulomb friction changes sign.
pub const COULOMB_SPEED: f64 = 0.05;
/// Samples the accelerations are averaged over (72 ms at 125 Hz).
pub const ACCELERATION_WINDOW: usize = 9;
/// Samples the shadow's residuals are averaged over (104 ms at 125 Hz).
pub const RESIDUAL_WINDOW: usize = 13;
/// The ridge towards the URDF's inertial parameters, per sample and joint (N·m² per unit²): on
/// the real UR5's recordings the held-out errors fall from 0.01 to 1 and level off beyond
/// (docs/logs.md): its friction is what the description lacks most, its inertials are close.
pub const RIDGE: f64 = 1.0;
/// Acceleration (rad/s², the largest joint's) under which the arm counts as not accelerating.
const QUIET_ACCELERATION: f64 = 0.05;
/// Flags closer than this (s) are one.
const MERGE_GAP: f64 = 0.3;

/// `calibration.toml` of an arm from a robot file: its effort model, the shadow's thresholds, and
/// where they came from. Written by `identify ROBOT.toml`, read by `replay ROBOT.toml`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArmCalibration {
    /// The robot file's name.
    pub robot: String,
    /// Where the logs' efforts came from (`--efforts`, as given): a replay must read its log the same way.
    pub efforts: String,
    /// The logs fitted (and the shadow learned from).
    pub logs: Vec<String>,
    pub model: EffortModel,
    pub shadow: Shadow,
}

impl ArmCalibration {
    /// Reads and checks the file at `path` for `robot`; errors name the file.
    pub fn read(path: &std::path::Path, robot: &RobotFile, dynamics: &Dynamics) -> anyhow::Result<ArmCalibration> {
        let at = |e: anyhow::Error| anyhow::anyhow!("{}: {e:#}", path.display());
        let text = std::fs::read_to_string(path).map_err(|e| at(e.into()))?;
        let calibration: ArmCalibration =
            toml::from_str(&text).map_err(|e| at(anyhow::anyhow!("{}", e.to_string().trim_end())))?;
        anyhow::ensure!(
            calibration.robot == robot.name,
            "{}: calibrates robot '{}', not '{}'",
            path.display(),
            calibration.robot,
            robot.name
        );
        calibration.model.check(dynamics).map_err(at)?;
        calibration.shadow.check(dynamics.dof()).map_err(at)?;
        Ok(calibration)
    }

    /// Writes it to `path`, atomically.
    pub fn write(&self, path: &std::path::Path) -> anyhow::Result<()> {
        let text = toml::to_string(self).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        let head = "# An arm's effort model and shadow thresholds (twinbots identify; docs/logs.md).\n";
        twinbots_api::files::write_atomic(path, format!("{head}{text}").as_bytes())
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }
}

/// Reads each log for `robot` with `efforts` as its motion.
pub fn read_motions(
    robot: &RobotFile,
    paths: &[std::path::PathBuf],
    efforts: &twinbots_log::rtde_csv::Efforts,
) -> anyhow::Result<Vec<Motion>> {
    paths
        .iter()
        .map(|path| {
            let mapping = twinbots_log::Mapping { efforts: efforts.clone(), controller_joints: robot.joints.clone() };
            let log = twinbots_log::read_mapped(path, &mapping)?;
            Motion::of_log(robot, &log, &path.display().to_string())
        })
        .collect()
}

/// A log's motion and efforts in the chain's joint order.
#[derive(Clone, Debug)]
pub struct Motion {
    pub name: String,
    pub time: Vec<f64>,
    pub q: Vec<Vec<f64>>,
    pub qd: Vec<Vec<f64>>,
    pub qdd: Vec<Vec<f64>>,
    pub effort: Vec<Vec<f64>>,
}

impl Motion {
    /// `log`'s states for `robot`'s chain; the log must name its joints and measure efforts.
    pub fn of_log(robot: &RobotFile, log: &RobotLog, name: &str) -> anyhow::Result<Motion> {
        let columns: Vec<usize> = robot
            .chain
            .movable()
            .map(|j| {
                log.joint_index(&j.name).ok_or_else(|| {
                    anyhow::anyhow!("{name}: no joint '{}' (the log has {})", j.name, log.joints.join(", "))
                })
            })
            .collect::<anyhow::Result<_>>()?;
        anyhow::ensure!(
            log.states.iter().all(|s| s.effort.len() == log.joints.len()),
            "{name}: the log has no efforts (a UR recording: --efforts current:K0,…,K5 or target_moment)"
        );
        anyhow::ensure!(log.states.len() > 2 * RESIDUAL_WINDOW, "{name}: {} samples, too few", log.states.len());
        let pick = |v: &Vec<f64>| columns.iter().map(|&c| v[c]).collect::<Vec<f64>>();
        Ok(Motion::new(
            name,
            log.states.iter().map(|s| s.time).collect(),
            log.states.iter().map(|s| pick(&s.position)).collect(),
            log.states.iter().map(|s| pick(&s.velocity)).collect(),
            log.states.iter().map(|s| pick(&s.effort)).collect(),
        ))
    }

    /// Samples' motion and efforts (the chain's joint order), the accelerations differentiated
    /// from the speeds and averaged over [`ACCELERATION_WINDOW`].
    pub fn new(name: &str, time: Vec<f64>, q: Vec<Vec<f64>>, qd: Vec<Vec<f64>>, effort: Vec<Vec<f64>>) -> Motion {
        let raw = differentiate(&time, &qd);
        Motion { name: name.to_string(), q, qdd: moving_average(&raw, ACCELERATION_WINDOW), qd, effort, time }
    }

    /// The largest joint acceleration at each sample, averaged as the residuals are.
    fn acceleration(&self) -> Vec<f64> {
        let largest: Vec<Vec<f64>> =
            self.qdd.iter().map(|a| vec![a.iter().fold(0.0f64, |m, v| m.max(v.abs()))]).collect();
        moving_average(&largest, RESIDUAL_WINDOW).into_iter().map(|v| v[0]).collect()
    }
}

/// Central differences of `values` over `time` (one-sided at the ends).
fn differentiate(time: &[f64], values: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let n = values.len();
    (0..n)
        .map(|k| {
            let (a, b) = (k.saturating_sub(1), (k + 1).min(n - 1));
            let dt = time[b] - time[a];
            values[a].iter().zip(&values[b]).map(|(x, y)| if dt > 0.0 { (y - x) / dt } else { 0.0 }).collect()
        })
        .collect()
}

/// The centred average over `window` samples (fewer at the ends).
fn moving_average(values: &[Vec<f64>], window: usize) -> Vec<Vec<f64>> {
    let (n, half) = (values.len(), window / 2);
    (0..n)
        .map(|k| {
            let (lo, hi) = (k.saturating_sub(half), (k + half + 1).min(n));
            let mut sum = vec![0.0; values[k].len()];
            for v in &values[lo..hi] {
                sum.iter_mut().zip(v).for_each(|(s, x)| *s += x);
            }
            sum.into_iter().map(|s| s / (hi - lo) as f64).collect()
        })
        .collect()
}

/// One joint's friction and rotor inertia.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointFriction {
    /// N·m.
    pub coulomb: f64,
    /// N·m·s/rad.
    pub viscous: f64,
    /// kg·m².
    pub armature: f64,
}

/// The arm's inertial parameters (ten a moving body, [`Dynamics`]'s order) and each joint's
/// friction, in the chain's joint order.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EffortModel {
    pub parameters: Vec<f64>,
    pub friction: Vec<JointFriction>,
}

impl EffortModel {
    /// The vendor's description as it stands: the URDF's inertials, no friction.
    pub fn nominal(dynamics: &Dynamics) -> Self {
        Self { parameters: dynamics.parameters(), friction: vec![JointFriction::default(); dynamics.dof()] }
    }

    /// Checks a model read from a file against the arm.
    pub fn check(&self, dynamics: &Dynamics) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.parameters.len() == dynamics.dof() * PARAMS_PER_BODY && self.friction.len() == dynamics.dof(),
            "{} inertial parameters and {} joints' friction: the arm has {} joints ({} parameters)",
            self.parameters.len(),
            self.friction.len(),
            dynamics.dof(),
            dynamics.dof() * PARAMS_PER_BODY
        );
        let finite =
            self.parameters.iter().chain(self.friction.iter().flat_map(|f| [&f.coulomb, &f.viscous, &f.armature]));
        anyhow::ensure!(finite.clone().all(|v| v.is_finite() && v.abs() < 1e6), "a value is not finite or beyond 1e6");
        Ok(())
    }

    /// The efforts along `motion`.
    pub fn efforts(&self, dynamics: &Dynamics, motion: &Motion) -> Vec<Vec<f64>> {
        (0..motion.time.len())
            .map(|k| {
                let (q, qd, qdd) = (&motion.q[k], &motion.qd[k], &motion.qdd[k]);
                let mut tau = dynamics.inverse_with(&self.parameters, q, qd, qdd, GRAVITY);
                for (j, f) in self.friction.iter().enumerate() {
                    tau[j] += f.coulomb * (qd[j] / COULOMB_SPEED).tanh() + f.viscous * qd[j] + f.armature * qdd[j];
                }
                tau
            })
            .collect()
    }

    /// Least squares over `motions`' samples, with [`RIDGE`] towards the URDF's inertials.
    pub fn fit(dynamics: &Dynamics, motions: &[Motion]) -> anyhow::Result<EffortModel> {
        let n = dynamics.dof();
        let inertial = n * PARAMS_PER_BODY;
        let cols = inertial + 3 * n;
        let mut normal = DMatrix::<f64>::zeros(cols, cols);
        let mut rhs = DVector::<f64>::zeros(cols);
        let mut rows = 0usize;
        let mut row = vec![0.0; cols];
        for motion in motions {
            for k in 0..motion.time.len() {
                let (q, qd, qdd) = (&motion.q[k], &motion.qd[k], &motion.qdd[k]);
                let y = dynamics.regressor(q, qd, qdd, GRAVITY);
                for j in 0..n {
                    row.iter_mut().for_each(|v| *v = 0.0);
                    row[..inertial].copy_from_slice(&y[j * inertial..(j + 1) * inertial]);
                    row[inertial + 3 * j] = (qd[j] / COULOMB_SPEED).tanh();
                    row[inertial + 3 * j + 1] = qd[j];
                    row[inertial + 3 * j + 2] = qdd[j];
                    let r = DVector::from_column_slice(&row);
                    normal.ger(1.0, &r, &r, 1.0);
                    rhs.axpy(motion.effort[k][j], &r, 1.0);
                    rows += 1;
                }
            }
        }
        anyhow::ensure!(rows > cols, "{rows} effort samples for {cols} unknowns: too few");
        // The ridge: inertials held towards the URDF's, friction all but free.
        let nominal = dynamics.parameters();
        for c in 0..cols {
            let weight = rows as f64 * if c < inertial { RIDGE } else { 1e-6 };
            normal[(c, c)] += weight;
            if c < inertial {
                rhs[c] += weight * nominal[c];
            }
        }
        let solution = normal
            .cholesky()
            .map(|c| c.solve(&rhs))
            .ok_or_else(|| anyhow::anyhow!("the least-squares system is singular"))?;
        let friction = (0..n)
            .map(|j| JointFriction {
                coulomb: solution[inertial + 3 * j],
                viscous: solution[inertial + 3 * j + 1],
                armature: solution[inertial + 3 * j + 2],
            })
            .collect();
        let model = EffortModel { parameters: solution.as_slice()[..inertial].to_vec(), friction };
        model.check(dynamics)?;
        Ok(model)
    }
}

/// Root mean square of `measured − predicted`, per joint.
pub fn rmse(measured: &[Vec<f64>], predicted: &[Vec<f64>]) -> Vec<f64> {
    let n = measured.first().map_or(0, Vec::len);
    let mut sum = vec![0.0; n];
    for (m, p) in measured.iter().zip(predicted) {
        for j in 0..n {
            sum[j] += (m[j] - p[j]).powi(2);
        }
    }
    sum.into_iter().map(|s| (s / measured.len().max(1) as f64).sqrt()).collect()
}

/// The shadow's thresholds per joint (N·m): `margin · (quiet + per_acceleration · a)`, `a` the
/// largest joint acceleration (rad/s², averaged as the residuals are).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Shadow {
    pub quiet: Vec<f64>,
    pub per_acceleration: Vec<f64>,
    pub margin: f64,
}

/// A stretch of a recording where a joint's residual exceeded its threshold.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Flag {
    /// Seconds from the recording's start.
    pub start: f64,
    pub end: f64,
    /// The joints (chain order) whose residual exceeded the threshold in it.
    pub joints: Vec<usize>,
    /// The largest residual over its threshold in it.
    pub peak: f64,
}

/// A flag as `replay.json` and `monitor.json` give it: its joints by name.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FlagReport {
    /// Seconds from the recording's start.
    pub start: f64,
    pub end: f64,
    pub peak: f64,
    pub joints: Vec<String>,
}

impl FlagReport {
    /// `flag` with its joints named from `joints` (the chain's order).
    pub fn of(flag: &Flag, joints: &[String]) -> Self {
        Self {
            start: flag.start,
            end: flag.end,
            peak: flag.peak,
            joints: flag.joints.iter().map(|&j| joints[j].clone()).collect(),
        }
    }
}

/// Flags as samples are judged one after another: a sample over its threshold on some joint
/// extends the last flag if it ended at most [`MERGE_GAP`] before, or begins one.
#[derive(Clone, Debug, Default)]
pub struct Flags {
    pub list: Vec<Flag>,
}

impl Flags {
    /// Judges the sample at `t` (s from the recording's start); returns the flag it began.
    pub fn judge(&mut self, t: f64, residual: &[f64], limit: &[f64]) -> Option<&Flag> {
        let over: Vec<usize> = (0..residual.len()).filter(|&j| residual[j].abs() > limit[j]).collect();
        if over.is_empty() {
            return None;
        }
        let peak = over.iter().map(|&j| residual[j].abs() / limit[j]).fold(0.0, f64::max);
        match self.list.last_mut() {
            Some(last) if t - last.end <= MERGE_GAP => {
                last.end = t;
                last.peak = last.peak.max(peak);
                for j in over {
                    if !last.joints.contains(&j) {
                        last.joints.push(j);
                    }
                }
                last.joints.sort_unstable();
                None
            }
            _ => {
                self.list.push(Flag { start: t, end: t, joints: over, peak });
                self.list.last()
            }
        }
    }
}

/// The samples away from a recording's ends, where the differences and averages are whole.
fn settled(len: usize) -> std::ops::Range<usize> {
    RESIDUAL_WINDOW.min(len)..len.saturating_sub(RESIDUAL_WINDOW)
}

/// The residuals (measured − predicted, a model's [`EffortModel::efforts`] along the motion),
/// averaged over [`RESIDUAL_WINDOW`].
pub fn residuals(measured: &[Vec<f64>], predicted: &[Vec<f64>]) -> Vec<Vec<f64>> {
    let raw: Vec<Vec<f64>> =
        measured.iter().zip(predicted).map(|(m, p)| m.iter().zip(p).map(|(a, b)| a - b).collect()).collect();
    moving_average(&raw, RESIDUAL_WINDOW)
}

impl Shadow {
    /// Thresholds from undisturbed `motions`: what the residuals reached there, times `margin`.
    pub fn learn(model: &EffortModel, dynamics: &Dynamics, motions: &[Motion], margin: f64) -> Shadow {
        let n = dynamics.dof();
        let samples: Vec<(Vec<f64>, f64)> = motions
            .iter()
            .flat_map(|m| {
                let inner = settled(m.time.len());
                residuals(&m.effort, &model.efforts(dynamics, m))
                    .into_iter()
                    .zip(m.acceleration())
                    .take(inner.end)
                    .skip(inner.start)
            })
            .collect();
        // The quietest tenth of the samples (or all those under QUIET_ACCELERATION, if more):
        // a recording that never rests still has its calmer stretches.
        let mut by_acceleration: Vec<f64> = samples.iter().map(|s| s.1).collect();
        by_acceleration.sort_by(f64::total_cmp);
        let calm = by_acceleration.get(by_acceleration.len() / 10).copied().unwrap_or(0.0).max(QUIET_ACCELERATION);
        let mut quiet = vec![0.0f64; n];
        for (r, a) in &samples {
            if *a <= calm {
                quiet.iter_mut().zip(r).for_each(|(q, v)| *q = q.max(v.abs()));
            }
        }
        let mut per_acceleration = vec![0.0f64; n];
        for (r, a) in &samples {
            for j in 0..n {
                let excess = r[j].abs() - quiet[j];
                if excess > 0.0 {
                    per_acceleration[j] = per_acceleration[j].max(excess / a.max(calm));
                }
            }
        }
        Shadow { quiet, per_acceleration, margin }
    }

    /// The thresholds at each sample of `motion`.
    pub fn thresholds(&self, motion: &Motion) -> Vec<Vec<f64>> {
        motion
            .acceleration()
            .into_iter()
            .map(|a| self.quiet.iter().zip(&self.per_acceleration).map(|(q, k)| self.margin * (q + k * a)).collect())
            .collect()
    }

    /// Where `residuals` exceed the thresholds along `motion`, as intervals.
    pub fn flags(&self, motion: &Motion, residuals: &[Vec<f64>]) -> Vec<Flag> {
        let t0 = motion.time[0];
        let mut flags = Flags::default();
        let inner = settled(motion.time.len());
        for (k, (r, limit)) in residuals.iter().zip(self.thresholds(motion)).enumerate() {
            if inner.contains(&k) {
                flags.judge(motion.time[k] - t0, r, &limit);
            }
        }
        flags.list
    }

    /// Checks thresholds read from a file against the arm.
    pub fn check(&self, dof: usize) -> anyhow::Result<()> {
        anyhow::ensure!(
            self.quiet.len() == dof && self.per_acceleration.len() == dof,
            "shadow thresholds for {} joints: the arm has {dof}",
            self.quiet.len()
        );
        let values = self.quiet.iter().chain(&self.per_acceleration).chain(std::iter::once(&self.margin));
        anyhow::ensure!(
            values.clone().all(|v| v.is_finite() && *v >= 0.0),
            "a shadow threshold is negative or not finite"
        );
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;
    use twinbots_log::{JointSample, LogMeta};

    fn ur5() -> (RobotFile, Dynamics) {
        let robot =
            RobotFile::read(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../assets/robots/ur5.toml")).unwrap();
        let dynamics = Dynamics::of(&robot.chain);
        (robot, dynamics)
    }

    /// A log of `truth`'s efforts along a smooth motion of every joint.
    fn log_of(robot: &RobotFile, dynamics: &Dynamics, truth: &EffortModel, seconds: f64, phase: f64) -> RobotLog {
        let dt = robot.control_period;
        let states = (0..(seconds / dt) as usize)
            .map(|k| {
                let t = k as f64 * dt;
                let w: Vec<f64> = (0..6).map(|j| 0.7 + 0.31 * j as f64).collect();
                let q: Vec<f64> = (0..6).map(|j| 0.8 * (w[j] * t + phase + j as f64).sin()).collect();
                let qd: Vec<f64> = (0..6).map(|j| 0.8 * w[j] * (w[j] * t + phase + j as f64).cos()).collect();
                let qdd: Vec<f64> = (0..6).map(|j| -0.8 * w[j] * w[j] * (w[j] * t + phase + j as f64).sin()).collect();
                let motion = Motion {
                    name: String::new(),
                    time: vec![t],
                    q: vec![q.clone()],
                    qd: vec![qd.clone()],
                    qdd: vec![qdd],
                    effort: vec![vec![0.0; 6]],
                };
                // The measurement's noise: ±0.5 N·m, deterministic.
                let noise = |j: usize| 0.5 * ((k * 7 + j * 13) as f64 * 12.9898).sin();
                let effort =
                    truth.efforts(dynamics, &motion).remove(0).iter().enumerate().map(|(j, e)| e + noise(j)).collect();
                JointSample { time: t, position: q, velocity: qd, effort }
            })
            .collect();
        RobotLog {
            meta: LogMeta::default(),
            joints: robot.joints.clone(),
            states,
            commands: Vec::new(),
            tool: Vec::new(),
        }
    }

    #[test]
    fn a_fit_recovers_friction_and_predicts_a_held_out_motion() {
        let (robot, dynamics) = ur5();
        let mut truth = EffortModel::nominal(&dynamics);
        for (j, f) in truth.friction.iter_mut().enumerate() {
            *f = JointFriction { coulomb: 3.0 - 0.4 * j as f64, viscous: 2.0 + 0.5 * j as f64, armature: 0.1 };
        }
        truth.parameters[2 * PARAMS_PER_BODY] *= 1.2; // the upper arm 20 % heavier
        let fitting = Motion::of_log(&robot, &log_of(&robot, &dynamics, &truth, 20.0, 0.0), "fit").unwrap();
        let held_out = Motion::of_log(&robot, &log_of(&robot, &dynamics, &truth, 10.0, 1.3), "held out").unwrap();
        let fitted = EffortModel::fit(&dynamics, std::slice::from_ref(&fitting)).unwrap();
        let before = rmse(&held_out.effort, &EffortModel::nominal(&dynamics).efforts(&dynamics, &held_out));
        let after = rmse(&held_out.effort, &fitted.efforts(&dynamics, &held_out));
        for j in 0..6 {
            assert!(after[j] < 0.2 * before[j], "joint {j}: {:.3} after, {:.3} before", after[j], before[j]);
            assert!((fitted.friction[j].coulomb - truth.friction[j].coulomb).abs() < 0.3, "{:?}", fitted.friction[j]);
        }
        // The shadow learned on undisturbed motions flags a push on the held-out one, and
        // nothing without it.
        let another = Motion::of_log(&robot, &log_of(&robot, &dynamics, &truth, 20.0, 2.6), "another").unwrap();
        let shadow = Shadow::learn(&fitted, &dynamics, &[fitting, another], 1.5);
        let quiet = shadow.flags(&held_out, &residuals(&held_out.effort, &fitted.efforts(&dynamics, &held_out)));
        assert!(quiet.is_empty(), "{quiet:?}");
        let mut pushed = held_out.clone();
        for k in 500..560 {
            pushed.effort[k][1] += 30.0;
        }
        let flags = shadow.flags(&pushed, &residuals(&pushed.effort, &fitted.efforts(&dynamics, &pushed)));
        assert_eq!(flags.len(), 1, "{flags:?}");
        assert!(flags[0].joints.contains(&1) && (3.9..4.1).contains(&flags[0].start), "{flags:?}");
    }
}
