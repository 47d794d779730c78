//! Callbacks that record a run as it goes: `progress.csv`, checkpoints, the learning curve and
//! the progress shown to people (a bar on a terminal, lines in a log).

use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use super::{Callback, Flow};
use crate::agent::Agent;
use crate::plot::{self, CurvePoint, EvaluationPoint};
use crate::run_dir::{LEARNING_CURVE, RunDir};
use crate::stats::UpdateStats;
use twinbots_api::SolvedCriterion;

/// Appends every update's row to the run's `progress.csv` (SB3's CSV logger).
pub struct ProgressCsvCallback {
    run: RunDir,
}

impl ProgressCsvCallback {
    pub fn new(run: RunDir) -> Self {
        Self { run }
    }
}

impl Callback for ProgressCsvCallback {
    fn on_training_start(&mut self, model: &dyn Agent) -> anyhow::Result<()> {
        self.run.check_progress_columns(model.train_figures())
    }

    fn on_update(&mut self, stats: &UpdateStats, _model: &dyn Agent) -> anyhow::Result<Flow> {
        self.run.append_progress(stats)?;
        Ok(Flow::Continue)
    }
}

/// Saves a checkpoint of the model every `every` updates (SB3's `CheckpointCallback`), each
/// complete or absent (see `RunDir::save_checkpoint`).
pub struct CheckpointCallback {
    run: RunDir,
    every: usize,
}

impl CheckpointCallback {
    pub fn new(run: RunDir, every: usize) -> Self {
        Self { run, every: every.max(1) }
    }
}

impl Callback for CheckpointCallback {
    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        if stats.update.is_multiple_of(self.every) {
            self.run.save_checkpoint(model)?;
        }
        Ok(Flow::Continue)
    }
}

/// Redraws the run's `learning_curve.png` from its `progress.csv` and `evaluations.csv` every
/// `every` updates and when training ends. Place it after the callbacks that write those.
pub struct LearningCurveCallback {
    run: RunDir,
    title: String,
    solved: Option<SolvedCriterion>,
    every: usize,
}

impl LearningCurveCallback {
    pub fn new(run: RunDir, title: String, solved: Option<SolvedCriterion>, every: usize) -> Self {
        Self { run, title, solved, every: every.max(1) }
    }

    fn draw(&self) -> anyhow::Result<()> {
        draw_learning_curve(&self.run, &self.title, self.solved)
    }
}

/// Draws `run`'s learning curve from its `progress.csv` and `evaluations.csv`.
pub fn draw_learning_curve(run: &RunDir, title: &str, solved: Option<SolvedCriterion>) -> anyhow::Result<()> {
    let progress = run.read_progress()?;
    let curve: Vec<CurvePoint> = progress
        .iter()
        .map(|s| CurvePoint {
            timesteps: s.timesteps,
            mean_reward: s.mean_reward,
            min_reward: s.min_reward,
            max_reward: s.max_reward,
            success_rate: s.success_rate,
        })
        .collect();
    let evaluations: Vec<EvaluationPoint> = run
        .read_evaluations()?
        .iter()
        .map(|e| EvaluationPoint {
            timesteps: e.timesteps,
            mean_score: e.mean_score,
            success_rate: e.success_rate.unwrap_or(f32::NAN),
        })
        .collect();
    // A learner that steps no env (behaviour cloning) has no episodes to draw: its loss instead.
    if progress.iter().all(|s| s.episodes == 0) && progress.iter().any(|s| s.train("loss").is_finite()) {
        let losses: Vec<(u64, f32)> = progress.iter().map(|s| (s.timesteps, s.train("loss"))).collect();
        return plot::loss_curve(&run.file(LEARNING_CURVE), title, &losses, &evaluations);
    }
    plot::learning_curve(&run.file(LEARNING_CURVE), title, &curve, &evaluations, solved)
}

impl Callback for LearningCurveCallback {
    fn on_update(&mut self, stats: &UpdateStats, _model: &dyn Agent) -> anyhow::Result<Flow> {
        if stats.update.is_multiple_of(self.every) {
            self.draw()?;
        }
        Ok(Flow::Continue)
    }

    fn on_training_end(&mut self, _model: &dyn Agent) -> anyhow::Result<()> {
        self.draw()
    }
}

/// Training's progress for people: on a terminal, a bar over the run's budget with steps/s and
/// the latest mean reward (SB3's `ProgressBarCallback`); elsewhere (a log file, CI, a pipe),
/// one line on stderr after the first update, every [`LINE_EVERY`] and at the end, as SB3's
/// stdout logger does.
pub struct ProgressBarCallback {
    display: Display,
    total: u64,
}

/// How often the line display writes while training goes on.
pub const LINE_EVERY: Duration = Duration::from_secs(10);

enum Display {
    Bar(ProgressBar),
    Lines { started: Instant, last: Option<Instant>, latest: Option<String> },
}

impl ProgressBarCallback {
    /// Progress towards `total` timesteps (the whole run's, so a resumed run starts part-way):
    /// a bar when stderr is a terminal, lines otherwise.
    pub fn new(total: u64) -> anyhow::Result<Self> {
        if std::io::stderr().is_terminal() { Self::bar(total) } else { Ok(Self::lines(total)) }
    }

    pub fn bar(total: u64) -> anyhow::Result<Self> {
        let bar = ProgressBar::new(total);
        bar.set_style(
            ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} steps {msg}")?.progress_chars("=> "),
        );
        Ok(Self { display: Display::Bar(bar), total })
    }

    pub fn lines(total: u64) -> Self {
        Self { display: Display::Lines { started: Instant::now(), last: None, latest: None }, total }
    }
}

/// An update's figures in a few words: what the bar shows beside it, and the core of a line.
fn progress_message(s: &UpdateStats) -> String {
    let success =
        if s.success_rate.is_finite() { format!(", success {:.0} %", 100.0 * s.success_rate) } else { String::new() };
    if s.episodes == 0 && !s.train.is_empty() {
        // A learner that steps no env (behaviour cloning): its own figures say how it goes.
        let figures: Vec<String> = s.train.iter().map(|(name, value)| format!("{name} {value:.4}")).collect();
        return format!("{:.0} steps/s, {}", s.steps_per_s, figures.join(", "));
    }
    format!("{:.0} steps/s, mean reward {:.1}{success} ({} episodes)", s.steps_per_s, s.mean_reward, s.episodes)
}

impl Callback for ProgressBarCallback {
    fn on_training_start(&mut self, model: &dyn Agent) -> anyhow::Result<()> {
        match &mut self.display {
            Display::Bar(bar) => bar.set_position(model.timesteps().min(self.total)),
            Display::Lines { started, .. } => *started = Instant::now(),
        }
        Ok(())
    }

    fn on_update(&mut self, s: &UpdateStats, _model: &dyn Agent) -> anyhow::Result<Flow> {
        match &mut self.display {
            Display::Bar(bar) => {
                bar.set_position(s.timesteps.min(self.total));
                bar.set_message(progress_message(s));
            }
            Display::Lines { started, last, latest } => {
                let line = format!(
                    "[{:.0} s] steps {}/{}: {}",
                    started.elapsed().as_secs_f64(),
                    s.timesteps,
                    self.total,
                    progress_message(s)
                );
                if last.is_none_or(|t| t.elapsed() >= LINE_EVERY) {
                    eprintln!("{line}");
                    *last = Some(Instant::now());
                    *latest = None;
                } else {
                    *latest = Some(line);
                }
            }
        }
        Ok(Flow::Continue)
    }

    fn on_training_end(&mut self, _model: &dyn Agent) -> anyhow::Result<()> {
        match &mut self.display {
            Display::Bar(bar) => bar.finish(),
            // The last update's line, if it has not been written yet.
            Display::Lines { latest, .. } => {
                if let Some(line) = latest.take() {
                    eprintln!("{line}");
                }
            }
        }
        Ok(())
    }
}
