//! `twinbots replay <robot> LOG`: the twin starts in the logged state, takes the logged commands
//! at the logged times, and is compared with the log per joint; writes a PNG of twin vs log and
//! the twin's trajectory as a log beside it. With a robot file (`*.toml`) as the robot: the
//! twin's efforts along the logged motion against the logged ones, and the shadow's flags where
//! they part (docs/logs.md).

use anyhow::Context;
use std::path::{Path, PathBuf};

use twinbots_sim::urdf::dynamics::Dynamics;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sysid::effort_model::{ArmCalibration, EffortModel, FlagReport, Motion, residuals, rmse};

use twinbots_sysid::Rig;
use twinbots_sysid::replay::{replay_stream, twin_meta};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them), or a robot file (`*.toml`).
    pub robot: String,
    /// With a robot file: replay the log's commands on its twin's test stand, as for a built-in
    /// robot, instead of judging its efforts by the effort model.
    #[arg(long)]
    pub twin: bool,
    /// The robot's log (`.mcap` or `.csv`, see docs/logs.md).
    pub log: PathBuf,
    /// Run the twin with this calibration (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Position error (rad or m) beyond which a joint counts as diverged.
    #[arg(long, default_value_t = 0.05)]
    pub threshold: f64,
    /// Where to write replay.png, twin.mcap and replay.json; default: `<log>.replay/` beside it.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// With a robot file: also run the arm's twin (the twin's physics: the URDF's meshes must be
    /// found) along the log's position targets (`target_q`) under a servo, `position` (the
    /// default) or `computed-torque`, and compare its joints and efforts with the measured ones.
    #[arg(long, num_args = 0..=1, default_missing_value = "position", value_parser = twinbots_arm::servo::Servo::parse)]
    pub servo: Option<twinbots_arm::servo::Servo>,
    /// Where a UR recording's efforts come from (docs/logs.md): `none`, `target_moment` (the
    /// controller's model torque) or `current:K0,…,K5` (actual currents × torque constants).
    #[arg(long, default_value = "none", value_parser = twinbots_log::rtde_csv::Efforts::parse)]
    pub efforts: twinbots_log::rtde_csv::Efforts,
}

/// `twinbots replay`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if RobotFile::is_path(&args.robot) && !args.twin {
        return exec_arm(args);
    }
    anyhow::ensure!(
        args.servo.is_none(),
        "--servo runs a robot file's arm under its position servo; '{}' replays its own way",
        args.robot
    );
    let rig = Rig::of(&registry::find(&args.robot)?)?;
    let calibration = rig.read_calibration(args.calibration.as_deref())?;
    anyhow::ensure!(args.threshold > 0.0, "--threshold must be positive");
    let mapping = twinbots_log::Mapping { efforts: args.efforts.clone(), controller_joints: rig.joints.clone() };
    // The log is read as the twin replays it: memory does not grow with its length.
    let mut log = twinbots_log::open(&args.log, &mapping)?;
    let params = rig.parameters(&calibration)?;
    let out = args.out.unwrap_or_else(|| PathBuf::from(format!("{}.replay", args.log.display())));
    let label = if args.calibration.is_some() { "twin (calibrated)" } else { "twin (nominal)" };
    let calibration_name = args.calibration.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
    let meta = twin_meta(&rig, &log.name, &calibration_name);
    // A log found damaged part-way leaves nothing behind: the twin's log is written under a
    // temporary name, and a folder made for it is removed again.
    let made = !out.exists();
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let mut replayed = || -> anyhow::Result<twinbots_sysid::ReplayReport> {
        let mut twin = twinbots_log::mcap_file::FileWriter::create(&out.join("twin.mcap"), &meta, &rig.joints)?;
        let (report, plot) = replay_stream(&rig, &params, &mut log, args.threshold, label, |sample| {
            twin.write(&twinbots_log::Entry::State(sample))
        })?;
        twinbots_sysid::plot::replay_png(&out.join("replay.png"), &rig, &plot)?;
        twin.finish()?;
        twinbots_api::files::write_json(&out.join("replay.json"), &report)?;
        Ok(report)
    };
    let report = replayed().inspect_err(|_| {
        if made {
            let _ = std::fs::remove_dir(&out);
        }
    })?;
    // The table once the files stand: a reader that leaves (`| head`) ends the command here.
    print!("{}", report.table());
    println!("wrote {}/replay.png, twin.mcap, replay.json", out.display());
    Ok(())
}

/// `replay ROBOT.toml LOG`: the efforts the twin predicts along the logged motion (the robot's
/// description as it stands, and calibrated with `--calibration`) against the logged ones, per
/// joint; with a calibration, the shadow's residuals, thresholds and flagged intervals.
fn exec_arm(args: Args) -> anyhow::Result<()> {
    let robot = RobotFile::read(Path::new(&args.robot))?;
    let dynamics = Dynamics::of(&robot.chain);
    let calibration = args.calibration.as_deref().map(|p| ArmCalibration::read(p, &robot, &dynamics)).transpose()?;
    if let (Some(c), Some(path)) = (&calibration, &args.calibration) {
        anyhow::ensure!(
            c.efforts == args.efforts.to_string(),
            "{}: fitted to efforts read as '{}', but --efforts is '{}': read the log as it was calibrated",
            path.display(),
            c.efforts,
            args.efforts
        );
    }
    let name = args.log.display().to_string();
    let mapping = twinbots_log::Mapping { efforts: args.efforts.clone(), controller_joints: robot.joints.clone() };
    let log = twinbots_log::read_mapped(&args.log, &mapping)?;
    let motion = Motion::of_log(&robot, &log, &name)?;
    let joints: Vec<String> = robot.chain.movable().map(|j| j.name.clone()).collect();
    let nominal = EffortModel::nominal(&dynamics).efforts(&dynamics, &motion);
    let calibrated = calibration.as_ref().map(|c| c.model.efforts(&dynamics, &motion));
    let rmse_nominal = rmse(&motion.effort, &nominal);
    let rmse_calibrated = calibrated.as_ref().map(|c| rmse(&motion.effort, c));
    println!("{name}: {:.1} s, effort RMSE per joint (N*m)", motion.time.last().unwrap_or(&0.0) - motion.time[0]);
    for (j, joint) in joints.iter().enumerate() {
        match &rmse_calibrated {
            Some(c) => println!(
                "  {joint:<24} nominal {:>8.3}  calibrated {:>8.3} ({:+.0} %)",
                rmse_nominal[j],
                c[j],
                (c[j] / rmse_nominal[j] - 1.0) * 100.0
            ),
            None => println!("  {joint:<24} nominal {:>8.3}", rmse_nominal[j]),
        }
    }
    let followed = args.servo.map(|servo| twinbots_arm::servo::follow_log(&robot, servo, &log, &name)).transpose()?;
    let servo = followed.as_ref().map(|f| rmse(&f.measured, &f.twin.positions));
    // From the first period on: the start has no period behind it.
    let servo_effort =
        followed.as_ref().and_then(|f| Some(rmse(&f.measured_efforts.as_ref()?[1..], &f.twin.efforts[1..])));
    if let Some(rmse) = &servo {
        let servo = args.servo.map_or("", |s| s.name());
        println!("{name}: the twin under its {servo} servo on the logged targets, RMSE per joint");
        for (j, joint) in robot.joints.iter().enumerate() {
            let effort = servo_effort.as_ref().map_or(String::new(), |e| format!("  effort {:>8.3} N*m", e[j]));
            println!("  {joint:<24} position {:>8.3} mrad{effort}", 1e3 * rmse[j]);
        }
    }
    let residual = residuals(&motion.effort, calibrated.as_ref().unwrap_or(&nominal));
    let (thresholds, flags) = match &calibration {
        Some(c) => (Some(c.shadow.thresholds(&motion)), c.shadow.flags(&motion, &residual)),
        None => {
            println!("no --calibration: no shadow thresholds, nothing flagged");
            (None, Vec::new())
        }
    };
    let flagged: Vec<FlagReport> = flags.iter().map(|f| FlagReport::of(f, &joints)).collect();
    for f in &flagged {
        println!("flagged {:.2}-{:.2} s: {} ({:.2} x the threshold)", f.start, f.end, f.joints.join(", "), f.peak);
    }
    if calibration.is_some() {
        println!("{} flagged interval(s)", flags.len());
    }
    let out = args.out.unwrap_or_else(|| PathBuf::from(format!("{}.replay", args.log.display())));
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let time: Vec<f64> = motion.time.iter().map(|t| t - motion.time[0]).collect();
    let spans: Vec<(f64, f64)> = flags.iter().map(|f| (f.start, f.end)).collect();
    twinbots_sysid::plot::shadow_png(
        &out.join("replay.png"),
        &format!("{}: the shadow on {name}", robot.name),
        &joints,
        &time,
        &residual,
        thresholds.as_deref(),
        &spans,
    )?;
    let mut lines: Vec<(&str, &[Vec<f64>])> = vec![("measured", &motion.effort), ("twin (nominal)", &nominal)];
    if let Some(c) = &calibrated {
        lines.push(("twin (calibrated)", c));
    }
    twinbots_sysid::plot::efforts_png(
        &out.join("efforts.png"),
        &format!("{}: efforts, {name}", robot.name),
        &joints,
        &time,
        &lines,
    )?;
    let report = serde_json::json!({
        "robot": robot.name,
        "log": name,
        "joints": joints,
        "rmse_nominal": rmse_nominal,
        "rmse_calibrated": rmse_calibrated,
        "servo": args.servo.map(|s| s.name()),
        "servo_position_rmse_rad": servo,
        "servo_effort_rmse": servo_effort,
        "flagged": flagged,
    });
    twinbots_api::files::write_json(&out.join("replay.json"), &report)?;
    println!("wrote {}/replay.png, efforts.png, replay.json", out.display());
    Ok(())
}
