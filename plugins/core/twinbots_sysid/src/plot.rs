//! PNG figures: twin against log per joint, and a fit's convergence.

use std::path::Path;
use std::sync::Once;

use plotters::prelude::*;

use crate::search::Generation;
use crate::replay::PreparedLog;
use crate::rig::{Rig, Trajectory};

static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

fn register_font() {
    REGISTER.call_once(|| {
        // Compiled in; a font that does not parse is a build defect the tests catch.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// Writes a PNG through `draw`, atomically.
fn write_png(path: &Path, size: (u32, u32), draw: impl FnOnce(&DrawingArea<BitMapBackend, plotters::coord::Shift>) -> anyhow::Result<()>) -> anyhow::Result<()> {
    register_font();
    let tmp = path.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, size).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
    }
    std::fs::rename(&tmp, path)?;
    Ok(())
}

/// One panel per joint: the logged position and each labelled twin's, against time.
pub fn replay_png(path: &Path, rig: &Rig, log: &PreparedLog, twins: &[(&str, &Trajectory, Vec<f64>)]) -> anyhow::Result<()> {
    let rows = rig.joints.len();
    write_png(path, (1000, 220 * rows as u32 + 40), |root| {
        let root = root.titled(&format!("{}: twin vs log ({})", rig.robot, log.name), ("sans-serif", 20))?;
        let dt = rig.dt();
        let colours = [RED, BLUE, GREEN];
        for (j, area) in root.split_evenly((rows, 1)).iter().enumerate() {
            let logged: Vec<(f64, f64)> = log.reference.iter().enumerate().map(|(k, r)| ((k + 1) as f64 * dt, r.position[j] as f64)).collect();
            let twin_series: Vec<Vec<(f64, f64)>> = twins
                .iter()
                .map(|(_, t, bias)| t.steps.iter().enumerate().map(|(k, r)| ((k + 1) as f64 * dt, r.position[j] as f64 + bias[j])).collect())
                .collect();
            let all = logged.iter().chain(twin_series.iter().flatten()).map(|p| p.1);
            let (lo, hi) = all.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
            let pad = ((hi - lo) * 0.05).max(1e-3);
            let t_max = logged.last().map_or(1.0, |p| p.0);
            let mut chart = ChartBuilder::on(area)
                .margin(6)
                .x_label_area_size(24)
                .y_label_area_size(60)
                .caption(&rig.joints[j], ("sans-serif", 14))
                .build_cartesian_2d(0.0..t_max, (lo - pad)..(hi + pad))?;
            chart.configure_mesh().x_desc("s").label_style(("sans-serif", 11)).draw()?;
            chart
                .draw_series(LineSeries::new(logged, BLACK.stroke_width(2)))?
                .label("log")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(2)));
            for ((label, _, _), (series, colour)) in twins.iter().zip(twin_series.into_iter().zip(colours.iter().cycle())) {
                let colour = *colour;
                chart
                    .draw_series(LineSeries::new(series, colour.stroke_width(1)))?
                    .label(*label)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            }
            chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).label_font(("sans-serif", 11)).draw()?;
        }
        Ok(())
    })
}

/// The best and mean tracking error of every generation (log scale), and the nominal twin's.
pub fn convergence_png(path: &Path, title: &str, history: &[Generation], nominal: f64) -> anyhow::Result<()> {
    write_png(path, (900, 540), |root| {
        let values = history.iter().flat_map(|g| [g.best, g.mean, g.best_so_far]).chain([nominal]).filter(|v| v.is_finite() && *v > 0.0);
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| (a.min(y), b.max(y)));
        let (lo, hi) = if lo.is_finite() { (lo * 0.8, hi * 1.25) } else { (1e-3, 1.0) };
        let x_max = history.len().max(2) as f64;
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0..x_max, (lo..hi).log_scale())?;
        chart.configure_mesh().x_desc("generation").y_desc("tracking error (weighted)").label_style(("sans-serif", 13)).draw()?;
        let line = |f: fn(&Generation) -> f64| history.iter().map(move |g| ((g.generation + 1) as f64, f(g))).collect::<Vec<_>>();
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
        chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).label_font(("sans-serif", 13)).draw()?;
        Ok(())
    })
}
