//! `twinbots study <robot> [FILE.toml] --out DIR`: a policy test suite (the pendulums) or a cell
//! study (the UR5e) on the robot's twin (docs/studies.md).

use std::path::PathBuf;

use twinbots_study::{cell, report, run_suite};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (see `twinbots robots`).
    pub robot: String,
    /// The suite (pendulums) or cell study (UR5e); default the robot's shipped one,
    /// `assets/studies/<robot>.toml`.
    pub suite: Option<PathBuf>,
    /// Where the results go (made if missing).
    #[arg(long, default_value = "study")]
    pub out: PathBuf,
    /// Controllers instead of the suite's, comma-separated: `classic`, run directories, `.onnx`
    /// files.
    #[arg(long, value_delimiter = ',')]
    pub controller: Vec<String>,
}

/// `twinbots study`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let entry = registry::find(&args.robot)?;
    let suite =
        args.suite.clone().unwrap_or_else(|| PathBuf::from("assets/studies").join(format!("{}.toml", entry.name)));
    anyhow::ensure!(
        suite.exists(),
        "{}: no such suite file{}",
        suite.display(),
        if args.suite.is_none() { format!(" ({} has no shipped suite: name one)", entry.name) } else { String::new() }
    );
    if entry.cell.is_some() {
        let result = cell::run(&entry, &suite, &args.controller)?;
        cell::report::write(&result, &suite, &args.out)?;
        let placed = result.episodes.iter().filter(|e| e.success).count();
        println!(
            "{} episodes, {placed} placed; results in {} (results.csv, summary.csv, phases.csv, report.md, plots/)",
            result.episodes.len(),
            args.out.display()
        );
        return Ok(());
    }
    let result = run_suite(&entry, &suite, &args.controller)?;
    report::write(&result, &suite, &args.out)?;
    let survived = result.runs.iter().filter(|r| r.survived).count();
    println!(
        "{} runs, {survived} survived; results in {} (summary.csv, report.md, plots/)",
        result.runs.len(),
        args.out.display()
    );
    Ok(())
}
