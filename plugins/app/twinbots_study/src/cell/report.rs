//! What a cell study leaves behind (docs/studies.md): `results.csv` (one row per episode),
//! `summary.csv` (one per combination), `phases.csv`, the plots and `report.md`.

use std::fmt::Write as _;
use std::path::Path;

use bevy::math::Vec3;
use twinbots_api::files::write_atomic;
use twinbots_task::cell::layout::CellLayout;
use twinbots_task::cell::parts::{PART_HEIGHT, POCKET_FLOOR};
use twinbots_task::cell::program::CLEARANCE;

use super::plan::Combination;
use super::{CellStudyResult, EpisodeRecord, PHASES, PlacedArm, plots};

/// Grid step of the reachability maps (m).
const REACH_STEP: f32 = 0.05;

/// One combination's figures.
pub struct Summary {
    pub episodes: usize,
    pub success_rate: f64,
    pub cycle_time_mean_s: Option<f64>,
    pub cycle_time_p95_s: Option<f64>,
    pub energy_mean_j: f64,
    pub collision_events: u32,
    pub protective_stops: u32,
    pub reach_failures: usize,
}

impl Summary {
    pub fn of(episodes: &[&EpisodeRecord]) -> Self {
        let n = episodes.len().max(1) as f64;
        let mut cycles: Vec<f64> = episodes.iter().filter_map(|e| e.cycle_time_s.filter(|_| e.success)).collect();
        cycles.sort_by(f64::total_cmp);
        let mean = (!cycles.is_empty()).then(|| cycles.iter().sum::<f64>() / cycles.len() as f64);
        // Nearest rank.
        let p95 = cycles.get(((0.95 * cycles.len() as f64).ceil() as usize).saturating_sub(1)).copied();
        Self {
            episodes: episodes.len(),
            success_rate: episodes.iter().filter(|e| e.success).count() as f64 / n,
            cycle_time_mean_s: mean,
            cycle_time_p95_s: p95,
            energy_mean_j: episodes.iter().map(|e| e.energy_j).sum::<f64>() / n,
            collision_events: episodes.iter().map(|e| e.collision_events).sum(),
            protective_stops: episodes.iter().map(|e| e.protective_stops).sum(),
            reach_failures: episodes.iter().filter(|e| e.reach_failure).count(),
        }
    }
}

impl CellStudyResult {
    fn labels(&self, c: &Combination) -> [String; 6] {
        [
            self.controllers[c.controller].clone(),
            self.layouts[c.layout].0.clone(),
            format!("{}", c.speed),
            c.payload.map_or("nominal".into(), |m| format!("{m}")),
            format!("{}", c.latency),
            c.failure.name().to_string(),
        ]
    }

    fn episodes_of(&self, combination: usize) -> Vec<&EpisodeRecord> {
        self.episodes.iter().filter(|e| e.combination == combination).collect()
    }
}

const FACTORS: [&str; 6] = ["controller", "layout", "speed", "payload_kg", "latency_steps", "failure"];

fn optional(v: Option<f64>) -> String {
    v.map(|v| format!("{v:.4}")).unwrap_or_default()
}

/// Writes everything into `out` (made if missing).
pub fn write(result: &CellStudyResult, study_file: &Path, out: &Path) -> anyhow::Result<()> {
    let io = |path: &Path, e: std::io::Error| anyhow::anyhow!("{}: {e}", path.display());
    std::fs::create_dir_all(out.join("plots")).map_err(|e| io(out, e))?;
    let phase_names: Vec<&str> = PHASES.iter().map(|(_, n)| *n).collect();

    let mut results = format!(
        "{},episode,success,outcome,cycle_time_s,energy_j,collision_events,joint_limit_events,protective_stops,reach_failure,steps,{}\n",
        FACTORS.join(","),
        phase_names.iter().map(|p| format!("{p}_s")).collect::<Vec<_>>().join(",")
    );
    for e in &result.episodes {
        let labels = result.labels(&result.combinations[e.combination]);
        let _ = writeln!(
            results,
            "{},{},{},{},{},{:.4},{},{},{},{},{},{}",
            labels.join(","),
            e.episode,
            e.success,
            e.outcome,
            optional(e.cycle_time_s),
            e.energy_j,
            e.collision_events,
            e.joint_limit_events,
            e.protective_stops,
            e.reach_failure,
            e.steps,
            e.phases_s.iter().map(|s| format!("{s:.3}")).collect::<Vec<_>>().join(",")
        );
    }
    let path = out.join("results.csv");
    write_atomic(&path, results.as_bytes()).map_err(|e| io(&path, e))?;

    let summaries: Vec<Summary> = (0..result.combinations.len()).map(|c| Summary::of(&result.episodes_of(c))).collect();
    let mut summary = format!(
        "{},episodes,success_rate,cycle_time_mean_s,cycle_time_p95_s,energy_mean_j,collision_events,protective_stops,reach_failures\n",
        FACTORS.join(",")
    );
    for (c, s) in result.combinations.iter().zip(&summaries) {
        let _ = writeln!(
            summary,
            "{},{},{:.4},{},{},{:.4},{},{},{}",
            result.labels(c).join(","),
            s.episodes,
            s.success_rate,
            optional(s.cycle_time_mean_s),
            optional(s.cycle_time_p95_s),
            s.energy_mean_j,
            s.collision_events,
            s.protective_stops,
            s.reach_failures
        );
    }
    let path = out.join("summary.csv");
    write_atomic(&path, summary.as_bytes()).map_err(|e| io(&path, e))?;

    let breakdown = phase_breakdown(result);
    let mut phases = format!(
        "controller,layout,cycles,{}\n",
        phase_names.iter().map(|p| format!("{p}_s")).collect::<Vec<_>>().join(",")
    );
    for (label, cycles, times) in &breakdown {
        // No successful cycle: no times to give.
        let cells: Vec<String> =
            times.iter().map(|t| if *cycles > 0 { format!("{t:.3}") } else { String::new() }).collect();
        let _ = writeln!(phases, "{},{cycles},{}", label.replace(" in ", ","), cells.join(","));
    }
    let path = out.join("phases.csv");
    write_atomic(&path, phases.as_bytes()).map_err(|e| io(&path, e))?;

    let figures = draw(result, out, &breakdown)?;
    let path = out.join("report.md");
    write_atomic(&path, report_md(result, study_file, &summaries, &breakdown, &figures).as_bytes())
        .map_err(|e| io(&path, e))?;
    Ok(())
}

/// Per controller and layout: how many successful cycles, and their mean seconds per phase.
fn phase_breakdown(result: &CellStudyResult) -> Vec<(String, usize, Vec<f64>)> {
    let mut rows = Vec::new();
    for (c, controller) in result.controllers.iter().enumerate() {
        for (l, (layout, _)) in result.layouts.iter().enumerate() {
            let cycles: Vec<&EpisodeRecord> = result
                .episodes
                .iter()
                .filter(|e| {
                    e.success && {
                        let k = &result.combinations[e.combination];
                        k.controller == c && k.layout == l
                    }
                })
                .collect();
            let n = cycles.len().max(1) as f64;
            let times = (0..PHASES.len()).map(|p| cycles.iter().map(|e| e.phases_s[p]).sum::<f64>() / n).collect();
            rows.push((format!("{controller} in {layout}"), cycles.len(), times));
        }
    }
    rows
}

/// Every plot; returns (caption, file under plots/).
fn draw(
    result: &CellStudyResult,
    out: &Path,
    breakdown: &[(String, usize, Vec<f64>)],
) -> anyhow::Result<Vec<(String, String)>> {
    let dir = out.join("plots");
    let mut figures = Vec::new();
    // Cycle time against each factor with more than one level (the others averaged over).
    for (f, factor) in FACTORS.iter().enumerate().skip(1) {
        let mut levels: Vec<String> = Vec::new();
        for c in &result.combinations {
            let level = result.labels(c)[f].clone();
            if !levels.contains(&level) {
                levels.push(level);
            }
        }
        if levels.len() < 2 {
            continue;
        }
        let series: Vec<(String, Vec<Option<f64>>)> = result
            .controllers
            .iter()
            .enumerate()
            .map(|(ci, name)| {
                let values = levels
                    .iter()
                    .map(|level| {
                        let cycles: Vec<f64> = result
                            .episodes
                            .iter()
                            .filter(|e| e.success)
                            .filter(|e| {
                                let c = &result.combinations[e.combination];
                                c.controller == ci && result.labels(c)[f] == *level
                            })
                            .filter_map(|e| e.cycle_time_s)
                            .collect();
                        (!cycles.is_empty()).then(|| cycles.iter().sum::<f64>() / cycles.len() as f64)
                    })
                    .collect();
                (name.clone(), values)
            })
            .collect();
        let file = format!("cycle-time-vs-{factor}.png");
        plots::grouped_bars(
            &dir.join(&file),
            &format!("{}: cycle time by {factor}", result.robot),
            "mean cycle time of successes (s)",
            &levels,
            &series,
        )?;
        figures.push((format!("Cycle time by {factor}"), file));
    }
    // Success: layouts × failure scenarios, per controller (other factors pooled).
    let failures: Vec<&str> = {
        let mut names = Vec::new();
        for c in &result.combinations {
            if !names.contains(&c.failure.name()) {
                names.push(c.failure.name());
            }
        }
        names
    };
    for (ci, controller) in result.controllers.iter().enumerate() {
        let values: Vec<Vec<Option<f64>>> = (0..result.layouts.len())
            .map(|l| {
                failures
                    .iter()
                    .map(|failure| {
                        let eps: Vec<&EpisodeRecord> = result
                            .episodes
                            .iter()
                            .filter(|e| {
                                let c = &result.combinations[e.combination];
                                c.controller == ci && c.layout == l && c.failure.name() == *failure
                            })
                            .collect();
                        (!eps.is_empty()).then(|| eps.iter().filter(|e| e.success).count() as f64 / eps.len() as f64)
                    })
                    .collect()
            })
            .collect();
        let file = format!("success-{controller}.png");
        let rows: Vec<String> = result.layouts.iter().map(|(n, _)| n.clone()).collect();
        let columns: Vec<String> = failures.iter().map(|s| s.to_string()).collect();
        plots::heat_map(
            &dir.join(&file),
            &format!("{controller}: success by layout and failure"),
            &rows,
            &columns,
            &values,
        )?;
        figures.push((format!("Success of {controller}, layouts × failure scenarios"), file));
    }
    for ((name, layout), arm) in result.layouts.iter().zip(&result.arms) {
        let file = format!("reach-{name}.png");
        plots::reach_map(
            &dir.join(&file),
            &format!("{name}: where the tool reaches, {:.2} m above the table", approach_height()),
            layout,
            REACH_STEP,
            &reach_grid(layout, arm),
        )?;
        figures.push((format!("Reachability over the table, layout {name}"), file));
    }
    let rows: Vec<(String, Vec<f64>)> =
        breakdown.iter().filter(|(_, n, _)| *n > 0).map(|(l, _, t)| (l.clone(), t.clone())).collect();
    if !rows.is_empty() {
        let names: Vec<&str> = PHASES.iter().map(|(_, n)| *n).collect();
        plots::phases(&dir.join("phases.png"), &format!("{}: a cycle's time per phase", result.robot), &names, &rows)?;
        figures.push(("Cycle time per phase of the program".into(), "phases.png".into()));
    }
    Ok(figures)
}

/// The program's approach height above the table top: the part's top plus the clearance.
fn approach_height() -> f32 {
    POCKET_FLOOR + PART_HEIGHT + CLEARANCE
}

/// Reachability (tool pointing down, at the approach height) over the table top, on a grid of
/// [`REACH_STEP`]: columns along x, rows along y, in the cell frame.
pub fn reach_grid(layout: &CellLayout, arm: &PlacedArm) -> Vec<Vec<bool>> {
    let t = &layout.table;
    let (nx, ny) = ((t.size[0] / REACH_STEP).round() as usize, (t.size[1] / REACH_STEP).round() as usize);
    let base = arm.base.inverse();
    (0..nx)
        .map(|i| {
            (0..ny)
                .map(|j| {
                    let x = t.centre[0] - t.size[0] / 2.0 + (i as f32 + 0.5) * REACH_STEP;
                    let y = t.centre[1] - t.size[1] / 2.0 + (j as f32 + 0.5) * REACH_STEP;
                    arm.reachable(base.transform_point(Vec3::new(x, y, t.height + approach_height())))
                })
                .collect()
        })
        .collect()
}

fn report_md(
    result: &CellStudyResult,
    study_file: &Path,
    summaries: &[Summary],
    breakdown: &[(String, usize, Vec<f64>)],
    figures: &[(String, String)],
) -> String {
    let s = &result.study;
    let mut text = format!(
        "# {}: cell study\n\nStudy `{}`: {} combinations × {} episodes ({} in all) in {:.0} s; controllers {}; layouts {}.\n\n",
        result.robot,
        study_file.display(),
        result.combinations.len(),
        s.episodes,
        result.episodes.len(),
        result.wall_s,
        result.controllers.join(", "),
        result.layouts.iter().map(|(n, _)| n.as_str()).collect::<Vec<_>>().join(", "),
    );
    text += "| controller | layout | speed | payload (kg) | latency (steps) | failure | success | cycle mean (s) | cycle p95 (s) | energy (J) | collisions | stops | reach failures |\n";
    text += "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n";
    for (c, m) in result.combinations.iter().zip(summaries) {
        let cycle = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.2}"));
        let _ = writeln!(
            text,
            "| {} | {:.0} % | {} | {} | {:.1} | {} | {} | {} |",
            result.labels(c).join(" | "),
            100.0 * m.success_rate,
            cycle(m.cycle_time_mean_s),
            cycle(m.cycle_time_p95_s),
            m.energy_mean_j,
            m.collision_events,
            m.protective_stops,
            m.reach_failures
        );
    }
    text += "\n## Cycle time per phase (successful cycles)\n\n| controller in layout | cycles | ";
    text += &PHASES.iter().map(|(_, n)| format!("{n} (s)")).collect::<Vec<_>>().join(" | ");
    text += " |\n|";
    text += &" --- |".repeat(PHASES.len() + 2);
    text += "\n";
    for (label, n, times) in breakdown {
        let cells: Vec<String> = times.iter().map(|t| if *n > 0 { format!("{t:.2}") } else { "—".into() }).collect();
        let _ = writeln!(text, "| {label} | {n} | {} |", cells.join(" | "));
    }
    for (caption, file) in figures {
        let _ = write!(text, "\n## {caption}\n\n![{caption}](plots/{file})\n");
    }
    text
}
