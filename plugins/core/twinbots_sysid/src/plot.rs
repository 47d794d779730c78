//! PNG figures: twin against log per joint, and a fit's convergence.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;

use crate::rig::Rig;
use crate::search::Generation;
use crate::trace::{Envelope, ReplayPlot};

static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // Compiled in; a font that does not parse is a build defect the tests catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// One panel of a figure: `caption` over time (s) along `x` and `y` up, with its grid drawn
/// (`y_labels` pixels for the y axis' numbers).
fn time_chart<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, plotters::coord::Shift>,
    caption: &str,
    x: std::ops::Range<f64>,
    y: std::ops::Range<f64>,
    y_labels: u32,
) -> anyhow::Result<
    ChartContext<
        'a,
        BitMapBackend<'b>,
        Cartesian2d<plotters::coord::types::RangedCoordf64, plotters::coord::types::RangedCoordf64>,
    >,
> {
    let mut chart = ChartBuilder::on(area)
        .margin(6)
        .x_label_area_size(24)
        .y_label_area_size(y_labels)
        .caption(caption, ("sans-serif", 14))
        .build_cartesian_2d(x, y)?;
    chart.configure_mesh().x_desc("s").label_style(("sans-serif", 11)).draw()?;
    Ok(chart)
}

/// The series' labels in a box at the chart's corner.
fn legend<'a, DB, CT>(chart: &mut ChartContext<'a, DB, CT>, font: u32) -> anyhow::Result<()>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: plotters::coord::CoordTranslate,
{
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", font))
        .draw()?;
    Ok(())
}

/// Writes a PNG through `draw`, atomically.
fn write_png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    register_font();
    twinbots_api::files::write_through(path, |tmp| {
        let root = BitMapBackend::new(tmp, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present().map_err(|e| anyhow::anyhow!("{}: {e}", tmp.display()))?;
        Ok(())
    })
}

/// One row per joint: the logged position and each labelled twin's against time (left), and
/// each twin's position error, twin − log (right: at the left's scale they overlap).
pub fn replay_png(path: &Path, rig: &Rig, plot: &ReplayPlot) -> anyhow::Result<()> {
    let rows = rig.joints.len();
    write_png(path, (1400, 220 * rows as u32 + 40), |root| {
        let root = root.titled(&format!("{}: twin vs log ({})", rig.robot, plot.log), ("sans-serif", 20))?;
        let colours = [RED, BLUE, GREEN];
        for (j, row) in root.split_evenly((rows, 1)).iter().enumerate() {
            let (left, right) = row.split_horizontally(row.dim_in_pixel().0 as i32 / 2);
            let positions: Vec<Vec<(f64, f64)>> = plot.positions[j].iter().map(Envelope::points).collect();
            let errors: Vec<Vec<(f64, f64)>> = plot.errors[j].iter().map(Envelope::points).collect();
            let t_max = positions[0].last().map_or(1.0, |p| p.0);
            let mut panels = [
                (&left, format!("{} (rad or m)", rig.joints[j]), positions, true),
                (&right, format!("{}: twin − log", rig.joints[j]), errors, false),
            ];
            for (area, caption, series, with_log) in panels.iter_mut() {
                let (lo, hi) = bounds(series.iter().flatten().map(|p| p.1));
                let mut chart = time_chart(area, caption, 0.0..t_max, lo..hi, 70)?;
                let mut lines = series.iter();
                if *with_log {
                    chart
                        .draw_series(LineSeries::new(
                            lines.next().expect("the log's line").clone(),
                            BLACK.stroke_width(2),
                        ))?
                        .label("log")
                        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
                }
                for (label, (line, colour)) in plot.labels.iter().zip(lines.zip(colours.iter().cycle())) {
                    let colour = *colour;
                    chart
                        .draw_series(LineSeries::new(line.clone(), colour.stroke_width(1)))?
                        .label(label.as_str())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
                }
                legend(&mut chart, 11)?;
            }
        }
        Ok(())
    })
}

/// The best and mean tracking error of every generation (log scale), and the nominal twin's.
pub fn convergence_png(path: &Path, title: &str, history: &[Generation], nominal: f64) -> anyhow::Result<()> {
    write_png(path, (900, 540), |root| {
        let values = history
            .iter()
            .flat_map(|g| [g.best, g.mean, g.best_so_far])
            .chain([nominal])
            .filter(|v| v.is_finite() && *v > 0.0);
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
        let (lo, hi) = if lo.is_finite() { (lo * 0.8, hi * 1.25) } else { (1e-3, 1.0) };
        let x_max = history.len().max(2) as f64;
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x_max, (lo..hi).log_scale())?;
        chart
            .configure_mesh()
            .x_desc("generation")
            .y_desc("tracking error (weighted)")
            .label_style(("sans-serif", 13))
            .draw()?;
        let line = |f: fn(&Generation) -> f64| {
            history.iter().map(move |g| ((g.generation + 1) as f64, f(g))).collect::<Vec<_>>()
        };
        chart
            .draw_series(LineSeries::new(line(|g| g.mean), BLUE.mix(0.5)))?
            .label("generation mean")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.mix(0.5)));
        chart
            .draw_series(LineSeries::new(line(|g| g.best_so_far), BLUE.stroke_width(2)))?
            .label("best so far")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        chart
            .draw_series(LineSeries::new([(0.0, nominal), (x_max, nominal)], RED.mix(0.7)))?
            .label("nominal twin")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        legend(&mut chart, 13)?;
        Ok(())
    })
}

/// A robot followed live by its twin (`twinbots monitor`): one row per joint, the position
/// error (robot − twin, mrad) on the left and the effort residual (robot − twin, N·m) on the
/// right, against the controller's time; `alarms` (times, s) drawn as vertical red lines.
pub fn divergence_png(
    path: &Path,
    title: &str,
    robot: &twinbots_log::RobotLog,
    twin: &twinbots_log::RobotLog,
    alarms: &[f64],
) -> anyhow::Result<()> {
    let rows = robot.joints.len();
    anyhow::ensure!(rows > 0 && robot.states.len() == twin.states.len(), "robot and twin logs do not pair up");
    let t_max = robot.states.last().map_or(1.0, |s| s.time).max(1e-3);
    let t0 = robot.states.first().map_or(0.0, |s| s.time);
    write_png(path, (1400, 200 * rows as u32 + 40), |root| {
        let root = root.titled(title, ("sans-serif", 20))?;
        for (j, row) in root.split_evenly((rows, 1)).iter().enumerate() {
            let (left, right) = row.split_horizontally(row.dim_in_pixel().0 as i32 / 2);
            let pairs = robot.states.iter().zip(&twin.states);
            let position: Vec<(f64, f64)> =
                pairs.clone().map(|(r, t)| (r.time, 1e3 * (r.position[j] - t.position[j]))).collect();
            let effort: Vec<(f64, f64)> = pairs
                .map(|(r, t)| {
                    (r.time, r.effort.get(j).copied().unwrap_or(0.0) - t.effort.get(j).copied().unwrap_or(0.0))
                })
                .collect();
            for (area, caption, series) in [
                (&left, format!("{}: robot − twin (mrad)", robot.joints[j]), position),
                (&right, format!("{}: effort residual (N·m)", robot.joints[j]), effort),
            ] {
                let (lo, hi) =
                    series.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
                let (lo, hi) = if lo.is_finite() { (lo.min(-1e-3), hi.max(1e-3)) } else { (-1.0, 1.0) };
                let pad = (hi - lo) * 0.05;
                let mut chart = time_chart(area, &caption, t0..t_max, (lo - pad)..(hi + pad), 60)?;
                chart.draw_series(LineSeries::new(series, BLUE.stroke_width(1)))?;
                for &a in alarms {
                    chart.draw_series(LineSeries::new(vec![(a, lo - pad), (a, hi + pad)], RED.stroke_width(1)))?;
                }
            }
        }
        Ok(())
    })
}

/// One row per joint: each labelled series of efforts against time (the first, the measured, in
/// black).
pub fn efforts_png(
    path: &Path,
    title: &str,
    joints: &[String],
    time: &[f64],
    series: &[(&str, &[Vec<f64>])],
) -> anyhow::Result<()> {
    let colours = [BLACK, RED, BLUE, GREEN];
    write_png(path, (1400, 200 * joints.len() as u32 + 40), |root| {
        let root = root.titled(title, ("sans-serif", 20))?;
        let t_max = time.last().copied().unwrap_or(1.0).max(1e-3);
        for (j, area) in root.split_evenly((joints.len(), 1)).iter().enumerate() {
            let values = series.iter().flat_map(|(_, s)| s.iter().map(move |v| v[j]));
            let (lo, hi) = bounds(values);
            let mut chart = time_chart(area, &format!("{} (N·m)", joints[j]), 0.0..t_max, lo..hi, 70)?;
            for ((label, s), colour) in series.iter().zip(colours.iter().cycle()) {
                let colour = *colour;
                let width = if colour == BLACK { 2 } else { 1 };
                chart
                    .draw_series(LineSeries::new(
                        time.iter().zip(s.iter()).map(|(t, v)| (*t, v[j])),
                        colour.stroke_width(width),
                    ))?
                    .label(*label)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(width)));
            }
            legend(&mut chart, 11)?;
        }
        Ok(())
    })
}

/// One row per joint: the residual (measured − model) against time, its threshold either side,
/// and the flagged intervals shaded.
pub fn shadow_png(
    path: &Path,
    title: &str,
    joints: &[String],
    time: &[f64],
    residuals: &[Vec<f64>],
    thresholds: Option<&[Vec<f64>]>,
    flagged: &[(f64, f64)],
) -> anyhow::Result<()> {
    write_png(path, (1400, 170 * joints.len() as u32 + 40), |root| {
        let root = root.titled(title, ("sans-serif", 20))?;
        let t_max = time.last().copied().unwrap_or(1.0).max(1e-3);
        for (j, area) in root.split_evenly((joints.len(), 1)).iter().enumerate() {
            let limit = |k: usize| thresholds.map_or(0.0, |t| t[k][j]);
            let values = residuals.iter().enumerate().flat_map(|(k, r)| [r[j], limit(k), -limit(k)]);
            let (lo, hi) = bounds(values);
            let mut chart = time_chart(area, &format!("{}: measured − twin (N·m)", joints[j]), 0.0..t_max, lo..hi, 70)?;
            chart.draw_series(
                flagged.iter().map(|(a, b)| Rectangle::new([(*a, lo), (b.max(a + 0.02), hi)], RED.mix(0.25).filled())),
            )?;
            if thresholds.is_some() {
                for sign in [1.0, -1.0] {
                    chart.draw_series(LineSeries::new(
                        time.iter().enumerate().map(|(k, t)| (*t, sign * limit(k))),
                        BLUE.stroke_width(1),
                    ))?;
                }
            }
            chart.draw_series(LineSeries::new(
                time.iter().zip(residuals).map(|(t, r)| (*t, r[j])),
                BLACK.stroke_width(1),
            ))?;
        }
        Ok(())
    })
}

/// The range of `values`, padded; (-1, 1) when there are none.
fn bounds(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) =
        values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
    if !lo.is_finite() {
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    (lo - pad, hi + pad)
}
