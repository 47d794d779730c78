//! `twinbots identify <robot> LOG... --out DIR`: calibrates the twin to robot logs. Replays the
//! logs with candidate parameters in parallel arenas (one candidate per arena), minimising the
//! tracking error with CMA-ES; reports each value with its spread and whether the logs pin it
//! down, the error before and after on held-out logs, a convergence plot, and writes
//! `DIR/calibration.toml`. `--list-params` prints the parameters: name, default, unit.

use anyhow::Context;
use std::path::{Path, PathBuf};

use twinbots_log::rtde_csv::Efforts;
use twinbots_sim::urdf::dynamics::Dynamics;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_sysid::effort_model::{ArmCalibration, EffortModel, Shadow, read_motions, rmse};
use twinbots_sysid::identify::{Fit, FitOptions};
use twinbots_sysid::report::{calibration_of, validate};
use twinbots_sysid::{PreparedLog, Rig, identify, prepare};

use twinbots_api::files::write_json;
use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them), or a robot file (`*.toml`: its effort model is
    /// fitted to the logs' efforts, docs/logs.md; with --twin, its twin's physics).
    pub robot: String,
    /// With a robot file: fit its twin's physics on its test stand (damping, friction,
    /// armature, the command delay) to the logs, as for a built-in robot, instead of its effort
    /// model.
    #[arg(long)]
    pub twin: bool,
    /// Logs to fit (`.mcap` or `.csv`).
    pub logs: Vec<PathBuf>,
    /// Print every parameter the robot's twin has, one per line: name, default value, unit.
    #[arg(long)]
    pub list_params: bool,
    /// The parameters to fit: names separated by commas, or a file with one name per line;
    /// default: the robot's own choice (the UR5e's 6 joints × damping, friction, armature and
    /// the command delay).
    #[arg(long)]
    pub params: Option<String>,
    /// Held-out logs: the joint-position error before and after, on motion not fitted.
    #[arg(long, num_args = 1..)]
    pub validate: Vec<PathBuf>,
    /// Start from (and keep the unfitted values of) this calibration.
    #[arg(long)]
    pub calibration: Option<PathBuf>,
    /// Where to write calibration.toml, fit.json, convergence.png and validation.png.
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Where a UR recording's efforts come from (docs/logs.md): `none`, `target_moment` (the
    /// controller's model torque) or `current:K0,…,K5` (actual currents × torque constants).
    #[arg(long, default_value = "none", value_parser = twinbots_log::rtde_csv::Efforts::parse)]
    pub efforts: twinbots_log::rtde_csv::Efforts,
    /// A robot file's shadow: its thresholds are this many times what the residuals reached on
    /// the (undisturbed) fitted logs.
    #[arg(long, default_value_t = 1.5)]
    pub margin: f64,
    /// CMA-ES generations of the joints' search (the delay's take a third to a half of it).
    #[arg(long, default_value_t = 16)]
    pub generations: usize,
    /// Candidates per generation of the joints' search (0: CMA-ES's default, 4 + ⌊3 ln n⌋ for
    /// n parameters: 12 for the UR5e's 18).
    #[arg(long, default_value_t = 0)]
    pub popsize: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

/// `twinbots identify`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if RobotFile::is_path(&args.robot) && !args.twin {
        return exec_arm(args);
    }
    let rig = Rig::of(&registry::find(&args.robot)?)?;
    if args.list_params {
        for p in &rig.catalogue {
            println!("{} {} {}", p.name, p.default, p.unit);
        }
        return Ok(());
    }
    anyhow::ensure!(!args.logs.is_empty(), "no logs to fit: give one or more LOG files (or --list-params)");
    let Some(out) = args.out.clone() else { anyhow::bail!("--out DIR is required: where calibration.toml goes") };
    anyhow::ensure!((1..=10_000).contains(&args.generations), "--generations must be from 1 to 10000");
    anyhow::ensure!(args.popsize <= 1000, "--popsize must be at most 1000 (0: CMA-ES's own)");
    // Everything is read and checked before anything is written.
    let base = rig.read_calibration(args.calibration.as_deref())?;
    let params = parameter_names(&rig, args.params.as_deref())?;
    let logs = prepare_all(&rig, &args.logs, &args.efforts)?;
    let validation = prepare_all(&rig, &args.validate, &args.efforts)?;
    let options = FitOptions { params, popsize: args.popsize, generations: args.generations, seed: args.seed };
    // Where the files go is made before the fit, so an unwritable --out fails at once.
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    println!(
        "{}: fitting {} parameters to {} log(s), {:.1} s in all",
        rig.robot,
        options.params.len(),
        logs.len(),
        seconds(&rig, &logs)
    );
    let fit = identify(&rig, &logs, &base, &options, |g| {
        println!(
            "generation {:>3}: best {:.4}  mean {:.4}  best so far {:.4}",
            g.generation + 1,
            g.best,
            g.mean,
            g.best_so_far
        );
    })?;
    if let Some(why) = &fit.no_better {
        print!("{}", fit_table(&fit));
        anyhow::bail!("{why}: nothing written (more --generations, other --params or longer logs may do better)");
    }
    let mut calibration = calibration_of(&fit, &base);
    let nominal = rig.parameters(&base)?;
    let calibrated = rig.parameters(&calibration.parameters)?;
    let validation_report = validate(&rig, &validation, &nominal, &calibrated, &out.join("validation.png"))?;
    print!("{}", fit_table(&fit));
    write_json(&out.join("fit.json"), &serde_json::json!({ "fit": fit, "validation": validation_report }))?;
    if let Some(v) = &validation_report {
        println!(
            "held-out position RMSE: nominal {:.6}, calibrated {:.6} ({:+.1} %)",
            v.nominal,
            v.calibrated,
            v.change * 100.0
        );
        anyhow::ensure!(
            v.calibrated <= v.nominal,
            "the fit tracks the held-out logs worse than the twin as it runs (position RMSE {:.6} against {:.6}, {:+.1} %): calibration.toml not written (fit.json and validation.png say how it went)",
            v.calibrated,
            v.nominal,
            v.change * 100.0
        );
        v.note(&mut calibration);
    }
    calibration.write(&out.join("calibration.toml"), &rig.catalogue)?;
    twinbots_sysid::plot::convergence_png(
        &out.join("convergence.png"),
        &format!("{}: calibration", rig.robot),
        &fit.history,
        fit.cost_nominal,
    )?;
    println!(
        "{} candidates ({} replays) in {:.1} s, {:.3} s per replay; wrote {}/calibration.toml",
        fit.candidates,
        fit.replays,
        fit.seconds,
        fit.seconds_per_replay,
        out.display()
    );
    Ok(())
}

/// `identify ROBOT.toml`: the arm's effort model by least squares on the logs' efforts (the
/// fitted logs undisturbed: the shadow's thresholds are learned from them), judged against the
/// vendor's description on them and on the held-out logs; nothing is written if it is worse.
fn exec_arm(args: Args) -> anyhow::Result<()> {
    let robot = RobotFile::read(Path::new(&args.robot))?;
    let dynamics = Dynamics::of(&robot.chain);
    anyhow::ensure!(!args.logs.is_empty(), "no logs to fit: give one or more LOG files");
    let Some(out) = args.out.clone() else { anyhow::bail!("--out DIR is required: where calibration.toml goes") };
    anyhow::ensure!(
        args.efforts != Efforts::None,
        "--efforts: a robot file's calibration fits efforts (current:K0,…,K5 or target_moment)"
    );
    anyhow::ensure!(args.margin.is_finite() && args.margin >= 1.0, "--margin must be at least 1");
    let started = std::time::Instant::now();
    let fitting = read_motions(&robot, &args.logs, &args.efforts)?;
    let held_out = read_motions(&robot, &args.validate, &args.efforts)?;
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let samples: usize = fitting.iter().map(|m| m.time.len()).sum();
    println!("{}: fitting the effort model to {} log(s), {samples} samples", robot.name, fitting.len());
    let model = EffortModel::fit(&dynamics, &fitting)?;
    let nominal = EffortModel::nominal(&dynamics);
    let mut rows = Vec::new();
    let mut worse = Vec::new();
    println!("effort RMSE (N*m), nominal -> calibrated, per joint:");
    // The log the plot shows: the first held out, else the first fitted.
    let shown = held_out.first().unwrap_or(&fitting[0]);
    let mut shown_efforts = None;
    for (held, motion) in fitting.iter().map(|m| (false, m)).chain(held_out.iter().map(|m| (true, m))) {
        let (nominal_efforts, model_efforts) = (nominal.efforts(&dynamics, motion), model.efforts(&dynamics, motion));
        let before = rmse(&motion.effort, &nominal_efforts);
        let after = rmse(&motion.effort, &model_efforts);
        if std::ptr::eq(motion, shown) {
            shown_efforts = Some((nominal_efforts, model_efforts));
        }
        let cells: Vec<String> = before
            .iter()
            .zip(&after)
            .map(|(b, a)| format!("{b:.2}->{a:.2} ({:+.0} %)", (a / b - 1.0) * 100.0))
            .collect();
        println!("  {} {}: {}", if held { "held out" } else { "fitted  " }, motion.name, cells.join("  "));
        if after.iter().sum::<f64>() > before.iter().sum::<f64>() {
            worse.push(motion.name.clone());
        }
        rows.push(serde_json::json!({ "log": motion.name, "held_out": held, "rmse_nominal": before, "rmse_calibrated": after }));
    }
    write_json(
        &out.join("fit.json"),
        &serde_json::json!({ "robot": robot.name, "joints": joint_names(&robot), "samples": samples, "logs": rows, "model": model }),
    )?;
    anyhow::ensure!(
        worse.is_empty(),
        "the fit predicts the efforts of {} worse than the robot's description: calibration.toml not written (fit.json says how it went)",
        worse.join(", ")
    );
    let shadow = Shadow::learn(&model, &dynamics, &fitting, args.margin);
    let (shown_nominal, shown_model) = shown_efforts.expect("the shown log is among those compared");
    let time: Vec<f64> = shown.time.iter().map(|t| t - shown.time[0]).collect();
    twinbots_sysid::plot::efforts_png(
        &out.join("efforts.png"),
        &format!(
            "{}: efforts, {} ({})",
            robot.name,
            shown.name,
            if held_out.is_empty() { "fitted" } else { "held out" }
        ),
        &joint_names(&robot),
        &time,
        &[("measured", &shown.effort), ("twin (nominal)", &shown_nominal), ("twin (calibrated)", &shown_model)],
    )?;
    let calibration = ArmCalibration {
        robot: robot.name.clone(),
        efforts: args.efforts.to_string(),
        logs: fitting.iter().map(|m| m.name.clone()).collect(),
        model,
        shadow,
    };
    calibration.write(&out.join("calibration.toml"))?;
    println!(
        "{:.1} s; wrote {}/calibration.toml, fit.json and efforts.png",
        started.elapsed().as_secs_f64(),
        out.display()
    );
    Ok(())
}

fn joint_names(robot: &RobotFile) -> Vec<String> {
    robot.chain.movable().map(|j| j.name.clone()).collect()
}

fn seconds(rig: &Rig, logs: &[PreparedLog]) -> f64 {
    logs.iter().map(|l| l.reference.len() as f64 * rig.dt()).sum()
}

/// `--params`: a file of names (one per line, `#` comments) or a comma-separated list.
fn parameter_names(rig: &Rig, arg: Option<&str>) -> anyhow::Result<Vec<String>> {
    let names: Vec<String> = match arg {
        None => rig.description.fit.iter().map(|s| s.to_string()).collect(),
        Some(a) if Path::new(a).is_file() => std::fs::read_to_string(a)?
            .lines()
            .map(|l| l.split('#').next().unwrap_or("").trim().to_string())
            .filter(|l| !l.is_empty())
            .collect(),
        Some(a) => a.split(',').map(|s| s.trim().to_string()).filter(|s| !s.is_empty()).collect(),
    };
    twinbots_sysid::identify::parameter_specs(rig, &names)?;
    Ok(names)
}

fn prepare_all(rig: &Rig, paths: &[PathBuf], efforts: &Efforts) -> anyhow::Result<Vec<PreparedLog>> {
    paths
        .iter()
        .map(|path| {
            let mapping = twinbots_log::Mapping { efforts: efforts.clone(), controller_joints: rig.joints.clone() };
            let log = twinbots_log::read_mapped(path, &mapping)?;
            let name = path.display().to_string();
            prepare(rig, &log, &name).map_err(|e| anyhow::anyhow!("{name}: {e:#}"))
        })
        .collect()
}

fn fit_table(fit: &Fit) -> String {
    let mut out = format!(
        "tracking error (χ² per step): nominal {:.4}, calibrated {:.4}; the replay's numerical noise ±{:.0} in χ² over {} samples\n{:<32} {:>12} {:>12} {:>12}  {}\n",
        fit.cost_nominal,
        fit.cost_fitted,
        fit.replay_noise,
        fit.samples,
        "parameter",
        "nominal",
        "fitted",
        "spread",
        "unit"
    );
    for p in &fit.parameters {
        out += &format!("{:<32} {:>12.5e} {:>12.5e} {:>12.2e}  {}\n", p.name, p.nominal, p.value, p.spread, p.unit);
        if let Some(why) = &p.not_identifiable {
            out += &format!("{:<32} not identifiable: {why}\n", "");
        }
    }
    out
}
