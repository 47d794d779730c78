//! Learning curves as PNG (plotters, with the DejaVu Sans font shipped in `assets/fonts`).

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;

use twinbots_api::{Measure, SolvedCriterion};

static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// One point of a learning curve.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CurvePoint {
    pub timesteps: u64,
    pub mean_reward: f32,
    pub min_reward: f32,
    pub max_reward: f32,
    /// Success rate over the last 100 episodes; NaN for tasks that report none.
    pub success_rate: f32,
}

/// A periodic evaluation of the deterministic policy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EvaluationPoint {
    pub timesteps: u64,
    pub mean_score: f32,
    /// NaN for tasks that report no success.
    pub success_rate: f32,
}

/// A 900 × 540 PNG drawn by `draw` on white, written atomically to `path`.
fn write_png(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    png(path, (900, 540), draw)
}

/// A PNG of `size` pixels drawn by `draw` on white, written atomically to `path`, with the
/// shipped font registered as "sans-serif": for figures of other crates.
pub fn png(
    path: &Path,
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    REGISTER.call_once(|| {
        // The font is compiled in; failing to parse it is a build defect the tests catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
    twinbots_api::files::write_through(path, |tmp| {
        let root = BitMapBackend::new(tmp, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present().map_err(|e| anyhow::anyhow!("{}: {e}", tmp.display()))?;
        Ok(())
    })
}

/// The series' legend, boxed, at `position`.
fn draw_legend<'a, X: Ranged, Y: Ranged>(
    chart: &mut ChartContext<'a, BitMapBackend<'a>, Cartesian2d<X, Y>>,
    position: SeriesLabelPosition,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .position(position)
        .draw()?;
    Ok(())
}

/// Draws mean episode reward (and its min–max band over the last 100 episodes) against
/// timesteps into `path`, written atomically, with the success rate on a second axis when the
/// task reports one, periodic evaluations as points, and the solved threshold on the axis its
/// criterion measures. Points without episodes yet (NaN) are skipped.
pub fn learning_curve(
    path: &Path,
    title: &str,
    points: &[CurvePoint],
    evaluations: &[EvaluationPoint],
    solved: Option<SolvedCriterion>,
) -> anyhow::Result<()> {
    let target = solved.filter(|c| c.measure == Measure::Score).map(|c| c.threshold);
    let success_target = solved.filter(|c| c.measure == Measure::Success).map(|c| c.threshold);
    let points: Vec<CurvePoint> = points.iter().copied().filter(|p| p.mean_reward.is_finite()).collect();
    write_png(path, |root| {
        let x_max = points.last().map_or(1, |p| p.timesteps).max(1) as f64;
        let mut y_max = points.iter().map(|p| p.max_reward).fold(1.0f32, f32::max);
        let mut y_min = points.iter().map(|p| p.min_reward).fold(0.0f32, f32::min);
        if let Some(t) = target {
            y_max = y_max.max(t);
            y_min = y_min.min(t);
        }
        let pad = (y_max - y_min).max(1.0) * 0.05;
        let successes: Vec<(f64, f64)> = points
            .iter()
            .filter(|p| p.success_rate.is_finite())
            .map(|p| (p.timesteps as f64, p.success_rate as f64))
            .collect();
        let evaluated_successes: Vec<(f64, f64)> = evaluations
            .iter()
            .filter(|e| e.success_rate.is_finite())
            .map(|e| (e.timesteps as f64, e.success_rate as f64))
            .collect();
        let evaluated_scores: Vec<(f64, f64)> = evaluations
            .iter()
            .filter(|e| e.mean_score.is_finite() && !e.success_rate.is_finite())
            .map(|e| (e.timesteps as f64, e.mean_score as f64))
            .collect();
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .right_y_label_area_size(if successes.is_empty() { 0 } else { 60 })
            .build_cartesian_2d(0f64..x_max, (y_min - pad) as f64..(y_max + pad) as f64)?
            .set_secondary_coord(0f64..x_max, 0f64..1.02f64);
        chart
            .configure_mesh()
            .x_desc("timesteps")
            .x_label_formatter(&steps_label)
            .y_desc("episode reward (last 100 episodes)")
            .label_style(("sans-serif", 14))
            .draw()?;
        let band: Vec<(f64, f64)> = points
            .iter()
            .map(|p| (p.timesteps as f64, p.max_reward as f64))
            .chain(points.iter().rev().map(|p| (p.timesteps as f64, p.min_reward as f64)))
            .collect();
        if !band.is_empty() {
            chart.draw_series(std::iter::once(Polygon::new(band, BLUE.mix(0.15))))?;
        }
        chart
            .draw_series(LineSeries::new(
                points.iter().map(|p| (p.timesteps as f64, p.mean_reward as f64)),
                BLUE.stroke_width(2),
            ))?
            .label("mean")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if let Some(t) = target {
            chart
                .draw_series(LineSeries::new([(0.0, t as f64), (x_max, t as f64)], RED.mix(0.7)))?
                .label("solved threshold")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        }
        if !evaluated_scores.is_empty() {
            chart
                .draw_series(evaluated_scores.iter().map(|&p| Circle::new(p, 4, BLACK.filled())))?
                .label("evaluation (deterministic)")
                .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
        }
        if !successes.is_empty() {
            chart
                .configure_secondary_axes()
                .y_desc("success rate (last 100 episodes)")
                .label_style(("sans-serif", 14))
                .draw()?;
            let green = RGBColor(0, 140, 60);
            chart
                .draw_secondary_series(LineSeries::new(successes, green.stroke_width(2)))?
                .label("success rate (training episodes)")
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], green.stroke_width(2)));
            if !evaluated_successes.is_empty() {
                chart.draw_secondary_series(LineSeries::new(evaluated_successes.clone(), green.mix(0.6)))?;
                chart
                    .draw_secondary_series(evaluated_successes.iter().map(move |&p| Circle::new(p, 4, green.filled())))?
                    .label("evaluation success rate (deterministic)")
                    .legend(move |(x, y)| Circle::new((x + 10, y), 4, green.filled()));
            }
            if let Some(t) = success_target {
                chart
                    .draw_secondary_series(LineSeries::new([(0.0, t as f64), (x_max, t as f64)], RED.mix(0.7)))?
                    .label("solved threshold (success rate)")
                    .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
            }
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        Ok(())
    })
}

/// Draws the training loss against timesteps into `path`, written atomically: the curve of a
/// learner that finishes no training episodes (behaviour cloning), with periodic evaluations'
/// success rates (or mean scores, for tasks without success) on a second axis.
pub fn loss_curve(
    path: &Path,
    title: &str,
    losses: &[(u64, f32)],
    evaluations: &[EvaluationPoint],
) -> anyhow::Result<()> {
    let losses: Vec<(f64, f64)> =
        losses.iter().filter(|(_, l)| l.is_finite()).map(|&(t, l)| (t as f64, l as f64)).collect();
    let successes = evaluations.iter().all(|e| e.success_rate.is_finite());
    let evaluated: Vec<(f64, f64)> = evaluations
        .iter()
        .map(|e| (e.timesteps as f64, if successes { e.success_rate } else { e.mean_score } as f64))
        .filter(|p| p.1.is_finite())
        .collect();
    write_png(path, |root| {
        let x_max = losses.iter().chain(&evaluated).map(|p| p.0).fold(1.0, f64::max);
        let y_max = losses.iter().map(|p| p.1).fold(1e-6, f64::max) * 1.05;
        let (e_min, e_max) = match successes {
            true => (0.0, 1.02),
            false => evaluated.iter().fold((0.0f64, 1.0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1))),
        };
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .right_y_label_area_size(if evaluated.is_empty() { 0 } else { 60 })
            .build_cartesian_2d(0f64..x_max, 0f64..y_max)?
            .set_secondary_coord(0f64..x_max, e_min..e_max);
        chart
            .configure_mesh()
            .x_desc("timesteps (demonstration frames learnt from)")
            .x_label_formatter(&steps_label)
            .y_desc("training loss")
            .label_style(("sans-serif", 14))
            .draw()?;
        chart
            .draw_series(LineSeries::new(losses.iter().copied(), BLUE.stroke_width(2)))?
            .label("loss")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if !evaluated.is_empty() {
            let what = if successes { "evaluation success rate" } else { "evaluation mean score" };
            chart.configure_secondary_axes().y_desc(what).label_style(("sans-serif", 14)).draw()?;
            let green = RGBColor(0, 140, 60);
            chart.draw_secondary_series(LineSeries::new(evaluated.clone(), green.mix(0.6)))?;
            chart
                .draw_secondary_series(evaluated.iter().map(move |&p| Circle::new(p, 4, green.filled())))?
                .label(format!("{what} (deterministic)"))
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, green.filled()));
        }
        draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        Ok(())
    })
}

/// Draws the median of several runs' curves and the band between their quartiles
/// ([`crate::seeds::band`] rows: x, q1, median, q3) into `path`, written atomically, each run's
/// own curve faint behind them, with the solved threshold when there is one.
pub fn seed_band(
    path: &Path,
    title: &str,
    y_label: &str,
    runs: &[Vec<(f64, f64)>],
    band: &[(f64, f64, f64, f64)],
    threshold: Option<f64>,
) -> anyhow::Result<()> {
    write_png(path, |root| {
        let x_max = band.last().map_or(1.0, |b| b.0).max(1.0);
        let ys = runs.iter().flatten().map(|p| p.1).chain(threshold);
        let (y_min, y_max) = ys.fold((0.0f64, 1.0f64), |(lo, hi), y| (lo.min(y), hi.max(y)));
        let pad = (y_max - y_min).max(1e-3) * 0.05;
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..x_max, (y_min - pad)..(y_max + pad))?;
        chart
            .configure_mesh()
            .x_desc("timesteps")
            .x_label_formatter(&steps_label)
            .y_desc(y_label)
            .label_style(("sans-serif", 14))
            .draw()?;
        for run in runs {
            chart.draw_series(LineSeries::new(run.iter().copied(), BLUE.mix(0.2)))?;
        }
        let area: Vec<(f64, f64)> =
            band.iter().map(|b| (b.0, b.3)).chain(band.iter().rev().map(|b| (b.0, b.1))).collect();
        if !area.is_empty() {
            chart
                .draw_series(std::iter::once(Polygon::new(area, BLUE.mix(0.2))))?
                .label("interquartile range over seeds")
                .legend(|(x, y)| Rectangle::new([(x, y - 5), (x + 20, y + 5)], BLUE.mix(0.2).filled()));
        }
        chart
            .draw_series(LineSeries::new(band.iter().map(|b| (b.0, b.2)), BLUE.stroke_width(2)))?
            .label(format!("median of {} runs", runs.len()))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if let Some(t) = threshold {
            chart
                .draw_series(LineSeries::new([(0.0, t), (x_max, t)], RED.mix(0.7)))?
                .label("solved threshold")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        }
        draw_legend(&mut chart, SeriesLabelPosition::LowerRight)?;
        Ok(())
    })
}

/// Labelled time series (x: seconds) into `path`, written atomically: one colour per label,
/// dashed grey lines at each of `levels` (a settling band) and a vertical one at each of
/// `marks` (when something happened). NaN points are skipped.
pub fn time_series(
    path: &Path,
    title: &str,
    y_label: &str,
    lines: &[(String, Vec<(f64, f64)>)],
    levels: &[f64],
    marks: &[f64],
) -> anyhow::Result<()> {
    write_png(path, |root| {
        let points = || lines.iter().flat_map(|(_, l)| l.iter()).filter(|p| p.1.is_finite());
        let x_max = points().map(|p| p.0).fold(1e-3, f64::max);
        let (y_min, y_max) = points()
            .map(|p| p.1)
            .chain(levels.iter().copied())
            .fold((f64::MAX, f64::MIN), |(lo, hi), y| (lo.min(y), hi.max(y)));
        let (y_min, y_max) = if y_min > y_max { (-1.0, 1.0) } else { (y_min, y_max) };
        let pad = (y_max - y_min).max(1e-6) * 0.05;
        let y_range = (y_min - pad)..(y_max + pad);
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0f64..x_max, y_range.clone())?;
        chart.configure_mesh().x_desc("time (s)").y_desc(y_label).label_style(("sans-serif", 14)).draw()?;
        let grey = BLACK.mix(0.35);
        for &level in levels {
            chart.draw_series(DashedLineSeries::new([(0.0, level), (x_max, level)], 6, 4, grey.into()))?;
        }
        for &mark in marks {
            chart.draw_series(DashedLineSeries::new(
                [(mark, y_range.start), (mark, y_range.end)],
                3,
                3,
                grey.into(),
            ))?;
        }
        for (i, (label, line)) in lines.iter().enumerate() {
            let colour = Palette99::pick(i).to_rgba();
            let finite = line.iter().copied().filter(|p| p.1.is_finite());
            chart
                .draw_series(LineSeries::new(finite, colour.stroke_width(2)))?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
        Ok(())
    })
}

/// A timesteps tick as people write it: 0, 750, 50k, 1.5M (plotters' default prints 450000.0).
fn steps_label(x: &f64) -> String {
    let short =
        |v: f64, unit: &str| if v.fract().abs() < 1e-9 { format!("{v:.0}{unit}") } else { format!("{v:.1}{unit}") };
    match x.abs() {
        a if a >= 1e6 => short(x / 1e6, "M"),
        a if a >= 1e3 => short(x / 1e3, "k"),
        _ => format!("{x:.0}"),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn timesteps_ticks_read_as_people_write_them() {
        let labels: Vec<String> = [0.0, 750.0, 50_000.0, 450_000.0, 12_500.0, 1_500_000.0, 3_000_000.0]
            .iter()
            .map(super::steps_label)
            .collect();
        assert_eq!(labels, ["0", "750", "50k", "450k", "12.5k", "1.5M", "3M"]);
    }
}
