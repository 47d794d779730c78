//! Callbacks that record a run as it goes: `progress.csv`, checkpoints, the learning curve and
//! the terminal's progress bar.

use indicatif::{ProgressBar, ProgressStyle};

use super::{Callback, Flow};
use crate::plot::{self, CurvePoint, EvaluationPoint};
use crate::ppo::{Ppo, UpdateStats};
use crate::run_dir::{LEARNING_CURVE, RunDir};
use crate::task::SolvedCriterion;

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
    fn on_training_start(&mut self, _model: &Ppo) -> anyhow::Result<()> {
        self.run.check_progress_columns()
    }

    fn on_update(&mut self, stats: &UpdateStats, _model: &Ppo) -> anyhow::Result<Flow> {
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
    fn on_update(&mut self, stats: &UpdateStats, model: &Ppo) -> anyhow::Result<Flow> {
        if stats.update % self.every == 0 {
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
    let curve: Vec<CurvePoint> = run
        .read_progress()?
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
        .map(|e| EvaluationPoint { timesteps: e.timesteps, mean_score: e.mean_score, success_rate: e.success_rate.unwrap_or(f32::NAN) })
        .collect();
    plot::learning_curve(&run.file(LEARNING_CURVE), title, &curve, &evaluations, solved)
}

impl Callback for LearningCurveCallback {
    fn on_update(&mut self, stats: &UpdateStats, _model: &Ppo) -> anyhow::Result<Flow> {
        if stats.update % self.every == 0 {
            self.draw()?;
        }
        Ok(Flow::Continue)
    }

    fn on_training_end(&mut self, _model: &Ppo) -> anyhow::Result<()> {
        self.draw()
    }
}

/// A progress bar over the run's budget with steps/s and the latest mean reward (SB3's
/// `ProgressBarCallback`).
pub struct ProgressBarCallback {
    bar: ProgressBar,
    total: u64,
}

impl ProgressBarCallback {
    /// A bar towards `total` timesteps (the whole run's, so a resumed run starts part-way).
    pub fn new(total: u64) -> anyhow::Result<Self> {
        let bar = ProgressBar::new(total);
        bar.set_style(ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} steps {msg}")?.progress_chars("=> "));
        Ok(Self { bar, total })
    }
}

impl Callback for ProgressBarCallback {
    fn on_training_start(&mut self, model: &Ppo) -> anyhow::Result<()> {
        self.bar.set_position(model.timesteps.min(self.total));
        Ok(())
    }

    fn on_update(&mut self, s: &UpdateStats, _model: &Ppo) -> anyhow::Result<Flow> {
        self.bar.set_position(s.timesteps.min(self.total));
        let success = if s.success_rate.is_finite() { format!(", success {:.0} %", 100.0 * s.success_rate) } else { String::new() };
        self.bar.set_message(format!("{:.0} steps/s, mean reward {:.1}{success} ({} episodes)", s.steps_per_s, s.mean_reward, s.episodes));
        Ok(Flow::Continue)
    }

    fn on_training_end(&mut self, _model: &Ppo) -> anyhow::Result<()> {
        self.bar.finish();
        Ok(())
    }
}
