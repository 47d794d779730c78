//! `twinbots compare RUN...`: figures over seeds. Runs of one robot's task (typically the same
//! command with `--seed 0..N`) as the median, quartiles and interquartile mean of steps to
//! solve, wall clock and final evaluation, and their learning curves as a median with the band
//! between the quartiles (PNG). One seed's figure cannot be told from noise; this can.

use std::path::PathBuf;

use twinbots_api::Measure;
use twinbots_learn::RunDir;
use twinbots_learn::seeds::{Spread, band};

use twinbots_run::registry;
use twinbots_run::settings::TrainSettings;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Run directories of `twinbots train`, all of one robot.
    #[arg(required = true, num_args = 1..)]
    pub runs: Vec<PathBuf>,
    /// Draw the learning curves' median and interquartile band to this PNG.
    #[arg(long)]
    pub png: Option<PathBuf>,
    /// Write the figures as JSON to this file.
    #[arg(long)]
    pub json: Option<PathBuf>,
}

/// One run's figures.
#[derive(serde::Serialize)]
struct RunFigures {
    run: PathBuf,
    seed: u64,
    solved: bool,
    /// Steps to solve; unsolved runs count as never (∞) in the spread.
    solved_at_timesteps: Option<u64>,
    timesteps: u64,
    wall_clock_s: f64,
    final_success_rate: Option<f32>,
    final_mean_score: Option<f32>,
}

/// The figures over the runs, as `--json` writes them.
#[derive(serde::Serialize)]
struct Comparison {
    robot: String,
    runs: Vec<RunFigures>,
    solved: usize,
    /// Steps to solve (∞ for a run that did not, written as null).
    steps_to_solve: Option<Spread>,
    wall_clock_s: Option<Spread>,
    final_success_rate: Option<Spread>,
    final_mean_score: Option<Spread>,
}

/// `twinbots compare`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let mut first: Option<TrainSettings> = None;
    let mut runs = Vec::new();
    let mut curves = Vec::new();
    for path in &args.runs {
        let dir = RunDir::new(path);
        let settings = TrainSettings::of_run(&dir)?;
        match &first {
            None => first = Some(settings.clone()),
            Some(f) if f.robot != settings.robot => {
                anyhow::bail!(
                    "{}: a run of {}, the others are of {}: compare runs of one robot",
                    path.display(),
                    settings.robot,
                    f.robot
                )
            }
            Some(f) if f.task != settings.task => {
                let name = |t: &Option<String>| t.clone().unwrap_or_else(|| "its main task".into());
                anyhow::bail!(
                    "{}: a run of {}, the others of {}: compare runs of one task",
                    path.display(),
                    name(&settings.task),
                    name(&f.task)
                )
            }
            Some(_) => {}
        }
        let summary = dir.read_summary().map_err(|e| anyhow::anyhow!("{}: no finished run ({e})", path.display()))?;
        runs.push(RunFigures {
            run: path.clone(),
            seed: settings.seed,
            solved: summary.solved,
            solved_at_timesteps: summary.solved_at_timesteps,
            timesteps: summary.timesteps,
            wall_clock_s: summary.wall_clock_s_this_session,
            final_success_rate: summary.evaluation.as_ref().and_then(|e| e.success_rate),
            final_mean_score: summary.evaluation.as_ref().map(|e| e.mean_score),
        });
        curves.push(dir);
    }
    let first = first.expect("clap requires a run");
    // The runs' own task: its solved criterion is the curve's threshold.
    let entry = registry::find(&first.robot)?;
    let spec = first.task(&entry)?;
    let task = first.task_name(&entry)?;
    let robot = first.robot;
    let spread = |values: Vec<f64>| Spread::of(&values);
    let comparison = Comparison {
        solved: runs.iter().filter(|r| r.solved).count(),
        steps_to_solve: spread(
            runs.iter().map(|r| r.solved_at_timesteps.map_or(f64::INFINITY, |t| t as f64)).collect(),
        ),
        wall_clock_s: spread(runs.iter().map(|r| r.wall_clock_s).collect()),
        final_success_rate: spread(runs.iter().filter_map(|r| r.final_success_rate.map(f64::from)).collect()),
        final_mean_score: spread(runs.iter().filter_map(|r| r.final_mean_score.map(f64::from)).collect()),
        robot,
        runs,
    };
    print(&comparison);
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&comparison)?;
        std::fs::write(path, text + "\n").map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    }
    if let Some(path) = &args.png {
        // The curve the task is solved on: evaluation success, or the training episodes' score.
        let by_success = spec.solved.is_some_and(|c| c.measure == Measure::Success);
        let mut lines = Vec::new();
        for dir in &curves {
            let line: Vec<(f64, f64)> = if by_success {
                dir.read_evaluations()?
                    .iter()
                    .filter_map(|e| Some((e.timesteps as f64, f64::from(e.success_rate?))))
                    .collect()
            } else {
                dir.read_progress()?
                    .iter()
                    .filter(|s| s.mean_reward.is_finite())
                    .map(|s| (s.timesteps as f64, f64::from(s.mean_reward)))
                    .collect()
            };
            lines.push(line);
        }
        let y_label = if by_success { "evaluation success rate" } else { "episode reward (last 100 episodes)" };
        let title = format!("{} {task} — {} runs, median and interquartile range", comparison.robot, lines.len());
        let threshold = spec.solved.map(|c| f64::from(c.threshold));
        twinbots_learn::plot::seed_band(path, &title, y_label, &lines, &band(&lines, 200), threshold)?;
        println!("learning curves: {}", path.display());
    }
    Ok(())
}

fn print(c: &Comparison) {
    println!("{}: {} runs, {} solved", c.robot, c.runs.len(), c.solved);
    for r in &c.runs {
        let solved = r.solved_at_timesteps.map_or("not solved".to_string(), |t| format!("solved at {t}"));
        let success = r.final_success_rate.map_or(String::new(), |s| format!(", final evaluation {:.1} %", 100.0 * s));
        println!(
            "  seed {:<3} {solved}, {} steps, {:.0} s{success}  ({})",
            r.seed,
            r.timesteps,
            r.wall_clock_s,
            r.run.display()
        );
    }
    let line = |name: &str, s: &Option<Spread>, scale: f64, decimals: usize, unit: &str| {
        if let Some(s) = s {
            let f = |v: f64| if v.is_finite() { format!("{:.decimals$}{unit}", v * scale) } else { "never".into() };
            println!("  {name}: median {}, IQR {} – {}, IQM {}", f(s.median), f(s.q1), f(s.q3), f(s.iqm));
        }
    };
    line("steps to solve", &c.steps_to_solve, 1.0, 0, "");
    line("wall clock", &c.wall_clock_s, 1.0, 0, " s");
    line("final evaluation success", &c.final_success_rate, 100.0, 1, " %");
    line("final evaluation score", &c.final_mean_score, 1.0, 1, "");
}
