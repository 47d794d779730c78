//! `twinbots monitor ur5e --rtde HOST[:PORT] [--calibration FILE] [--seconds S] --out DIR`: the
//! twin follows the robot live and says where they part (docs/monitor.md).

use std::path::PathBuf;
use std::time::Duration;

use twinbots::monitor::{Monitor, MonitorOptions, Report};
use twinbots_rtde::{DataPackage, RtdeClient};
use twinbots_sysid::Rig;
use twinbots_task::calibration::read_calibration;

use crate::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (only ur5e has a controller link).
    pub robot: String,
    /// The robot's controller: RTDE at HOST[:PORT] (port 30004 by default).
    #[arg(long)]
    pub rtde: String,
    /// Run the twin calibrated by this file (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Follow for this many seconds of controller time (default: until the controller goes).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// Position divergence (mrad, RMSE over the window) that raises the alarm.
    #[arg(long, default_value_t = 5.0)]
    pub position_threshold_mrad: f64,
    /// Effort divergence (N*m, RMSE over the window) that raises the alarm.
    #[arg(long, default_value_t = 1.5)]
    pub effort_threshold: f64,
    /// The rolling window (s).
    #[arg(long, default_value_t = 1.0)]
    pub window: f64,
    /// The longest to wait for the controller (ms).
    #[arg(long, default_value_t = 1000.0)]
    pub patience_ms: f64,
    /// Where to write robot.mcap, twin.mcap, monitor.json and divergence.png.
    #[arg(long)]
    pub out: PathBuf,
}

/// `twinbots monitor`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let entry = registry::find(&args.robot)?;
    anyhow::ensure!(args.robot == "ur5e", "robot '{}' has no controller link: only ur5e is monitored (RTDE)", args.robot);
    if let Some(s) = args.seconds {
        anyhow::ensure!(s > 0.0 && s.is_finite(), "--seconds must be positive, not {s}");
    }
    anyhow::ensure!(args.patience_ms > 0.0, "--patience-ms must be positive");
    let rig = Rig::of(&entry)?;
    let calibration = args.calibration.as_deref().map(|p| read_calibration(p, &rig.catalogue, rig.robot)).transpose()?.unwrap_or_default();
    std::fs::create_dir_all(&args.out).map_err(|e| anyhow::anyhow!("{}: {e}", args.out.display()))?;
    let options = MonitorOptions {
        calibration,
        position_threshold: args.position_threshold_mrad / 1e3,
        effort_threshold: args.effort_threshold,
        window: args.window,
    };
    let mut client = RtdeClient::connect(&args.rtde, Duration::from_secs_f64(args.patience_ms / 1e3))?;
    client.setup_outputs(&["timestamp", "actual_q", "actual_qd", "target_qd", "target_moment"], twinbots_rtde::MAX_FREQUENCY)?;
    client.start()?;
    let first = report(&client.receive()?)?;
    let mut monitor = Monitor::new(options, &first)?;
    println!("monitor: following {} from t = {:.3} s (the twin settles 0.5 s before it compares)", args.rtde, first.time);
    let mut next_line = first.time + 1.0;
    let ended = loop {
        let package = match client.receive() {
            Ok(p) => p,
            Err(e) => break Some(e),
        };
        let r = report(&package)?;
        for alarm in monitor.observe(&r) {
            println!("[{:9.3} s] ALARM {}: {}", alarm.time, alarm.kind, alarm.message);
        }
        if r.time >= next_line {
            next_line += 1.0;
            print_line(&monitor, r.time);
        }
        if args.seconds.is_some_and(|s| r.time - first.time >= s) {
            break None;
        }
    };
    if let Some(e) = &ended {
        println!("monitor: the controller went ({e}); writing what was followed");
    }
    let account = monitor.report();
    twinbots_log::write(&monitor.robot_log, &args.out.join("robot.mcap"))?;
    twinbots_log::write(&monitor.twin_log, &args.out.join("twin.mcap"))?;
    crate::cli::replay::write_json(&args.out.join("monitor.json"), account)?;
    let alarms: Vec<f64> = account.alarms.iter().map(|a| a.time).collect();
    twinbots_sysid::plot::divergence_png(&args.out.join("divergence.png"), "ur5e: robot vs twin, live", &monitor.robot_log, &monitor.twin_log, &alarms)?;
    println!(
        "monitor: {:.1} s, {} reports ({} skipped), {} alarm(s), {} motion(s); worst position RMSE {:.3} mrad, worst effort RMSE {:.3} N*m; wrote {}/robot.mcap, twin.mcap, monitor.json, divergence.png",
        account.seconds - first.time,
        account.reports,
        account.skipped,
        account.alarms.len(),
        account.motions.len(),
        1e3 * account.worst_rmse.iter().cloned().fold(0.0, f64::max),
        account.worst_effort_rmse.iter().cloned().fold(0.0, f64::max),
        args.out.display()
    );
    Ok(())
}

/// The running account: a line a second.
fn print_line(monitor: &Monitor, time: f64) {
    let (rmse, effort) = (monitor.rmse(), monitor.effort_rmse());
    let worst = (0..6).max_by(|&a, &b| effort[a].total_cmp(&effort[b])).unwrap_or(0);
    let account = monitor.report();
    let last = account.motions.last().map_or(String::new(), |m| format!(", last motion {:.2} s, {:.1} J", m.duration_s, m.energy_j));
    println!(
        "[{time:9.3} s] worst joint {}: position RMSE {:.3} mrad, effort RMSE {:.3} N*m; {} motion(s){last}; {} alarm(s)",
        ur5e::kinematics::JOINTS[worst],
        rmse[worst] * 1e3,
        effort[worst],
        account.motions.len(),
        account.alarms.len()
    );
}

fn report(p: &DataPackage) -> anyhow::Result<Report> {
    let six = |name: &str| -> anyhow::Result<[f64; 6]> {
        let v = p.vector6(name).ok_or_else(|| anyhow::anyhow!("the controller's report has no {name}"))?;
        anyhow::ensure!(v.iter().all(|x| x.is_finite()), "the controller reported {name} = {v:?}");
        Ok(v)
    };
    Ok(Report {
        time: p.double("timestamp").ok_or_else(|| anyhow::anyhow!("the controller's report has no timestamp"))?,
        q: six("actual_q")?,
        qd: six("actual_qd")?,
        command: six("target_qd")?,
        effort: six("target_moment")?,
    })
}
