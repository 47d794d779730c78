//! TensorBoard logs of a run, under Stable-Baselines3's tag names so that SB3 runs and twinbots
//! runs compare on one board. The tags are listed in docs/export.md.

use std::time::Instant;

use super::{Callback, Flow};
use crate::evaluation::EvalResult;
use crate::ppo::{Ppo, UpdateStats};
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
    fn on_training_start(&mut self, model: &Ppo) -> anyhow::Result<()> {
        self.started = Some((Instant::now(), model.timesteps));
        // A resumed run logs again what came after its checkpoint: TensorBoard drops points
        // from this step on that an earlier file holds.
        self.events.session_start(model.timesteps + 1)
    }

    fn on_update(&mut self, stats: &UpdateStats, model: &Ppo) -> anyhow::Result<Flow> {
        let mut scalars = training_scalars(stats, model);
        if let Some((since, timesteps)) = self.started {
            let fps = (stats.timesteps - timesteps) as f64 / since.elapsed().as_secs_f64().max(1e-9);
            scalars.push(("time/fps".into(), fps as f32));
        }
        self.events.scalars(stats.timesteps, &scalars)?;
        Ok(Flow::Continue)
    }
}

/// The `rollout/` and `train/` scalars of an update.
pub fn training_scalars(s: &UpdateStats, model: &Ppo) -> Vec<(String, f32)> {
    let c = &model.config;
    // SB3's loss, L_clip − c_ent·H + c_V·L_V, here averaged over the update's minibatches
    // (SB3 logs its last minibatch's).
    let loss = s.policy_loss - c.ent_coef * s.entropy + c.vf_coef * s.value_loss;
    let mut out: Vec<(String, f32)> = vec![
        ("rollout/ep_rew_mean".into(), s.mean_reward),
        ("rollout/ep_len_mean".into(), s.mean_length),
        ("rollout/success_rate".into(), s.success_rate),
        ("train/loss".into(), loss),
        ("train/policy_gradient_loss".into(), s.policy_loss),
        ("train/value_loss".into(), s.value_loss),
        ("train/entropy_loss".into(), -s.entropy),
        ("train/approx_kl".into(), s.approx_kl),
        ("train/clip_fraction".into(), s.clip_fraction),
        ("train/learning_rate".into(), s.learning_rate as f32),
        ("train/skipped_gradient_steps".into(), s.skipped_steps as f32),
    ];
    if let Some(std) = gaussian_std(model) {
        out.push(("train/std".into(), std));
    }
    out.extend(model.recent_metric_means().into_iter().map(|(name, v)| (format!("rollout/{name}"), v)));
    out
}

/// The mean σ of a Gaussian policy (SB3's `train/std`); `None` for discrete actions.
fn gaussian_std(model: &Ppo) -> Option<f32> {
    let (_, log_std) = model.policy.named_vars().into_iter().find(|(name, _)| name == "log_std")?;
    let values = log_std.as_tensor().to_vec1::<f32>().ok()?;
    Some(values.iter().map(|l| l.exp()).sum::<f32>() / values.len().max(1) as f32)
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
