//! `twinbots bench rtde`: the link's own cost at the controller's full rate. A UR stand-in runs
//! in this process (its 500 Hz loop on its own thread, serving RTDE on loopback); the client
//! answers every report — observation, policy, shadow, command — and measures the time from the
//! report's arrival to its command's departure, with every cycle the link missed.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use twinbots_rtde::server::RtdeServer;

use super::arm::{Arm, RtdeArm};
use super::{controller_of, shadow_of};
use crate::bundle::Bundle;
use crate::ur_sim::{CYCLE, UrSim, UrSimOptions, controller_info};

/// A UR controller stops the arm when no command came for this long (ms).
pub const STOP_GAP_MS: f64 = 20.0;

#[derive(Clone, Debug, Serialize)]
pub struct LatencyReport {
    pub seconds: f64,
    pub commands: usize,
    /// Report in → command out (µs).
    pub p50_us: f64,
    pub p99_us: f64,
    pub p999_us: f64,
    pub max_us: f64,
    /// The longest between two commands sent (ms, wall clock): a UR controller stops the arm
    /// when none came for [`STOP_GAP_MS`] (ur_rtde's and ur_robot_driver's receive timeout).
    pub longest_gap_ms: f64,
    /// Gaps between commands of [`STOP_GAP_MS`] or more.
    pub stopping_gaps: usize,
    /// Commands later than one controller cycle (2 ms) after their report.
    pub late_commands: usize,
    /// Reports the client never saw (gaps in the controller's timestamps).
    pub missed_reports: u64,
    /// Cycles the stand-in's own loop started late.
    pub standin_missed_cycles: u64,
}

/// Measures for `seconds` of controller time; `progress` sees the report so far every 10 s.
/// With `rt_priority` N the client runs on SCHED_FIFO at N and the stand-in's loop at N − 1:
/// on two shared cores the link comes first, as on a controller PC beside a real controller.
pub fn measure(
    bundle: &Bundle,
    seconds: f64,
    rt_priority: Option<i32>,
    mut progress: impl FnMut(&LatencyReport),
) -> anyhow::Result<LatencyReport> {
    if let Some(p) = rt_priority {
        anyhow::ensure!(
            (2..=99).contains(&p),
            "--rt-priority must be 2 to 99 for bench rtde (the stand-in runs at one less), not {p}"
        );
    }
    let server = RtdeServer::bind("127.0.0.1:0", controller_info())?;
    let address = server.local_addr().to_string();
    let stop = Arc::new(AtomicBool::new(false));
    let flag = stop.clone();
    // The twin's app stays on the thread that steps it.
    let standin = std::thread::spawn(move || -> anyhow::Result<u64> {
        if let Some(p) = rt_priority {
            crate::realtime::set_rt_priority(p - 1)?;
        }
        let mut sim = UrSim::new(&UrSimOptions { watchdog: 0.1, ..Default::default() })?;
        Ok(sim.serve(&server, None, &flag, f64::INFINITY))
    });
    let result = (|| {
        if let Some(p) = rt_priority {
            crate::realtime::set_rt_priority(p)?;
        }
        let mut arm = RtdeArm::connect(&address, Duration::from_secs(1))?;
        let shadow = shadow_of(bundle);
        let mut controller = controller_of(bundle);
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        controller.new_reach(&mut rng);
        let mut latencies = Vec::new();
        let mut gaps: Vec<f64> = Vec::new();
        let mut last_sent: Option<std::time::Instant> = None;
        let (mut missed, mut last, mut previous_time) = (0u64, [0.0; 6], None::<f64>);
        let mut start = None;
        let mut next_progress = 10.0;
        loop {
            let m = arm.read()?;
            let t0 = *start.get_or_insert(m.time);
            if let Some(p) = previous_time {
                missed += (((m.time - p) / CYCLE).round() as u64).saturating_sub(1);
            }
            previous_time = Some(m.time);
            controller.read(&m.q, &m.qd);
            if controller.arrived() {
                controller.new_reach(&mut rng);
            }
            let action = bundle.policy.act(controller.observation())?;
            let wanted = super::six(controller.act(&action));
            let verdict = shadow.check(&m.q, &wanted, &last, CYCLE);
            if verdict.refused {
                arm.stop()?
            } else {
                arm.command(&verdict.command)?
            };
            last = if verdict.refused { [0.0; 6] } else { verdict.command };
            latencies.push(m.received.elapsed().as_secs_f64() * 1e6);
            let sent = std::time::Instant::now();
            if let Some(before) = last_sent.replace(sent) {
                gaps.push((sent - before).as_secs_f64() * 1e3);
            }
            let elapsed = m.time - t0;
            if elapsed >= next_progress {
                next_progress += 10.0;
                progress(&summary(&latencies, &gaps, elapsed, missed, 0));
            }
            if elapsed >= seconds {
                arm.stop()?;
                return Ok(summary(&latencies, &gaps, elapsed, missed, 0));
            }
        }
    })();
    stop.store(true, Ordering::SeqCst);
    let standin_missed = standin.join().map_err(|_| anyhow::anyhow!("the stand-in's thread panicked"))??;
    result.map(|r: LatencyReport| LatencyReport { standin_missed_cycles: standin_missed, ..r })
}

fn summary(latencies: &[f64], gaps: &[f64], seconds: f64, missed: u64, standin: u64) -> LatencyReport {
    let (p50_us, p99_us, max_us) = super::percentiles(latencies);
    let mut sorted = latencies.to_vec();
    sorted.sort_by(f64::total_cmp);
    let p999_us = sorted.get(((sorted.len().max(1) - 1) as f64 * 0.999).round() as usize).copied().unwrap_or(0.0);
    LatencyReport {
        seconds,
        commands: latencies.len(),
        p50_us,
        p99_us,
        p999_us,
        max_us,
        longest_gap_ms: gaps.iter().copied().fold(0.0, f64::max),
        stopping_gaps: gaps.iter().filter(|&&g| g >= STOP_GAP_MS).count(),
        late_commands: latencies.iter().filter(|&&l| l > CYCLE * 1e6).count(),
        missed_reports: missed,
        standin_missed_cycles: standin,
    }
}
