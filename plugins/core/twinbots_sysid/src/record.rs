//! A stand-in for a real robot: the twin with hidden "true" physics, driven through an
//! excitation program, logging only what a controller measures (joint encoders with their
//! bias and noise, speeds, motor efforts) and the commands it sent.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use twinbots_log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog};
use twinbots_sim::{MotorCommand, Parameters};

use crate::excitation::{Excitation, program};
use crate::rig::{Rig, run};

/// A known truth to recover (`tests/logs/recovery.rs`, `examples/sysid_truth_probe.rs`): every
/// parameter the rig fits off where a calibration starts (the robot's prior) by up to ±30 % —
/// the prior times 1.3, 0.7, 1.25, 0.75, 1.2, 0.8 in turn, zeros left at zero — and a 12 ms
/// command delay.
pub fn perturbed_truth(rig: &Rig) -> Parameters {
    let factors = [1.3, 0.7, 1.25, 0.75, 1.2, 0.8];
    let prior = rig.description.prior_parameters();
    let mut truth = Parameters::default();
    for (i, name) in rig.description.fit.iter().enumerate() {
        let nominal = rig.value(&prior, name);
        truth.0.insert(name.to_string(), if nominal > 0.0 { nominal * factors[i % factors.len()] } else { nominal });
    }
    truth.0.insert("command_delay".into(), 0.012);
    truth
}

/// A hidden truth drawn at random (seeded) from the prior's ranges: each positive fitted
/// parameter the prior's value times 2^u, u uniform in [−1, 1] (well inside the search's range,
/// a quarter to four times the start), the others as the prior has them, and the command delay
/// uniform in [4, 20] ms. What a recovery test is judged on when it must not be tuned to one truth.
pub fn random_truth(rig: &Rig, seed: u64) -> Parameters {
    use rand::Rng;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let prior = rig.description.prior_parameters();
    let mut truth = Parameters::default();
    for name in &rig.description.fit {
        let start = rig.value(&prior, name);
        let value = if start > 0.0 { start * 2f64.powf(rng.random_range(-1.0..=1.0)) } else { start };
        truth.0.insert(name.to_string(), value);
    }
    truth.0.insert("command_delay".into(), rng.random_range(0.004..=0.020));
    truth
}

/// The longest recording (s): an hour of a robot's log, about 450,000 joint states at 125 Hz.
pub const MAX_SECONDS: f64 = 3600.0;

/// Standard deviations of the measurement noise.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorNoise {
    /// Encoder noise (rad or m).
    pub position: f64,
    /// Speed noise (rad/s or m/s).
    pub velocity: f64,
    /// Effort noise (N·m or N).
    pub effort: f64,
}

impl Default for SensorNoise {
    /// About a UR's: 0.1 mrad encoders, speeds from differentiated encoders, efforts from currents.
    fn default() -> Self {
        Self { position: 1e-4, velocity: 2e-3, effort: 0.05 }
    }
}

/// What to record.
#[derive(Clone, Debug)]
pub struct Recording {
    pub excitation: Excitation,
    pub seconds: f64,
    pub seed: u64,
    pub noise: SensorNoise,
}

/// Records the rig run with `truth` (over its nominal parameters): a log of every physics step.
pub fn record(rig: &Rig, truth: &Parameters, recording: &Recording) -> anyhow::Result<RobotLog> {
    anyhow::ensure!(
        recording.seconds > 0.0 && recording.seconds <= MAX_SECONDS,
        "--seconds must be positive and at most {MAX_SECONDS} (an hour), not {}",
        recording.seconds
    );
    let params = rig.parameters(truth)?;
    let program = program(rig, recording.excitation, recording.seconds, recording.seed);
    let trajectory = run(rig, &[], &program, std::slice::from_ref(&params)).pop().expect("one arena, one trajectory");
    let bias = rig.biases(&params);
    let mut rng = ChaCha8Rng::seed_from_u64(recording.seed ^ twinbots_api::seeds::RECORDING_NOISE);
    let noise = recording.noise;
    let mut n =
        |std: f64| if std > 0.0 { Normal::new(0.0, std).expect("a positive std").sample(&mut rng) } else { 0.0 };
    let states: Vec<JointSample> = trajectory
        .samples(rig.dt(), &bias)
        .into_iter()
        .map(|mut s| {
            s.position.iter_mut().for_each(|q| *q += n(noise.position));
            s.velocity.iter_mut().for_each(|v| *v += n(noise.velocity));
            // An unactuated joint has no drive to measure an effort with: 0.
            s.effort.iter_mut().zip(&rig.actuated).for_each(|(e, &a)| *e = if a { *e + n(noise.effort) } else { 0.0 });
            s
        })
        .collect();
    let dt = rig.dt();
    let commands = program
        .changes
        .iter()
        .enumerate()
        .filter(|(_, c)| !c.is_empty())
        .map(|(k, changes)| {
            let (joints, values) = changes
                .iter()
                .map(|&(j, c)| {
                    let MotorCommand::Velocity(v) = c else { unreachable!("excitation commands speeds") };
                    (rig.joints[j].clone(), v as f64)
                })
                .unzip();
            CommandSample { time: k as f64 * dt, modes: vec![CommandMode::Velocity; changes.len()], joints, values }
        })
        .collect();
    let meta = LogMeta {
        robot: rig.robot.to_string(),
        source: format!("twinbots {} record (a stand-in robot)", env!("CARGO_PKG_VERSION")),
        calibration: String::new(),
        control_period: dt * rig.description.command_steps.max(1) as f64,
        extra: [
            ("excitation".to_string(), recording.excitation.name().to_string()),
            ("seed".to_string(), recording.seed.to_string()),
        ]
        .into_iter()
        .collect(),
    };
    Ok(RobotLog { meta, joints: rig.joints.clone(), states, commands, tool: Vec::new() })
}
