//! What a study leaves behind (docs/studies.md): per run a directory with `timeseries.csv` and
//! `metadata.json`; `summary.csv` with one row per run; a plot per test; `report.md`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use twinbots_api::files::write_atomic;

use super::{RunRecord, StudyResult};

/// Writes everything into `out` (made if missing).
pub fn write(result: &StudyResult, suite_file: &Path, out: &Path) -> anyhow::Result<()> {
    let io = |path: &Path, e: std::io::Error| anyhow::anyhow!("{}: {e}", path.display());
    std::fs::create_dir_all(out.join("plots")).map_err(|e| io(out, e))?;
    for run in &result.runs {
        let dir = run_dir(out, run);
        std::fs::create_dir_all(&dir).map_err(|e| io(&dir, e))?;
        let csv = dir.join("timeseries.csv");
        write_atomic(&csv, timeseries_csv(run).as_bytes()).map_err(|e| io(&csv, e))?;
        let meta = serde_json::json!({
            "robot": result.robot,
            "suite": suite_file.display().to_string(),
            "signal": result.suite.signal,
            "setpoint": result.suite.setpoint,
            "settle_band": result.suite.settle_band,
            "duration_s": result.suite.duration,
            "push_link": result.suite.push.link,
            "push_direction": result.suite.push.direction,
            "run": run,
        });
        let json = dir.join("metadata.json");
        write_atomic(&json, serde_json::to_string_pretty(&meta)?.as_bytes()).map_err(|e| io(&json, e))?;
    }
    let summary = out.join("summary.csv");
    write_atomic(&summary, summary_csv(&result.runs).as_bytes()).map_err(|e| io(&summary, e))?;
    let plots = plot_tests(result, out)?;
    let report = out.join("report.md");
    write_atomic(&report, report_md(result, suite_file, &plots).as_bytes()).map_err(|e| io(&report, e))?;
    Ok(())
}

/// `out/<controller>/<test>-seed<seed>`.
pub fn run_dir(out: &Path, run: &RunRecord) -> PathBuf {
    out.join(&run.controller).join(format!("{}-seed{}", run.test, run.seed))
}

fn cell(v: f64) -> String {
    if v.is_finite() { format!("{v}") } else { String::new() }
}

fn timeseries_csv(run: &RunRecord) -> String {
    let mut text = run.columns.join(",") + "\n";
    for row in &run.series {
        text += &row.iter().map(|&v| cell(v)).collect::<Vec<_>>().join(",");
        text.push('\n');
    }
    text
}

const SUMMARY_HEADER: &str = "controller,test,kind,seed,force_n,at_s,push_s,payload_kg,survived,ended_s,ended_by,peak,peak_time_s,overshoot,max_deviation,settling_time_s,steady_state_error";

fn summary_csv(runs: &[RunRecord]) -> String {
    let mut text = format!("{SUMMARY_HEADER}\n");
    for r in runs {
        let m = &r.response;
        let optional = |v: Option<f64>| v.map(cell).unwrap_or_default();
        let _ = writeln!(
            text,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.controller,
            r.test,
            r.kind,
            r.seed,
            r.force_n,
            r.at_s,
            r.push_s,
            optional(r.payload_kg),
            r.survived,
            optional(r.ended_s),
            r.ended_by.as_deref().unwrap_or(""),
            cell(m.peak),
            cell(m.peak_time_s),
            cell(m.overshoot),
            cell(m.max_deviation),
            optional(m.settling_time_s),
            cell(m.steady_state_error),
        );
    }
    text
}

/// One plot per test: the signal of every controller and seed against time, the settling band
/// and the push's start. Returns (test, file name) pairs.
fn plot_tests(result: &StudyResult, out: &Path) -> anyhow::Result<Vec<(String, String)>> {
    let mut tests: Vec<&str> = Vec::new();
    for r in &result.runs {
        if !tests.contains(&r.test.as_str()) {
            tests.push(&r.test);
        }
    }
    let suite = &result.suite;
    let band = [suite.setpoint - suite.settle_band, suite.setpoint + suite.settle_band];
    let mut files = Vec::new();
    for test in tests {
        let runs: Vec<&RunRecord> = result.runs.iter().filter(|r| r.test == test).collect();
        let lines: Vec<(String, Vec<(f64, f64)>)> = runs
            .iter()
            .map(|r| {
                let label = if suite.seeds.len() > 1 {
                    format!("{} seed {}", r.controller, r.seed)
                } else {
                    r.controller.clone()
                };
                (label, r.series.iter().map(|row| (row[0], row[result.signal_column])).collect())
            })
            .collect();
        let marks: Vec<f64> = runs.first().filter(|r| r.push_s > 0.0).map(|r| r.at_s).into_iter().collect();
        let file = format!("{test}.png");
        twinbots_learn::plot::time_series(
            &out.join("plots").join(&file),
            &format!("{}: {test}", result.robot),
            &suite.signal,
            &lines,
            &band,
            &marks,
        )?;
        files.push((test.to_string(), file));
    }
    Ok(files)
}

fn report_md(result: &StudyResult, suite_file: &Path, plots: &[(String, String)]) -> String {
    let suite = &result.suite;
    let mut text = format!(
        "# {}: policy test suite\n\nSuite `{}`: {} runs of {} s; signal `{}`, set point {}, settled within ±{}.\n\n",
        result.robot,
        suite_file.display(),
        result.runs.len(),
        suite.duration,
        suite.signal,
        suite.setpoint,
        suite.settle_band
    );
    text += "| controller | test | seed | survived | peak | overshoot | largest deviation | settling (s) | steady-state error |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for r in &result.runs {
        let m = &r.response;
        let survived = match (r.survived, r.ended_s) {
            (true, _) => "yes".to_string(),
            (false, Some(t)) => format!("no ({} at {t:.2} s)", r.ended_by.as_deref().unwrap_or("ended")),
            (false, None) => "no".to_string(),
        };
        let settled = m.settling_time_s.map_or("never".to_string(), |s| format!("{s:.2}"));
        let _ = writeln!(
            text,
            "| {} | {} | {} | {survived} | {:.4} | {:.0} % | {:.4} | {settled} | {:.4} |",
            r.controller,
            r.test,
            r.seed,
            m.peak,
            100.0 * m.overshoot,
            m.max_deviation,
            m.steady_state_error
        );
    }
    for (test, file) in plots {
        let _ = write!(text, "\n## {test}\n\n![{test}](plots/{file})\n");
    }
    text
}
