//! `twinbots monitor ur5e|ROBOT.toml (--rtde HOST[:PORT] | --ros2) [--calibration FILE] [--cell FILE]
//! [--seconds S] [--frames-every S] --out DIR`: the twin follows the robot live and says where they part
//! (docs/monitor.md; a robot file's six-joint arm through RTDE or ROS 2). `twinbots monitor ROBOT.toml --replay LOG --calibration FILE --out DIR`: a
//! recording played back as the arm would stream it, its efforts judged by the calibrated shadow
//! as they arrive.

use std::path::{Path, PathBuf};
use std::time::Duration;

use twinbots_ops::linked_arm::LinkedArm;
use twinbots_ops::live::{ALARM, RobotJoints, RobotView};
use twinbots_ops::monitor::recording::{SHADOW, follow};
use twinbots_ops::monitor::source::Source;
use twinbots_ops::monitor::{Monitor, MonitorOptions};
use twinbots_render::{Renderer, View};
use twinbots_run::live::LiveArgs;
use twinbots_run::settings::CalibrationSetting;
use twinbots_sim::urdf::dynamics::Dynamics;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sysid::effort_model::{ArmCalibration, Motion};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
#[command(group = clap::ArgGroup::new("source").required(true).args(["rtde", "ros2", "replay"]))]
pub struct Args {
    /// The robot: ur5e, or a robot file (`*.toml`): a six-joint arm through RTDE or ROS 2 (its
    /// joint states found by the file's joint names), any arm with --replay.
    pub robot: String,
    /// The robot's controller: RTDE at HOST[:PORT] (port 30004 by default).
    #[arg(long)]
    pub rtde: Option<String>,
    /// The robot's ROS 2 driver instead: its /joint_states and the commands sent to its forward
    /// velocity controller, overheard on DDS (`--domain`, default ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    pub ros2: bool,
    /// The DDS domain (with --ros2).
    #[arg(long, requires = "ros2")]
    pub domain: Option<String>,
    /// A recording of the arm instead (a UR CSV or an MCAP log, docs/logs.md), played back as
    /// the arm would stream it and judged by the shadow of --calibration (`identify`'s).
    #[arg(long)]
    pub replay: Option<PathBuf>,
    /// With --replay: where the recording's efforts come from (`target_moment` or
    /// `current:K0,…,K5`), as it was calibrated.
    #[arg(long, default_value = "none", value_parser = twinbots_log::rtde_csv::Efforts::parse, requires = "replay")]
    pub efforts: twinbots_log::rtde_csv::Efforts,
    /// With --replay: how many times real time it plays (0: as fast as it goes).
    #[arg(long, default_value_t = 1.0, requires = "replay")]
    pub speed: f64,
    /// Run the twin calibrated by this file (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// The robot's cell (docs/cells.md): the predicted alarm also watches its obstacles.
    #[arg(long)]
    pub cell: Option<PathBuf>,
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
    /// Render the twin as it follows, a PNG frame every this many seconds of controller time,
    /// into DIR/frames/ (off-screen: needs a Vulkan adapter, lavapipe will do).
    #[arg(long)]
    pub frames_every: Option<f64>,
    /// The frames' size (WxH).
    #[arg(long, default_value = "640x480")]
    pub size: String,
    /// The frames' camera: side, front, iso or top.
    #[arg(long, default_value = "iso")]
    pub camera: String,
    /// Where to write robot.mcap, twin.mcap, monitor.json, divergence.png (and frames/).
    #[arg(long)]
    pub out: PathBuf,
    // The live view: the twin (`twin/…`), the robot as a ghost at its reported joints
    // (`robot/…`), both joint states, the residuals and the alarms.
    #[command(flatten)]
    pub live: LiveArgs,
}

/// The twin rendered as it follows.
struct TwinFrames {
    renderer: Renderer,
    dir: PathBuf,
    every: f64,
    next: f64,
    written: usize,
}

impl TwinFrames {
    /// The renderer, made before the robot is reached (no adapter: an error, nothing followed).
    fn new(args: &Args, entry: &registry::RobotEntry) -> anyhow::Result<Option<Self>> {
        let Some(every) = args.frames_every else { return Ok(None) };
        anyhow::ensure!(every > 0.0 && every.is_finite(), "--frames-every must be positive, not {every}");
        let (w, h) = twinbots_render::recorder::parse_size(&args.size)?;
        let view: View = twinbots_render::recorder::camera(&entry.framing, &args.camera)?;
        let mut renderer = Renderer::new(w, h)?;
        renderer.set_view(view);
        let dir = args.out.join("frames");
        std::fs::create_dir_all(&dir).map_err(|e| anyhow::anyhow!("{}: {e}", dir.display()))?;
        Ok(Some(Self { renderer, dir, every, next: f64::NEG_INFINITY, written: 0 }))
    }

    /// A frame when its time has come: `frame_<ms since the start>.png`.
    fn offer(&mut self, monitor: &mut Monitor, time: f64, start: f64) -> anyhow::Result<()> {
        if self.next == f64::NEG_INFINITY {
            self.next = start;
        }
        if time + 1e-9 < self.next {
            return Ok(());
        }
        while self.next <= time + 1e-9 {
            self.next += self.every;
        }
        let (world, arena) = monitor.twin_scene();
        self.renderer.sync(world, arena);
        let rgb = self.renderer.render()?;
        let path = self.dir.join(format!("frame_{:07}.png", ((time - start) * 1e3).round() as u64));
        let (w, h) = (self.renderer.width, self.renderer.height);
        image::save_buffer(&path, &rgb, w, h, image::ExtendedColorType::Rgb8)
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        self.written += 1;
        Ok(())
    }
}

/// `twinbots monitor`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(log) = &args.replay {
        return exec_replay(&args, log);
    }
    let arm = LinkedArm::of(&args.robot)?;
    let is_ur5e = matches!(arm, LinkedArm::Ur5e);
    anyhow::ensure!(
        is_ur5e || args.cell.is_none(),
        "--cell lays out the UR5e's cell; a robot file's arm stands in an empty one"
    );
    let served = arm.served_arm()?;
    // The robot as `registry::find` would describe it, made once with the arm.
    let entry = &served.robot;
    if let Some(s) = args.seconds {
        anyhow::ensure!(s > 0.0 && s.is_finite(), "--seconds must be positive, not {s}");
    }
    anyhow::ensure!(args.patience_ms > 0.0, "--patience-ms must be positive");
    let calibration = CalibrationSetting::read_optional(entry, args.calibration.as_deref())?
        .map(|c| c.parameters())
        .unwrap_or_default();
    std::fs::create_dir_all(&args.out).map_err(|e| anyhow::anyhow!("{}: {e}", args.out.display()))?;
    let label = Source::label(args.rtde.as_deref());
    let options = MonitorOptions {
        calibration,
        position_threshold: args.position_threshold_mrad / 1e3,
        effort_threshold: args.effort_threshold,
        window: args.window,
        source: format!("robot ({label})"),
        shadow: match &args.cell {
            Some(path) => {
                let layout = ur5e::layout::CellLayout::read(path).map_err(anyhow::Error::msg)?;
                twinbots_task::shadow::Shadow { keepouts: ur5e::deploy::keepouts(&layout), ..ur5e::deploy::shadow() }
            }
            None => arm.shadow(&Default::default()),
        },
        arm: served.clone(),
    };
    let mut frames = TwinFrames::new(&args, entry)?;
    let mut view = args.live.start_with(|server| {
        let view = RobotView::new(server, entry, &served.joints)?;
        Monitor::advertise_live(&view)?;
        Ok(view)
    })?;
    let patience = Duration::from_secs_f64(args.patience_ms / 1e3);
    let mut source = Source::open(args.rtde.as_deref(), args.domain.as_deref(), &served.joints, patience)?;
    let first = source.receive()?.map_err(|e| anyhow::anyhow!("the robot never reported ({label}): {e}"))?;
    let mut monitor = Monitor::new(options, &first)?;
    if let Some(f) = frames.as_mut() {
        f.offer(&mut monitor, first.time, first.time)?;
    }
    println!("monitor: following {label} from t = {:.3} s (the twin settles 0.5 s before it compares)", first.time);
    let mut next_line = first.time + 1.0;
    // Every way the run ends writes what was followed: the controller going, Ctrl-C or
    // SIGTERM, --seconds, and a report that cannot be followed (then the error, after writing).
    twinbots_ops::stop_signal::install();
    let mut failure: Option<anyhow::Error> = None;
    let mut last_time = first.time;
    let ended = loop {
        if let Some(signal) = twinbots_ops::stop_signal::requested() {
            break Some(format!("stopped by {signal}"));
        }
        let r = match source.receive() {
            Ok(Ok(r)) => r,
            Ok(Err(e)) => break Some(e),
            Err(e) => {
                let text = format!("{e:#}");
                failure = Some(e);
                break Some(text);
            }
        };
        if !(r.time > last_time) {
            let e = anyhow::anyhow!(
                "the controller's clock read {} s after {last_time} s: it stood still, ran back or is not a number",
                r.time
            );
            let text = e.to_string();
            failure = Some(e);
            break Some(text);
        }
        last_time = r.time;
        let alarms = monitor.observe(&r);
        for alarm in &alarms {
            println!("[{:9.3} s] ALARM {}: {}", alarm.time, alarm.kind, alarm.message);
        }
        if let Some(view) = view.as_mut() {
            monitor.publish_live(view, &r, &alarms);
        }
        if let Some(f) = frames.as_mut() {
            f.offer(&mut monitor, r.time, first.time)?;
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
        println!("monitor: ended ({e}); writing what was followed");
    }
    let account = monitor.report();
    twinbots_log::write(&monitor.robot_log, &args.out.join("robot.mcap"))?;
    twinbots_log::write(&monitor.twin_log, &args.out.join("twin.mcap"))?;
    twinbots_api::files::write_json(&args.out.join("monitor.json"), account)?;
    let alarms: Vec<f64> = account.alarms.iter().map(|a| a.time).collect();
    twinbots_sysid::plot::divergence_png(
        &args.out.join("divergence.png"),
        &format!("{}: robot vs twin, live", served.robot.name),
        &monitor.robot_log,
        &monitor.twin_log,
        &alarms,
    )?;
    let frames_line = frames.map_or(String::new(), |f| format!(", {} frame(s) in frames/", f.written));
    println!(
        "monitor: {:.1} s, {} reports ({} skipped), {} alarm(s), {} motion(s); worst position RMSE {:.3} mrad, worst effort RMSE {:.3} N*m; wrote {}/robot.mcap, twin.mcap, monitor.json, divergence.png{frames_line}",
        account.seconds - first.time,
        account.reports,
        account.skipped,
        account.alarms.len(),
        account.motions.len(),
        1e3 * account.worst_rmse.iter().cloned().fold(0.0, f64::max),
        account.worst_effort_rmse.iter().cloned().fold(0.0, f64::max),
        args.out.display()
    );
    match failure {
        Some(e) => Err(e.context(format!("what was followed is written to {}", args.out.display()))),
        None => Ok(()),
    }
}

/// The running account: a line a second.
fn print_line(monitor: &Monitor, time: f64) {
    let (rmse, effort) = (monitor.rmse(), monitor.effort_rmse());
    let worst = (0..6).max_by(|&a, &b| effort[a].total_cmp(&effort[b])).unwrap_or(0);
    let account = monitor.report();
    let last = account
        .motions
        .last()
        .map_or(String::new(), |m| format!(", last motion {:.2} s, {:.1} J", m.duration_s, m.energy_j));
    println!(
        "[{time:9.3} s] worst joint {}: position RMSE {:.3} mrad, effort RMSE {:.3} N*m; {} motion(s){last}; {} alarm(s)",
        monitor.joints()[worst],
        rmse[worst] * 1e3,
        effort[worst],
        account.motions.len(),
        account.alarms.len()
    );
}

/// `monitor ROBOT.toml --replay LOG`: the recording through the calibrated shadow, sample by
/// sample at `--speed`; alarms as flags begin; `monitor.json` (the flags, as `replay.json`'s) and
/// `shadow.png` (residuals, thresholds, flags) in `--out`.
fn exec_replay(args: &Args, log: &Path) -> anyhow::Result<()> {
    anyhow::ensure!(
        RobotFile::is_path(&args.robot),
        "monitor --replay judges a recording by the effort shadow of a robot file's arm (`identify` calibrates it): '{}' is no robot file (*.toml)",
        args.robot
    );
    let robot = RobotFile::read(Path::new(&args.robot))?;
    let dynamics = Dynamics::of(&robot.chain);
    let path = args.calibration.as_deref().ok_or_else(|| {
        anyhow::anyhow!("monitor --replay needs --calibration (`identify`'s calibration.toml): the shadow's thresholds are learnt there")
    })?;
    let calibration = ArmCalibration::read(path, &robot, &dynamics)?;
    anyhow::ensure!(
        calibration.efforts == args.efforts.to_string(),
        "{}: fitted to efforts read as '{}', but --efforts is '{}': read the recording as it was calibrated",
        path.display(),
        calibration.efforts,
        args.efforts
    );
    let name = log.display().to_string();
    let mapping = twinbots_log::Mapping { efforts: args.efforts.clone(), controller_joints: robot.joints.clone() };
    let motion = Motion::of_log(&robot, &twinbots_log::read_mapped(log, &mapping)?, &name)?;
    let joints: Vec<String> = robot.chain.movable().map(|j| j.name.clone()).collect();
    std::fs::create_dir_all(&args.out).map_err(|e| anyhow::anyhow!("{}: {e}", args.out.display()))?;
    let mut view = args.live.start_with(|server| {
        server.advertise("/alarms", ALARM)?;
        server.advertise("/shadow", SHADOW)?;
        RobotView::new(server, &registry::find(&args.robot)?, &joints)
    })?;
    twinbots_ops::stop_signal::install();
    println!(
        "monitor: following {name} ({:.1} s) through the shadow of {}",
        motion.time.last().unwrap_or(&0.0) - motion.time[0],
        path.display()
    );
    let (report, trace) = follow(
        &robot.name,
        &joints,
        &dynamics,
        &calibration,
        &motion,
        args.speed,
        |sample, judged| {
            let began = judged.and_then(|j| j.began.as_ref().map(|f| (j, f)));
            if let Some((j, flag)) = began {
                let which: Vec<&str> = flag.joints.iter().map(|&k| joints[k].as_str()).collect();
                let message = format!(
                    "{}: the effort parts from the twin's by {:.2} x its threshold (a push or a collision?)",
                    which.join(", "),
                    flag.peak
                );
                println!("[{:9.3} s] ALARM effort: {message}", j.time);
                if let Some(view) = &view {
                    view.server().publish_json(
                        "/alarms",
                        ALARM,
                        &serde_json::json!({"time": j.time, "kind": "effort", "message": message}),
                    );
                }
            }
            if let Some(view) = view.as_mut() {
                let robot = RobotJoints { time: sample.time, q: &sample.q, qd: &sample.qd, effort: &sample.effort };
                view.publish(robot, |frame| {
                if let Some(j) = judged {
                    let value = serde_json::json!({"time": j.time, "name": joints, "residual": j.residual, "threshold": j.threshold});
                    frame.json("/shadow", SHADOW, &value);
                }
            });
            }
        },
    )?;
    twinbots_api::files::write_json(&args.out.join("monitor.json"), &report)?;
    let spans: Vec<(f64, f64)> = report.flagged.iter().map(|f| (f.start, f.end)).collect();
    twinbots_sysid::plot::shadow_png(
        &args.out.join("shadow.png"),
        &format!("{}: the shadow following {name}", robot.name),
        &joints,
        &trace.time,
        &trace.residual,
        Some(&trace.threshold),
        &spans,
    )?;
    if let Some(e) = &report.ended {
        println!("monitor: ended ({e}); writing what was followed");
    }
    println!(
        "monitor: {:.1} s, {} samples ({} judged), {} flagged interval(s); wrote {}/monitor.json, shadow.png",
        report.seconds,
        report.samples,
        report.judged,
        report.flagged.len(),
        args.out.display()
    );
    Ok(())
}
