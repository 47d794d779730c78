//! `twinbots study <robot> [FILE.toml] --out DIR`: a policy test suite (the pendulums) or a cell
//! study (a robot with a pick-and-place cell: the UR5e, a robot file's arm with a cell and a
//! gripper) on the robot's twin (docs/studies.md).

use std::path::PathBuf;

use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_study::{cell, report, run_suite};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (see `twinbots robots`).
    pub robot: String,
    /// The suite (pendulums) or cell study (UR5e, robot files with a cell); default the robot's
    /// shipped one, `assets/studies/<robot>.toml` (a robot file: its file name).
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
    // A robot file's shipped study goes by the file's name (assets/robots/ur10-cell.toml:
    // assets/studies/ur10-cell.toml).
    let stem = std::path::Path::new(entry.name).file_stem().map_or(entry.name.into(), |s| s.to_string_lossy());
    let suite = args.suite.clone().unwrap_or_else(|| PathBuf::from("assets/studies").join(format!("{stem}.toml")));
    anyhow::ensure!(
        suite.exists(),
        "{}: no such suite file{}",
        suite.display(),
        if args.suite.is_none() { format!(" ({} has no shipped suite: name one)", entry.name) } else { String::new() }
    );
    // A robot file's arm has no test suites: its studies are cell studies (an arm without a
    // cell is told what it lacks).
    if entry.tasks.iter().any(|t| t.name == "pick-place") || RobotFile::is_path(entry.name) {
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
