//! `twinbots deploy <robot> --bundle DIR --rtde HOST[:PORT] [--dry-run]`: a deploy bundle's
//! policy on the robot, the twin as its shadow (docs/deploy.md).

use std::path::PathBuf;
use std::time::Duration;

use twinbots_ops::bundle::Bundle;
use twinbots_ops::deploy::arm::{Arm, RtdeArm, TwinArm};
use twinbots_ops::deploy::{DeployOptions, deploy};
use twinbots_ops::live::{RobotView, WatchedArm};
use twinbots_ops::ur_sim::UrSimOptions;
use twinbots_rtde::RtdeClient;
use twinbots_sysid::Rig;
use twinbots_task::calibration::Calibration;

use twinbots_run::live::LiveArgs;

/// The command's arguments.
#[derive(clap::Args)]
#[command(group = clap::ArgGroup::new("robot_link").required(true).multiple(true).args(["rtde", "dry_run"]))]
pub struct Args {
    /// The robot: ur5e, or a robot file (`*.toml`) of a six-joint arm behind a UR controller
    /// (the bundle's robot file, as this command finds it).
    pub robot: String,
    /// The bundle of `twinbots export <run> --bundle DIR`.
    #[arg(long)]
    pub bundle: PathBuf,
    /// The robot's controller: RTDE at HOST[:PORT] (port 30004 by default).
    #[arg(long)]
    pub rtde: Option<String>,
    /// Drive only the twin (the bundle's calibration), started where the robot stands (read
    /// through --rtde, if given; else at home). The robot is never commanded.
    #[arg(long)]
    pub dry_run: bool,
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Seeds the targets.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The longest from a state's arrival to its command (ms): later, the robot is stopped.
    #[arg(long, default_value_t = 20.0)]
    pub deadline_ms: f64,
    /// The longest to wait for the controller (ms).
    #[arg(long, default_value_t = 1000.0)]
    pub patience_ms: f64,
    /// Write the report (every episode's figures, the latencies) as JSON here.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Run the control loop on SCHED_FIFO at this priority (1-99; root or CAP_SYS_NICE), as
    /// ur_rtde's rt_priority: the scheduler never holds a command back behind other work.
    #[arg(long)]
    pub rt_priority: Option<i32>,
    // The live view: the robot as a ghost at its reported joints (`robot/…`), its joint
    // states, and each episode as it ends.
    #[command(flatten)]
    pub live: LiveArgs,
}

/// `twinbots deploy`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    anyhow::ensure!(args.episodes > 0, "--episodes must be at least 1");
    anyhow::ensure!(
        args.deadline_ms > 0.0 && args.patience_ms > 0.0,
        "--deadline-ms and --patience-ms must be positive"
    );
    let bundle = Bundle::read_for(&args.bundle, &args.robot)?;
    let served = bundle.robot.served_arm()?;
    if let Some(p) = args.rt_priority {
        twinbots_ops::realtime::set_rt_priority(p)?;
    }
    let patience = Duration::from_secs_f64(args.patience_ms / 1e3);
    let options = DeployOptions {
        episodes: args.episodes,
        seed: args.seed,
        deadline: Duration::from_secs_f64(args.deadline_ms / 1e3),
        ..Default::default()
    };
    let mut arm: Box<dyn Arm> = if args.dry_run {
        let start = args.rtde.as_deref().map(|address| robot_joints(address, patience)).transpose()?;
        let rig = Rig::of(&served.robot)?;
        let truth = match &bundle.manifest.calibration {
            Some(file) => Calibration::read(&bundle.dir.join(file), &rig.catalogue, rig.robot)?.parameters,
            None => Default::default(),
        };
        Box::new(TwinArm::new(&UrSimOptions { arm: served.clone(), truth, ..Default::default() }, start)?)
    } else {
        Box::new(RtdeArm::connect(args.rtde.as_deref().expect("clap requires --rtde without --dry-run"), patience)?)
    };
    // `/episodes` is every live server's from its start; the robot's channels come with its view.
    let live =
        args.live.start_with(|server| Ok((server.clone(), RobotView::new(server, &served.robot, &served.joints)?)))?;
    let (live, view) = live.unzip();
    if let Some(view) = view {
        // A dry run's twin in real time, as the robot would move: it is there to be watched.
        let watched = WatchedArm::new(arm, view);
        arm = Box::new(if args.dry_run { watched.real_time() } else { watched });
    }
    println!(
        "deploying {} ({} steps of training) on {}: {} episodes",
        bundle.dir.display(),
        bundle.manifest.timesteps,
        arm.describe(),
        args.episodes
    );
    // Ctrl-C and SIGTERM end the deployment at the next report, the robot told to stop first.
    twinbots_ops::stop_signal::install();
    let mut successes = 0;
    let report = deploy(arm.as_mut(), &bundle, &options, |e| {
        successes += usize::from(e.success);
        if let (Some(server), Ok(value)) = (&live, serde_json::to_value(e)) {
            server.publish_json("/episodes", twinbots_live::EPISODE, &value);
        }
        let outcome =
            e.cycle_time_s.map_or(format!("missed after {} steps", e.steps), |t| format!("arrived in {t:.2} s"));
        println!(
            "episode {:3}: {outcome}, error {:.1} mm, energy {:.1} J{} (success {successes}/{})",
            e.episode + 1,
            e.final_error_mm,
            e.energy_j,
            if e.clipped + e.refused > 0 {
                format!(", shadow clipped {} refused {}", e.clipped, e.refused)
            } else {
                String::new()
            },
            e.episode + 1
        );
    })?;
    println!(
        "{}: success {:.1} % of {}, mean cycle time {}, mean energy {:.1} J; state to command p50 {:.0} µs, p99 {:.0} µs, max {:.0} µs over {} commands; shadow clipped {}, refused {}",
        report.arm,
        100.0 * report.success_rate,
        report.episodes.len(),
        report.mean_cycle_time_s.map_or("-".into(), |t| format!("{t:.2} s")),
        report.mean_energy_j,
        report.latency_p50_us,
        report.latency_p99_us,
        report.latency_max_us,
        report.commands,
        report.clipped,
        report.refused
    );
    if let Some(out) = &args.out {
        twinbots_api::files::write_json(out, &report)?;
        println!("wrote {}", out.display());
    }
    Ok(())
}

/// Where the robot's joints stand: one report of an outputs-only RTDE connection.
fn robot_joints(address: &str, patience: Duration) -> anyhow::Result<[f64; 6]> {
    let mut client = RtdeClient::connect(address, patience)?;
    client.setup_outputs(&["actual_q"], 10.0)?;
    client.start()?;
    let p = client.receive()?;
    let q = p.vector6("actual_q").ok_or_else(|| anyhow::anyhow!("the robot reported no six joint angles"))?;
    anyhow::ensure!(q.iter().all(|v| v.is_finite()), "the robot reported joint angles {q:?}");
    Ok(q)
}
