//! A cell study's figures as PNG: a factor's effect on cycle time (bars per level and
//! controller), success as a heat map (layouts × failure scenarios), where the arm reaches over
//! the table, and the program's time per phase.

use std::path::Path;

use plotters::prelude::*;
use twinbots_learn::plot::png;
use twinbots_task::cell::layout::{CellLayout, FIXTURE_HALF};

/// Grouped bars: for each category (a factor's level), one bar per series (a controller);
/// `None` draws no bar (nothing to average: no successful episode).
pub fn grouped_bars(
    path: &Path,
    title: &str,
    y_label: &str,
    categories: &[String],
    series: &[(String, Vec<Option<f64>>)],
) -> anyhow::Result<()> {
    png(path, (900, 540), |root| {
        let top = series.iter().flat_map(|(_, v)| v.iter().flatten()).fold(1e-6f64, |m, &v| m.max(v)) * 1.15;
        let n = categories.len().max(1);
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(50)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0f64..top)?;
        // Ticks at whole numbers: each group of bars centred on its category's.
        let label = |x: &f64| {
            if (x - x.round()).abs() < 1e-6 && *x >= 0.0 {
                categories.get(x.round() as usize).cloned().unwrap_or_default()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(n + 1)
            .x_label_formatter(&label)
            .y_desc(y_label)
            .label_style(("sans-serif", 14))
            .draw()?;
        let width = 0.8 / series.len().max(1) as f64;
        for (s, (label, values)) in series.iter().enumerate() {
            let colour = Palette99::pick(s).to_rgba();
            let bars = values.iter().enumerate().filter_map(|(c, v)| {
                let x = c as f64 - 0.4 + s as f64 * width;
                v.map(|v| Rectangle::new([(x, 0.0), (x + width * 0.9, v)], colour.filled()))
            });
            chart
                .draw_series(bars)?
                .label(label.clone())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], colour.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()?;
        Ok(())
    })
}

/// A heat map of values in [0, 1] (success rates): `rows` × `columns`, each cell labelled with
/// its value as a percentage; `None` cells stay grey.
pub fn heat_map(
    path: &Path,
    title: &str,
    rows: &[String],
    columns: &[String],
    values: &[Vec<Option<f64>>],
) -> anyhow::Result<()> {
    let size = (220 + 150 * columns.len() as u32, 120 + 60 * rows.len() as u32);
    png(path, size, |root| {
        let root = root.titled(title, ("sans-serif", 22))?;
        let (label_w, label_h) = (200i32, 40i32);
        let (w, h) = root.dim_in_pixel();
        let cell_w = (w as i32 - label_w - 20) / columns.len().max(1) as i32;
        let cell_h = (h as i32 - label_h - 20) / rows.len().max(1) as i32;
        let text = |s: &str| Text::new(s.to_string(), (0, 0), ("sans-serif", 15).into_font());
        for (c, name) in columns.iter().enumerate() {
            root.draw(&(EmptyElement::at((label_w + c as i32 * cell_w + 8, 10)) + text(name)))?;
        }
        for (r, name) in rows.iter().enumerate() {
            let y = label_h + r as i32 * cell_h;
            root.draw(&(EmptyElement::at((8, y + cell_h / 2 - 8)) + text(name)))?;
            for c in 0..columns.len() {
                let x = label_w + c as i32 * cell_w;
                let value = values.get(r).and_then(|row| row.get(c)).copied().flatten();
                // Red (0) through yellow to green (1).
                let colour = match value {
                    Some(v) => HSLColor(v.clamp(0.0, 1.0) / 3.0, 0.7, 0.55).to_rgba(),
                    None => RGBAColor(200, 200, 200, 1.0),
                };
                root.draw(&Rectangle::new([(x, y), (x + cell_w - 2, y + cell_h - 2)], colour.filled()))?;
                let label = value.map_or("—".to_string(), |v| format!("{:.0} %", 100.0 * v));
                root.draw(&(EmptyElement::at((x + cell_w / 2 - 20, y + cell_h / 2 - 8)) + text(&label)))?;
            }
        }
        Ok(())
    })
}

/// Where the arm reaches over the table: the grid's cells (cell frame, x and y) green where
/// `reach` holds, grey where not; the robot's base and the fixtures drawn on top.
pub fn reach_map(path: &Path, title: &str, layout: &CellLayout, step: f32, reach: &[Vec<bool>]) -> anyhow::Result<()> {
    let t = &layout.table;
    let (x0, y0) = (t.centre[0] - t.size[0] / 2.0, t.centre[1] - t.size[1] / 2.0);
    let (x1, y1) = (x0 + t.size[0], y0 + t.size[1]);
    png(path, (760, 700), |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(f64::from(x0)..f64::from(x1), f64::from(y0)..f64::from(y1))?;
        chart.configure_mesh().disable_mesh().x_desc("x (m)").y_desc("y (m)").label_style(("sans-serif", 14)).draw()?;
        let cells = reach.iter().enumerate().flat_map(|(i, column)| {
            column.iter().enumerate().map(move |(j, &ok)| {
                let (x, y) = (f64::from(x0 + i as f32 * step), f64::from(y0 + j as f32 * step));
                let colour = if ok { RGBAColor(90, 180, 90, 0.55) } else { RGBAColor(150, 150, 150, 0.35) };
                Rectangle::new([(x, y), (x + f64::from(step), y + f64::from(step))], colour.filled())
            })
        });
        chart.draw_series(cells)?;
        let base = layout.robot.position.map(f64::from);
        chart
            .draw_series(std::iter::once(Circle::new((base[0], base[1]), 12, BLACK.filled())))?
            .label("robot base")
            .legend(|(x, y)| Circle::new((x + 6, y), 5, BLACK.filled()));
        for (name, fixture, colour) in [("pick fixture", &layout.pick, BLUE), ("place fixture", &layout.place, RED)] {
            let [x, y] = fixture.position.map(f64::from);
            let h = f64::from(FIXTURE_HALF);
            chart
                .draw_series(std::iter::once(Rectangle::new([(x - h, y - h), (x + h, y + h)], colour.stroke_width(3))))?
                .label(name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], colour.stroke_width(3)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()?;
        Ok(())
    })
}

/// Stacked horizontal bars: per row (a controller in a layout), the mean seconds of each phase.
pub fn phases(path: &Path, title: &str, phases: &[&str], rows: &[(String, Vec<f64>)]) -> anyhow::Result<()> {
    // Room for the legend's nine entries beside the bars.
    let height = (140 + 50 * rows.len() as u32).max(330);
    png(path, (1000, height), |root| {
        let total = rows.iter().map(|(_, p)| p.iter().sum::<f64>()).fold(1e-6, f64::max) * 1.3;
        let n = rows.len().max(1);
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(260)
            .build_cartesian_2d(0f64..total, -0.5f64..n as f64 - 0.5)?;
        let label = |y: &f64| {
            if (y - y.round()).abs() < 1e-6 && *y >= 0.0 {
                rows.get(y.round() as usize).map(|r| r.0.clone()).unwrap_or_default()
            } else {
                String::new()
            }
        };
        chart
            .configure_mesh()
            .disable_y_mesh()
            .y_labels(n + 1)
            .y_label_formatter(&label)
            .x_desc("mean time of a successful cycle (s)")
            .label_style(("sans-serif", 14))
            .draw()?;
        for (p, name) in phases.iter().enumerate() {
            let colour = Palette99::pick(p).to_rgba();
            let bars = rows.iter().enumerate().map(|(r, (_, times))| {
                let start: f64 = times[..p].iter().sum();
                Rectangle::new([(start, r as f64 - 0.35), (start + times[p], r as f64 + 0.35)], colour.filled())
            });
            chart
                .draw_series(bars)?
                .label(*name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], colour.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()?;
        Ok(())
    })
}
