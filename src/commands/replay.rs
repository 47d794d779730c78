//! `twinbots replay <robot> LOG`: the twin starts in the logged state, takes the logged commands
//! at the logged times, and is compared with the log per joint; writes a PNG of twin vs log and
//! the twin's trajectory as a log beside it.

use anyhow::Context;
use std::path::PathBuf;

use twinbots_sysid::replay::twin_log;
use twinbots_sysid::{Rig, compare, prepare, run};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them).
    pub robot: String,
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
    /// Where a UR recording's efforts come from (docs/logs.md): `none`, `target_moment` (the
    /// controller's model torque) or `current:K0,…,K5` (actual currents × torque constants).
    #[arg(long, default_value = "none", value_parser = twinbots_log::rtde_csv::Efforts::parse)]
    pub efforts: twinbots_log::rtde_csv::Efforts,
}

/// `twinbots replay`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let rig = Rig::of(&registry::find(&args.robot)?)?;
    let calibration = rig.read_calibration(args.calibration.as_deref())?;
    anyhow::ensure!(args.threshold > 0.0, "--threshold must be positive");
    let log = twinbots_log::read_with(&args.log, &args.efforts)?;
    let name = args.log.display().to_string();
    let prepared = prepare(&rig, &log, &name).map_err(|e| anyhow::anyhow!("{name}: {e:#}"))?;
    let params = rig.parameters(&calibration)?;
    let bias = rig.biases(&params);
    let twin = run(&rig, &prepared.start_positions(&rig, &params), &prepared.program, std::slice::from_ref(&params))
        .pop()
        .expect("one arena");
    let report = compare(&rig, &prepared, &twin, &bias, args.threshold);
    print!("{}", report.table());
    let out = args.out.unwrap_or_else(|| PathBuf::from(format!("{}.replay", args.log.display())));
    std::fs::create_dir_all(&out).with_context(|| out.display().to_string())?;
    let label = if args.calibration.is_some() { "twin (calibrated)" } else { "twin (nominal)" };
    twinbots_sysid::plot::replay_png(&out.join("replay.png"), &rig, &prepared, &[(label, &twin, bias.clone())])?;
    let calibration_name = args.calibration.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
    twinbots_log::write(&twin_log(&rig, &prepared, &twin, &bias, &calibration_name), &out.join("twin.mcap"))?;
    twinbots_api::files::write_json(&out.join("replay.json"), &report)?;
    println!("wrote {}/replay.png, twin.mcap, replay.json", out.display());
    Ok(())
}
