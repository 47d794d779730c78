//! `twinbots deploy`: a bundle's policy on a robot, at the control period it was trained with,
//! the twin as its shadow. Every control period (counted on the controller's clock) the
//! controller's state becomes the task's observation, the policy acts, the shadow checks the
//! joint speeds (clipping or refusing them) and only then do they go to the robot. Episodes are
//! the task's: home, a target from the task's sampler, up to its step limit. A missed deadline
//! (the command later than `deadline` after the state it answers), a robot that stops
//! reporting, or any error stops the robot before the error is returned.

pub mod arm;
pub mod latency;

use std::time::Duration;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use twinbots_task::shadow::Shadow;

use twinbots_task::on_robot::ReachOnRobot;

use self::arm::{Arm, Measured};
use crate::bundle::Bundle;

/// How a deployment runs.
#[derive(Clone, Debug)]
pub struct DeployOptions {
    pub episodes: usize,
    pub seed: u64,
    /// The longest from a state's arrival to the command that answers it.
    pub deadline: Duration,
    /// The longest homing may take (controller time, s).
    pub homing_limit: f64,
}

impl Default for DeployOptions {
    fn default() -> Self {
        Self { episodes: 100, seed: 0, deadline: Duration::from_millis(20), homing_limit: 10.0 }
    }
}

/// One episode on the robot.
#[derive(Clone, Debug, Serialize)]
pub struct EpisodeReport {
    pub episode: usize,
    pub success: bool,
    pub steps: u32,
    /// Time to arrival (s), if it arrived.
    pub cycle_time_s: Option<f64>,
    pub final_error_mm: f64,
    /// Mechanical energy the joints put in (J): Σ |τ·q̇| dt over the controller's reports.
    pub energy_j: f64,
    pub clipped: u32,
    pub refused: u32,
    pub target: [f32; 3],
}

/// A deployment's account.
#[derive(Clone, Debug, Serialize)]
pub struct DeployReport {
    pub robot: String,
    pub arm: String,
    pub episodes: Vec<EpisodeReport>,
    pub success_rate: f64,
    pub mean_cycle_time_s: Option<f64>,
    pub mean_energy_j: f64,
    pub clipped: u32,
    pub refused: u32,
    /// State in → command out (µs), over every command sent.
    pub latency_p50_us: f64,
    pub latency_p99_us: f64,
    pub latency_max_us: f64,
    pub commands: usize,
}

/// The shadow a bundle's limits describe, for the bundle's robot in its cell.
pub fn shadow_of(bundle: &Bundle) -> Shadow {
    let m = &bundle.manifest;
    Shadow {
        max_speed: std::array::from_fn(|k| m.joints[k].max_speed_rad_s),
        max_acceleration: std::array::from_fn(|k| m.shadow.max_acceleration_rad_s2.at(k)),
        lookahead: m.shadow.lookahead_s,
        range_margin: m.shadow.range_margin_rad,
        table_clearance: m.shadow.table_clearance_m,
        ..bundle.robot.shadow(&bundle.cell)
    }
}

/// The reach controller of the bundle's robot in its cell (the UR5e's targets avoid the cell's
/// own pick fixture).
pub fn controller_of(bundle: &Bundle) -> Box<dyn ReachOnRobot> {
    bundle.robot.controller(&bundle.cell)
}

/// A policy: raw observation in, action out.
pub type PolicyFn<'a> = &'a dyn Fn(&[f32]) -> anyhow::Result<Vec<f32>>;

/// The program's states that mean it no longer moves the arm (`ur_sim::program::ProgramState`).
const WATCHDOG_STOP: i32 = crate::ur_sim::program::ProgramState::WatchdogStop as i32;
const PROTECTIVE_STOP: i32 = crate::ur_sim::program::ProgramState::ProtectiveStop as i32;

/// Runs `options.episodes` episodes of the bundle's policy on `arm`; `progress` sees each as it
/// ends. On any error the robot is told to stop first.
pub fn deploy(
    arm: &mut dyn Arm,
    bundle: &Bundle,
    options: &DeployOptions,
    progress: impl FnMut(&EpisodeReport),
) -> anyhow::Result<DeployReport> {
    deploy_policy(arm, bundle, &|obs| bundle.policy.act(obs), options, progress)
}

/// [`deploy`] with another policy than the bundle's (the shadow's tests drive reckless ones).
pub fn deploy_policy(
    arm: &mut dyn Arm,
    bundle: &Bundle,
    policy: PolicyFn<'_>,
    options: &DeployOptions,
    mut progress: impl FnMut(&EpisodeReport),
) -> anyhow::Result<DeployReport> {
    let mut run = Deployment::new(bundle, policy, options);
    let result = (|| -> anyhow::Result<Vec<EpisodeReport>> {
        let mut episodes = Vec::with_capacity(options.episodes);
        for episode in 0..options.episodes {
            run.home(arm)?;
            let report = run.episode(arm, episode)?;
            progress(&report);
            episodes.push(report);
        }
        Ok(episodes)
    })();
    let stopped = arm.stop();
    let episodes = result?;
    stopped?;
    Ok(run.report(bundle, arm, episodes))
}

/// The deployment's state between control steps.
struct Deployment<'a> {
    policy: PolicyFn<'a>,
    controller: Box<dyn ReachOnRobot>,
    shadow: Shadow,
    episode_steps: u32,
    rng: ChaCha8Rng,
    period: f64,
    deadline: Duration,
    homing_limit: f64,
    /// Each joint's range (± rad, the controller's order): a report beyond it stops the robot.
    ranges: Vec<(String, f64)>,
    /// The last command sent (for the shadow's acceleration limit).
    last: [f64; 6],
    /// When the next control step is due (controller time).
    next_step: Option<f64>,
    latencies: Vec<f64>,
    /// The last report, for the energy integral.
    previous: Option<Measured>,
    energy: f64,
}

impl<'a> Deployment<'a> {
    fn new(bundle: &Bundle, policy: PolicyFn<'a>, options: &DeployOptions) -> Self {
        Self {
            policy,
            controller: controller_of(bundle),
            shadow: shadow_of(bundle),
            episode_steps: bundle.robot.episode_steps(),
            rng: ChaCha8Rng::seed_from_u64(options.seed),
            period: bundle.manifest.control_period_s,
            deadline: options.deadline,
            homing_limit: options.homing_limit,
            ranges: bundle.manifest.joints.iter().map(|j| (j.name.clone(), j.range_rad)).collect(),
            last: [0.0; 6],
            next_step: None,
            latencies: Vec::new(),
            previous: None,
            energy: 0.0,
        }
    }

    /// What a report must show for the deployment to go on: finite joints, a clock that moved
    /// on (one that stands still, runs back or is not a number is a controller that is not
    /// controlling), joints within their ranges, a control program that runs.
    fn check(&self, m: &Measured) -> anyhow::Result<()> {
        anyhow::ensure!(
            m.q.iter().chain(&m.qd).all(|v| v.is_finite()),
            "the robot reported joints {:?}, speeds {:?}",
            m.q,
            m.qd
        );
        anyhow::ensure!(m.time.is_finite(), "the robot reported time {}; the robot was told to stop", m.time);
        if let Some(p) = &self.previous {
            anyhow::ensure!(
                m.time > p.time,
                "the robot's clock {} after {} s: it stood still or ran back; the robot was told to stop",
                if m.time == p.time { format!("read {} s again", m.time) } else { format!("read {} s", m.time) },
                p.time
            );
        }
        if let Some((k, (name, range))) =
            self.ranges.iter().enumerate().find(|(k, (_, range))| m.q.get(*k).is_some_and(|q| q.abs() > *range))
        {
            anyhow::bail!(
                "the robot reported {name} at {:.3} rad, beyond its range ±{range:.3}; the robot was told to stop",
                m.q[k]
            );
        }
        anyhow::ensure!(
            ![WATCHDOG_STOP, PROTECTIVE_STOP].contains(&m.program) && m.program >= 0,
            "the robot's control program {}; the robot was told to stop",
            match m.program {
                WATCHDOG_STOP => "stopped on its watchdog (commands came too late)".to_string(),
                PROTECTIVE_STOP => "is in a protective stop (a joint left its range)".to_string(),
                other => format!("reports no state it knows ({other}): is it running?"),
            }
        );
        Ok(())
    }

    /// Reads reports until the next control step is due; returns the one it is due at.
    fn wait_step(&mut self, arm: &mut dyn Arm) -> anyhow::Result<Measured> {
        loop {
            if let Some(signal) = crate::stop_signal::requested() {
                anyhow::bail!("stopped by {signal}; the robot was told to stop");
            }
            let m = arm.read()?;
            self.check(&m)?;
            if let Some(p) = &self.previous {
                let dt = (m.time - p.time).max(0.0);
                self.energy += dt * m.effort.iter().zip(&m.qd).map(|(e, v)| (e * v).abs()).sum::<f64>();
            }
            self.previous = Some(m.clone());
            let due = *self.next_step.get_or_insert(m.time);
            // Within rounding of the controller's 2 ms cycles.
            if m.time + 1e-6 >= due {
                self.next_step = Some(due + self.period);
                if m.time > due + self.period {
                    // Reports were lost (or came late): count steps from now.
                    self.next_step = Some(m.time + self.period);
                }
                self.controller.read(&m.q, &m.qd);
                return Ok(m);
            }
        }
    }

    /// The shadow's verdict on `wanted`, sent; returns whether it was clipped and refused.
    fn send(&mut self, arm: &mut dyn Arm, m: &Measured, wanted: [f64; 6]) -> anyhow::Result<(bool, bool)> {
        let verdict = self.shadow.check(&m.q, &wanted, &self.last, self.period);
        if verdict.refused {
            arm.stop()?;
        } else {
            arm.command(&verdict.command)?;
        }
        let latency = m.received.elapsed();
        self.latencies.push(latency.as_secs_f64() * 1e6);
        anyhow::ensure!(
            latency <= self.deadline,
            "missed the control deadline: the command went {:.1} ms after the state it answers (limit {:.1} ms); the robot was told to stop",
            latency.as_secs_f64() * 1e3,
            self.deadline.as_secs_f64() * 1e3
        );
        self.last = if verdict.refused { [0.0; 6] } else { verdict.command };
        for note in &verdict.notes {
            eprintln!("shadow: {note}");
        }
        Ok((verdict.clipped, verdict.refused))
    }

    /// Homes the arm with the controller's homing move.
    fn home(&mut self, arm: &mut dyn Arm) -> anyhow::Result<()> {
        let m = self.wait_step(arm)?;
        let start = m.time;
        let mut m = m;
        while !self.controller.is_home() {
            anyhow::ensure!(
                m.time - start < self.homing_limit,
                "the arm did not home within {} s (joints at {:?})",
                self.homing_limit,
                m.q
            );
            let speeds = six(self.controller.homing());
            self.send(arm, &m, speeds)?;
            m = self.wait_step(arm)?;
        }
        self.send(arm, &m, [0.0; 6])?;
        Ok(())
    }

    fn episode(&mut self, arm: &mut dyn Arm, episode: usize) -> anyhow::Result<EpisodeReport> {
        self.controller.new_reach(&mut self.rng);
        let energy_before = self.energy;
        let (mut clipped, mut refused, mut steps) = (0, 0, 0);
        let mut m = self.wait_step(arm)?;
        let mut success = self.controller.arrived();
        while !success && steps < self.episode_steps {
            let action = (self.policy)(self.controller.observation())?;
            let speeds = six(self.controller.act(&action));
            let (c, r) = self.send(arm, &m, speeds)?;
            clipped += u32::from(c);
            refused += u32::from(r);
            steps += 1;
            m = self.wait_step(arm)?;
            success = self.controller.arrived();
        }
        self.send(arm, &m, [0.0; 6])?;
        let target = self.controller.target();
        Ok(EpisodeReport {
            episode,
            success,
            steps,
            cycle_time_s: success.then_some(steps as f64 * self.period),
            final_error_mm: 1000.0 * self.controller.error() as f64,
            energy_j: self.energy - energy_before,
            clipped,
            refused,
            target: target.to_array(),
        })
    }

    fn report(&self, bundle: &Bundle, arm: &dyn Arm, episodes: Vec<EpisodeReport>) -> DeployReport {
        let n = episodes.len().max(1) as f64;
        let successes: Vec<f64> = episodes.iter().filter_map(|e| e.cycle_time_s).collect();
        let (p50, p99, max) = percentiles(&self.latencies);
        DeployReport {
            robot: bundle.manifest.robot.clone(),
            arm: arm.describe(),
            success_rate: successes.len() as f64 / n,
            mean_cycle_time_s: (!successes.is_empty()).then(|| successes.iter().sum::<f64>() / successes.len() as f64),
            mean_energy_j: episodes.iter().map(|e| e.energy_j).sum::<f64>() / n,
            clipped: episodes.iter().map(|e| e.clipped).sum(),
            refused: episodes.iter().map(|e| e.refused).sum(),
            latency_p50_us: p50,
            latency_p99_us: p99,
            latency_max_us: max,
            commands: self.latencies.len(),
            episodes,
        }
    }
}

/// A six-joint arm's vector (a deployable robot's controller has six joints, checked when it
/// was taken on); anything else as zeros would be wrong, so it is a bug.
pub fn six(v: Vec<f64>) -> [f64; 6] {
    v.try_into().expect("a deployed arm has six joints")
}

/// The median, 99th percentile and largest of `values` (0 for none).
pub fn percentiles(values: &[f64]) -> (f64, f64, f64) {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let at = |p: f64| if sorted.is_empty() { 0.0 } else { sorted[((sorted.len() - 1) as f64 * p).round() as usize] };
    (at(0.5), at(0.99), sorted.last().copied().unwrap_or(0.0))
}
