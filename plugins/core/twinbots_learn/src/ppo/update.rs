//! One PPO update: the clipped surrogate objective optimised for `n_epochs` over shuffled
//! minibatches of a rollout whose advantages are computed, and the learning-rate schedule.

use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use rand::seq::SliceRandom;

use super::{ActorCritic, Ppo, RolloutBuffer, TRAIN_FIGURES, UpdateStats};
use crate::stats::figures;
use crate::nn::{Adam, AdamConfig};
use twinbots_api::spaces::Space;

/// The loss of one minibatch and what an update reports about it.
pub(super) struct MinibatchLoss {
    /// L = L_clip − c_ent H + c_V L_V, to minimise.
    pub loss: Tensor,
    pub policy_loss: Tensor,
    pub value_loss: Tensor,
    pub entropy: Tensor,
    /// log π(a|s) − log π_old(a|s) per sample.
    pub log_ratio: Tensor,
}

impl Ppo {
    /// Sets the learning rate for the next update of a run that ends at `end_timesteps`:
    /// constant, or with `linear_lr` SB3's linear schedule, lr × (1 − timesteps / end), a
    /// function of total timesteps so that a resumed run continues where it was.
    pub fn update_learning_rate(&mut self, end_timesteps: u64) {
        if self.config.linear_lr {
            let progress = self.timesteps as f64 / end_timesteps.max(1) as f64;
            self.optimizer.set_learning_rate(self.config.learning_rate * (1.0 - progress).clamp(0.0, 1.0));
        }
    }

    /// One PPO update on `buffer`, whose advantages are computed. `collecting_since` is when
    /// collecting it began: the update's row reports the samples per second since then.
    pub fn train(&mut self, buffer: &RolloutBuffer, collecting_since: Instant) -> anyhow::Result<UpdateStats> {
        self.updates += 1;
        let losses = self.optimize(buffer)?;
        if losses.skipped_steps > 0 {
            eprintln!(
                "update {}: {} gradient step(s) skipped: the loss or a gradient was not finite (NaN or infinity)",
                self.updates, losses.skipped_steps
            );
        }
        Ok(UpdateStats {
            learning_rate: self.optimizer.learning_rate(),
            steps_per_s: buffer.len() as f32 / collecting_since.elapsed().as_secs_f32(),
            skipped_steps: losses.skipped_steps,
            applied_steps: losses.applied_steps,
            train: losses.train,
            ..self.history.row(self.updates, self.timesteps, self.episodes)
        })
    }

    /// n_epochs over shuffled minibatches; returns the mean losses (the rest of the row is
    /// left at its default).
    fn optimize(&mut self, buffer: &RolloutBuffer) -> anyhow::Result<UpdateStats> {
        let c = self.config.clone();
        let mut indices: Vec<usize> = (0..buffer.len()).collect();
        let (mut pg_sum, mut v_sum, mut ent_sum, mut kl_sum, mut clip_sum, mut batches) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut skipped = 0;
        'epochs: for _ in 0..c.n_epochs {
            indices.shuffle(&mut self.rng);
            for chunk in indices.chunks(c.batch_size) {
                let mb = self.minibatch_loss(buffer, chunk)?;
                // A non-finite loss or gradient (e.g. from a poisoned reward) changes nothing and
                // is counted: one bad sample must not end a run's learning silently.
                if !self.optimizer.step(&mb.loss.backward()?, Some(c.max_grad_norm))?.applied {
                    skipped += 1;
                    continue;
                }

                let log_ratio = mb.log_ratio.to_vec1::<f32>()?;
                let n = log_ratio.len().max(1) as f32;
                // approx KL (Schulman's k3 estimator): E[(r - 1) - log r]
                let approx_kl = log_ratio.iter().map(|&l| l.exp() - 1.0 - l).sum::<f32>() / n;
                let clipped = log_ratio.iter().filter(|&&l| (l.exp() - 1.0).abs() > c.clip_range).count() as f32 / n;
                pg_sum += mb.policy_loss.to_scalar::<f32>()?;
                v_sum += mb.value_loss.to_scalar::<f32>()?;
                ent_sum += mb.entropy.to_scalar::<f32>()?;
                kl_sum += approx_kl;
                clip_sum += clipped;
                batches += 1.0;
                if let Some(target) = c.target_kl
                    && approx_kl > 1.5 * target
                {
                    break 'epochs;
                }
            }
        }
        let applied_steps = batches as usize;
        // No applied step: the losses are unknown, not zero.
        let batches = if batches == 0.0 { f32::NAN } else { batches };
        Ok(UpdateStats {
            // In the order of `TRAIN_FIGURES`.
            train: figures(TRAIN_FIGURES, &[pg_sum / batches, v_sum / batches, ent_sum / batches, kl_sum / batches, clip_sum / batches]),
            skipped_steps: skipped,
            applied_steps,
            ..Default::default()
        })
    }

    /// The PPO loss of the samples `chunk` of `buffer` under the current policy.
    pub(super) fn minibatch_loss(&self, buffer: &RolloutBuffer, chunk: &[usize]) -> anyhow::Result<MinibatchLoss> {
        let c = &self.config;
        let dev = Device::Cpu;
        let b = chunk.len();
        let (obs_dim, act_dim) = (buffer.obs_dim, buffer.act_dim);
        let gather = |src: &[f32], width: usize| -> Vec<f32> {
            chunk.iter().flat_map(|&i| src[i * width..(i + 1) * width].iter().copied()).collect()
        };
        // The observations as the policy saw them when it acted (the buffer holds them normalised).
        let obs = Tensor::from_vec(gather(&buffer.obs, obs_dim), (b, obs_dim), &dev)?;
        let actions = Tensor::from_vec(gather(&buffer.actions, act_dim), (b, act_dim), &dev)?;
        let actions = if act_dim == 1 && matches!(self.action_space, Space::Discrete { .. }) {
            actions.squeeze(1)?
        } else {
            actions
        };
        let old_log_prob = Tensor::from_vec(gather(&buffer.log_probs, 1), b, &dev)?;
        let returns = Tensor::from_vec(gather(&buffer.returns, 1), b, &dev)?;
        let mut adv = gather(&buffer.advantages, 1);
        if c.normalize_advantage && b > 1 {
            let m = adv.iter().sum::<f32>() / b as f32;
            let s = (adv.iter().map(|a| (a - m).powi(2)).sum::<f32>() / (b - 1) as f32).sqrt();
            adv.iter_mut().for_each(|a| *a = (*a - m) / (s + 1e-8));
        }
        let adv = Tensor::from_vec(adv, b, &dev)?;

        let eval = self.policy.evaluate(&obs, &actions)?;
        // ratio = π(a|s) / π_old(a|s)
        let log_ratio = (&eval.log_prob - &old_log_prob)?;
        let ratio = log_ratio.exp()?;
        // L_clip = E[min(r A, clip(r, 1-ε, 1+ε) A)]; we minimise its negative.
        let surr1 = (&ratio * &adv)?;
        let surr2 = (ratio.clamp(1.0 - c.clip_range, 1.0 + c.clip_range)? * &adv)?;
        let policy_loss = surr1.minimum(&surr2)?.mean_all()?.neg()?;
        // L_V = E[(V(s) - R)^2]   (SB3's MSE, no value clipping)
        let value_loss = (&eval.value - &returns)?.sqr()?.mean_all()?;
        let entropy = eval.entropy.mean_all()?;
        let loss = ((&policy_loss - (&entropy * c.ent_coef as f64)?)? + (&value_loss * c.vf_coef as f64)?)?;
        Ok(MinibatchLoss { loss, policy_loss, value_loss, entropy, log_ratio })
    }
}

/// Plain Adam as in SB3 (eps 1e-5, no weight decay).
pub(super) fn adam(policy: &ActorCritic, learning_rate: f64) -> Adam {
    let vars: Vec<Var> = policy.named_vars().into_iter().map(|(_, v)| v).collect();
    Adam::new(vars, AdamConfig { learning_rate, ..AdamConfig::default() })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::PpoConfig;
    use crate::classic::{ClassicCartPole, ClassicPendulum};
    use twinbots_api::env::VecEnv;

    /// Collects one rollout with observation normalisation on and returns the largest
    /// |π(a|s) / π_old(a|s) − 1| over the whole buffer before any gradient step, i.e. over any
    /// first minibatch of the update. Also checks that the statistics moved during the rollout
    /// (so normalising at use time, with the statistics of the end, would have differed).
    fn largest_first_ratio_deviation(env: &mut dyn VecEnv, config: PpoConfig) -> f32 {
        let seed = 7;
        let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), seed).unwrap();
        let first_raw = env.reset(Some(seed)).unwrap();
        let mut obs = model.observe(&first_raw);
        let mut buffer = RolloutBuffer::new(env.num_envs(), env.observation_space().dim(), env.action_space().dim());
        model.collect_rollout(env, &mut obs, &mut buffer).unwrap();
        let values = model.values(&obs).unwrap();
        buffer.compute_advantages(&values, model.config.gamma, model.config.gae_lambda);

        let stored = &buffer.obs[..first_raw.len()];
        let now = model.normalize(&first_raw);
        let moved = stored.iter().zip(&now).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(moved > 1e-2, "the statistics hardly moved ({moved}): the test would prove nothing");

        let all: Vec<usize> = (0..buffer.len()).collect();
        let mb = model.minibatch_loss(&buffer, &all).unwrap();
        (mb.log_ratio.exp().unwrap() - 1.0).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap()
    }

    #[test]
    fn the_first_minibatch_ratio_is_exactly_one_with_normalised_observations() {
        let config = PpoConfig { n_steps: 128, normalize_observations: true, ..PpoConfig::default() };
        let deviation = largest_first_ratio_deviation(&mut ClassicCartPole::new(4), config);
        assert!(deviation <= 1e-6, "|ratio - 1| up to {deviation}");
    }

    #[test]
    fn the_first_minibatch_ratio_is_one_for_a_gaussian_policy_with_normalised_observations() {
        let config = PpoConfig { n_steps: 128, normalize_observations: true, ..PpoConfig::default() };
        let deviation = largest_first_ratio_deviation(&mut ClassicPendulum::new(4), config);
        // The sampled action is mean + z σ and evaluated back as z = (a − mean) / σ: f32
        // rounding only.
        assert!(deviation <= 1e-5, "|ratio - 1| up to {deviation}");
    }
}
