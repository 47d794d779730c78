//! `twinbots identify <robot> LOG... --out DIR`: calibrates the twin to robot logs. Replays the
//! logs with candidate parameters in parallel arenas (one candidate per arena), minimising the
//! tracking error with CMA-ES; reports each value with its spread and whether the logs pin it
//! down, the error before and after on held-out logs, a convergence plot, and writes
//! `DIR/calibration.toml`. `--list-params` prints the parameters: name, default, unit.

use anyhow::Context;
use std::path::{Path, PathBuf};

use twinbots_sim::Parameters;
use twinbots_sysid::identify::{Fit, FitOptions, position_rmse};
use twinbots_sysid::{PreparedLog, Rig, identify, prepare, run};
use twinbots_task::calibration::calibration_text;

use twinbots_api::files::write_json;
use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them).
    pub robot: String,
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
    let rig = Rig::of(&registry::find(&args.robot)?)?;
    if args.list_params {
        for p in &rig.catalogue {
            println!("{} {} {}", p.name, p.default, p.unit);
        }
        return Ok(());
    }
    anyhow::ensure!(!args.logs.is_empty(), "no logs to fit: give one or more LOG files (or --list-params)");
    let Some(out) = args.out.clone() else { anyhow::bail!("--out DIR is required: where calibration.toml goes") };
    anyhow::ensure!(args.generations > 0, "--generations must be at least 1");
    // Everything is read and checked before anything is written.
    let base = rig.read_calibration(args.calibration.as_deref())?;
    let params = parameter_names(&rig, args.params.as_deref())?;
    let logs = prepare_all(&rig, &args.logs)?;
    let validation = prepare_all(&rig, &args.validate)?;
    let options = FitOptions { params, popsize: args.popsize, generations: args.generations, seed: args.seed };
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
    let mut calibrated = base.clone();
    calibrated.extend(&fit.values());
    let nominal = rig.parameters(&base)?;
    let calibrated = rig.parameters(&calibrated)?;
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let validation_report = validate(&rig, &validation, &nominal, &calibrated, &out)?;
    print!("{}", fit_table(&fit));
    if let Some(v) = &validation_report {
        println!(
            "held-out position RMSE: nominal {:.6}, calibrated {:.6} ({:+.1} %)",
            v.nominal,
            v.calibrated,
            v.change * 100.0
        );
    }
    write_calibration(&out.join("calibration.toml"), &rig, &fit, &args.logs, validation_report.as_ref())?;
    write_json(&out.join("fit.json"), &serde_json::json!({ "fit": fit, "validation": validation_report }))?;
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

fn prepare_all(rig: &Rig, paths: &[PathBuf]) -> anyhow::Result<Vec<PreparedLog>> {
    paths
        .iter()
        .map(|path| {
            let log = twinbots_log::read(path)?;
            let name = path.display().to_string();
            prepare(rig, &log, &name).map_err(|e| anyhow::anyhow!("{name}: {e:#}"))
        })
        .collect()
}

/// Held-out logs before and after.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Validation {
    pub logs: Vec<String>,
    pub nominal: f64,
    pub calibrated: f64,
    /// (calibrated − nominal) / nominal.
    pub change: f64,
}

fn validate(
    rig: &Rig,
    logs: &[PreparedLog],
    nominal: &Parameters,
    calibrated: &Parameters,
    out: &Path,
) -> anyhow::Result<Option<Validation>> {
    let Some(first) = logs.first() else { return Ok(None) };
    let before = position_rmse(rig, logs, nominal, 0.05);
    let after = position_rmse(rig, logs, calibrated, 0.05);
    let twins = run(rig, &first.start_positions(rig, nominal), &first.program, &[nominal.clone(), calibrated.clone()]);
    twinbots_sysid::plot::replay_png(
        &out.join("validation.png"),
        rig,
        first,
        &[("twin (nominal)", &twins[0], rig.biases(nominal)), ("twin (calibrated)", &twins[1], rig.biases(calibrated))],
    )?;
    Ok(Some(Validation {
        logs: logs.iter().map(|l| l.name.clone()).collect(),
        nominal: before,
        calibrated: after,
        change: (after - before) / before.max(1e-12),
    }))
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

fn write_calibration(
    path: &Path,
    rig: &Rig,
    fit: &Fit,
    logs: &[PathBuf],
    validation: Option<&Validation>,
) -> anyhow::Result<()> {
    let mut meta = toml::Table::new();
    let mut about = toml::Table::new();
    about.insert("robot".into(), rig.robot.into());
    about.insert("twinbots".into(), env!("CARGO_PKG_VERSION").into());
    about.insert("logs".into(), toml::Value::Array(logs.iter().map(|l| l.display().to_string().into()).collect()));
    about.insert("tracking_error_nominal".into(), fit.cost_nominal.into());
    about.insert("tracking_error_calibrated".into(), fit.cost_fitted.into());
    about.insert("replay_noise".into(), fit.replay_noise.into());
    about.insert("candidates".into(), (fit.candidates as i64).into());
    about.insert("seconds".into(), fit.seconds.into());
    if let Some(v) = validation {
        about.insert("validation_position_rmse_nominal".into(), v.nominal.into());
        about.insert("validation_position_rmse_calibrated".into(), v.calibrated.into());
    }
    meta.insert("fit".into(), toml::Value::Table(about));
    let spread: toml::Table = fit.parameters.iter().map(|p| (p.name.clone(), p.spread.into())).collect();
    meta.insert("spread".into(), toml::Value::Table(spread));
    let not: toml::Table = fit
        .parameters
        .iter()
        .filter_map(|p| p.not_identifiable.as_ref().map(|w| (p.name.clone(), w.clone().into())))
        .collect();
    if !not.is_empty() {
        meta.insert("not_identifiable".into(), toml::Value::Table(not));
    }
    let text = calibration_text(&fit.values(), &rig.catalogue, &meta);
    twinbots_api::files::write_atomic(path, text.as_bytes()).with_context(|| path.display().to_string())
}
