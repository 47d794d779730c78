//! TensorBoard logs of a run, under Stable-Baselines3's tag names so that SB3 runs and twinbots
//! runs compare on one board. The tags are listed in docs/export.md.

use std::time::Instant;

use super::{Callback, Flow};
use crate::agent::Agent;
use crate::evaluation::EvalResult;
use crate::stats::UpdateStats;
use crate::tensorboard::EventWriter;

/// After every update, one point of each training scalar at the run's timestep count (SB3's
/// x axis): `rollout/` (the last 100 training episodes: reward, length, success and the task's
/// figures), `train/` (the update's losses, KL, clip fraction, learning rate, Gaussian σ) and
/// `time/fps`.
pub struct TensorBoardCallback {
    events: EventWriter,
    /// When, and at which timestep count, this process's training began (for `time/fps`,
    /// as SB3 counts it).
    started: Option<(Instant, u64)>,
}

impl TensorBoardCallback {
    pub fn new(events: EventWriter) -> Self {
        Self { events, started: None }
    }
}

impl Callback for TensorBoardCallback {
    fn on_training_start(&mut self, model: &dyn Agent) -> anyhow::Result<()> {
        self.started = Some((Instant::now(), model.timesteps()));
        // A resumed run logs again what came after its checkpoint: TensorBoard drops points
        // from this step on that an earlier file holds.
        self.events.session_start(model.timesteps() + 1)
    }

    fn on_update(&mut self, stats: &UpdateStats, model: &dyn Agent) -> anyhow::Result<Flow> {
        let mut scalars = training_scalars(stats, model);
        if let Some((since, timesteps)) = self.started {
            let fps = (stats.timesteps - timesteps) as f64 / since.elapsed().as_secs_f64().max(1e-9);
            scalars.push(("time/fps".into(), fps as f32));
        }
        self.events.scalars(stats.timesteps, &scalars)?;
        Ok(Flow::Continue)
    }
}

/// The `rollout/` and `train/` scalars of an update: the episodes' figures, then the
/// algorithm's own tags, the learning rate and skipped gradient steps.
pub fn training_scalars(s: &UpdateStats, model: &dyn Agent) -> Vec<(String, f32)> {
    let mut out: Vec<(String, f32)> = vec![
        ("rollout/ep_rew_mean".into(), s.mean_reward),
        ("rollout/ep_len_mean".into(), s.mean_length),
        ("rollout/success_rate".into(), s.success_rate),
    ];
    out.extend(model.train_scalars(s));
    out.push(("train/learning_rate".into(), s.learning_rate as f32));
    out.push(("train/skipped_gradient_steps".into(), s.skipped_steps as f32));
    out.extend(model.history().metric_means().into_iter().map(|(name, v)| (format!("rollout/{name}"), v)));
    out
}

/// The `eval/` scalars of an evaluation (SB3's `EvalCallback` tags, and the task's figures).
pub fn evaluation_scalars(result: &EvalResult) -> Vec<(String, f32)> {
    let mut out: Vec<(String, f32)> =
        vec![("eval/mean_reward".into(), result.mean_score), ("eval/mean_ep_length".into(), result.mean_length)];
    if let Some(rate) = result.success_rate {
        out.push(("eval/success_rate".into(), rate));
    }
    out.extend(result.metrics.iter().map(|(name, v)| (format!("eval/{name}"), *v)));
    out
}
