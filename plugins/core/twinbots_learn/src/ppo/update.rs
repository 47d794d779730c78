//! One PPO update: the clipped surrogate objective optimised for `n_epochs` over shuffled
//! minibatches of a rollout whose advantages are computed, and the learning-rate schedule.

use std::borrow::Cow;
use std::time::Instant;

use candle_core::{Device, Tensor, Var};
use rand::seq::SliceRandom;

use super::part::{Part, PartGradient};
use super::{ActorCritic, Ppo, PpoConfig, RolloutBuffer, TRAIN_FIGURES, UpdateStats};
use crate::nn::{Adam, AdamConfig};
use crate::stats::figures;
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
            let progress = self.state.timesteps as f64 / end_timesteps.max(1) as f64;
            self.optimizer.set_learning_rate(self.config.learning_rate * (1.0 - progress).clamp(0.0, 1.0));
        }
    }

    /// One PPO update on `buffer`, whose advantages are computed. `collecting_since` is when
    /// collecting it began: the update's row reports the samples per second since then.
    pub fn train(&mut self, buffer: &RolloutBuffer, collecting_since: Instant) -> anyhow::Result<UpdateStats> {
        self.state.updates += 1;
        let losses = self.optimize(buffer)?;
        if losses.skipped_steps > 0 {
            eprintln!(
                "update {}: {} gradient step(s) skipped: the loss or a gradient was not finite (NaN or infinity)",
                self.state.updates, losses.skipped_steps
            );
        }
        Ok(UpdateStats {
            learning_rate: self.optimizer.learning_rate(),
            steps_per_s: buffer.len() as f32 / collecting_since.elapsed().as_secs_f32(),
            skipped_steps: losses.skipped_steps,
            applied_steps: losses.applied_steps,
            train: losses.train,
            ..self.state.history.row(self.state.updates, self.state.timesteps, self.state.episodes)
        })
    }

    /// n_epochs over shuffled minibatches; returns the mean losses (the rest of the row is
    /// left at its default). A minibatch's gradient is the sum of its parts' ([`parts`]): the
    /// second half on a helper thread while this one does the first.
    fn optimize(&mut self, buffer: &RolloutBuffer) -> anyhow::Result<UpdateStats> {
        let c = self.config.clone();
        let mut indices: Vec<usize> = (0..buffer.len()).collect();
        let (mut pg_sum, mut v_sum, mut ent_sum, mut kl_sum, mut clip_sum, mut batches) =
            (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        let mut skipped = 0;
        let frozen = if c.freeze_features && !super::fused::applies(&self.policy) {
            Some(FrozenFeatures::of(&self.policy, buffer)?)
        } else {
            None
        };
        let (policy, action_space, rng, optimizer) =
            (&self.policy, &self.state.action_space, &mut self.rng, &mut self.optimizer);
        let work = |part: Part| part_gradient(policy, &c, action_space, buffer, frozen.as_ref(), &part);
        crate::threads::with_helper(work, |helper| -> anyhow::Result<()> {
            'epochs: for _ in 0..c.n_epochs {
                indices.shuffle(rng);
                for chunk in indices.chunks(c.batch_size) {
                    let done = crate::threads::share(helper, &work, parts(buffer, chunk, c.normalize_advantage))?;
                    let done: Vec<PartGradient> = done.into_iter().collect::<anyhow::Result<_>>()?;
                    // A non-finite loss or gradient (e.g. from a poisoned reward) changes nothing and
                    // is counted: one bad sample must not end a run's learning silently.
                    if !optimizer
                        .step_flat(
                            crate::nn::sum_gradients(done.iter().map(|p| p.gradients.as_slice())),
                            Some(c.max_grad_norm),
                        )?
                        .applied
                    {
                        skipped += 1;
                        continue;
                    }

                    let mut log_ratio = Vec::with_capacity(chunk.len());
                    for part in &done {
                        log_ratio.extend_from_slice(&part.log_ratio);
                        pg_sum += part.policy_loss;
                        v_sum += part.value_loss;
                        ent_sum += part.entropy;
                    }
                    let n = log_ratio.len().max(1) as f32;
                    // approx KL (Schulman's k3 estimator): E[(r - 1) - log r]
                    let approx_kl = log_ratio.iter().map(|&l| l.exp() - 1.0 - l).sum::<f32>() / n;
                    let clipped =
                        log_ratio.iter().filter(|&&l| (l.exp() - 1.0).abs() > c.clip_range).count() as f32 / n;
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
            Ok(())
        })?;
        let applied_steps = batches as usize;
        // No applied step: the losses are unknown, not zero.
        let batches = if batches == 0.0 { f32::NAN } else { batches };
        Ok(UpdateStats {
            // In the order of `TRAIN_FIGURES`.
            train: figures(
                TRAIN_FIGURES,
                &[pg_sum / batches, v_sum / batches, ent_sum / batches, kl_sum / batches, clip_sum / batches],
            ),
            skipped_steps: skipped,
            applied_steps,
            ..Default::default()
        })
    }

    /// log π/π_old of the samples `chunk` of `buffer` under the current policy, as an update
    /// computes them (`fused`) and as candle's graph does.
    #[cfg(test)]
    pub(super) fn log_ratios(&self, buffer: &RolloutBuffer, chunk: &[usize]) -> anyhow::Result<(Vec<f32>, Vec<f32>)> {
        let advantages = normalized_advantages(buffer, chunk, self.config.normalize_advantage);
        let whole = Part { samples: chunk.to_vec(), advantages, of: chunk.len() };
        let update = part_gradient(&self.policy, &self.config, &self.state.action_space, buffer, None, &whole)?;
        let graph = part_loss(&self.policy, &self.config, &self.state.action_space, buffer, None, &whole)?;
        Ok((update.log_ratio, graph.log_ratio.to_vec1()?))
    }
}

impl PartGradient {
    /// From candle's graph: the loss's backward pass, read out per variable.
    pub(super) fn of(policy: &ActorCritic, loss: MinibatchLoss) -> anyhow::Result<Self> {
        let vars: Vec<Var> = policy.named_vars().into_iter().map(|(_, v)| v).collect();
        let gradients = crate::nn::flat_gradients(&vars, &loss.loss.backward()?)?;
        Ok(Self {
            policy_loss: loss.policy_loss.to_scalar()?,
            value_loss: loss.value_loss.to_scalar()?,
            entropy: loss.entropy.to_scalar()?,
            log_ratio: loss.log_ratio.to_vec1()?,
            gradients,
        })
    }
}

/// `part`'s loss terms and gradient: over slices for an MLP on flat observations
/// (`fused`), through candle's graph for the rest (from `frozen` encoders' features if given).
fn part_gradient(
    policy: &ActorCritic,
    c: &PpoConfig,
    action_space: &Space,
    buffer: &RolloutBuffer,
    frozen: Option<&FrozenFeatures>,
    part: &Part,
) -> anyhow::Result<PartGradient> {
    if super::fused::applies(policy) {
        super::fused::part_gradient(policy, c, buffer, part)
    } else {
        PartGradient::of(policy, part_loss(policy, c, action_space, buffer, frozen, part)?)
    }
}

/// Every sample's features under frozen encoders (`freeze_features`): those the rollout
/// computed as it acted (the buffer's), or else computed once an update instead of once an
/// epoch; the policy's, and the value's own where it has one.
pub(super) struct FrozenFeatures<'a> {
    policy: Cow<'a, [f32]>,
    value: Option<Cow<'a, [f32]>>,
    dim: usize,
    value_dim: usize,
}

impl<'a> FrozenFeatures<'a> {
    fn of(policy: &ActorCritic, buffer: &'a RolloutBuffer) -> anyhow::Result<Self> {
        let (dim, value_dim) = (buffer.cached_width(&buffer.features), buffer.cached_width(&buffer.value_features));
        if dim > 0 && (value_dim > 0) == policy.value_encoder.is_some() {
            let value = (value_dim > 0).then_some(Cow::Borrowed(&buffer.value_features[..]));
            return Ok(Self { policy: Cow::Borrowed(&buffer.features[..]), value, dim, value_dim });
        }
        // In blocks, so a long rollout of images never becomes one huge activation tensor.
        const BLOCK: usize = 256;
        let (mut features, mut value) = (Vec::new(), None::<Vec<f32>>);
        let (mut dim, mut value_dim) = (0, 0);
        for start in (0..buffer.len()).step_by(BLOCK) {
            let n = BLOCK.min(buffer.len() - start);
            let rows = &buffer.obs[start * buffer.obs_dim..(start + n) * buffer.obs_dim];
            let (f, v) = policy.features(&Tensor::from_slice(rows, (n, buffer.obs_dim), &Device::Cpu)?)?;
            dim = f.dim(1)?;
            features.extend(f.flatten_all()?.to_vec1::<f32>()?);
            if let Some(v) = v {
                value_dim = v.dim(1)?;
                value.get_or_insert_with(Vec::new).extend(v.flatten_all()?.to_vec1::<f32>()?);
            }
        }
        Ok(Self { policy: Cow::Owned(features), value: value.map(Cow::Owned), dim, value_dim })
    }
}

/// The minibatch `chunk` in the parts of [`crate::threads::halves`], its advantages normalised
/// over the whole minibatch.
fn parts(buffer: &RolloutBuffer, chunk: &[usize], normalize_advantage: bool) -> Vec<Part> {
    let advantages = normalized_advantages(buffer, chunk, normalize_advantage);
    let of = chunk.len();
    crate::threads::halves(of)
        .into_iter()
        .map(|r| Part { samples: chunk[r.clone()].to_vec(), advantages: advantages[r].to_vec(), of })
        .collect()
}

/// The advantages of `chunk`, normalised to mean 0 and std 1 over it (SB3's per-minibatch
/// normalisation) when asked.
fn normalized_advantages(buffer: &RolloutBuffer, chunk: &[usize], normalize: bool) -> Vec<f32> {
    let b = chunk.len();
    let mut adv: Vec<f32> = chunk.iter().map(|&i| buffer.advantages[i]).collect();
    if normalize && b > 1 {
        let m = adv.iter().sum::<f32>() / b as f32;
        let s = (adv.iter().map(|a| (a - m).powi(2)).sum::<f32>() / (b - 1) as f32).sqrt();
        adv.iter_mut().for_each(|a| *a = (*a - m) / (s + 1e-8));
    }
    adv
}

/// `part`'s share of its minibatch's PPO loss under `policy`: each term summed over the part and
/// divided by the minibatch's size, so the parts' losses add up to the minibatch's means.
pub(super) fn part_loss(
    policy: &ActorCritic,
    c: &PpoConfig,
    action_space: &Space,
    buffer: &RolloutBuffer,
    frozen: Option<&FrozenFeatures>,
    part: &Part,
) -> anyhow::Result<MinibatchLoss> {
    let dev = Device::Cpu;
    let b = part.samples.len();
    let (obs_dim, act_dim) = (buffer.obs_dim, buffer.act_dim);
    let gather = |src: &[f32], width: usize| -> Vec<f32> {
        part.samples.iter().flat_map(|&i| src[i * width..(i + 1) * width].iter().copied()).collect()
    };
    let actions = Tensor::from_vec(gather(&buffer.actions, act_dim), (b, act_dim), &dev)?;
    let actions =
        if act_dim == 1 && matches!(action_space, Space::Discrete { .. }) { actions.squeeze(1)? } else { actions };
    let old_log_prob = Tensor::from_vec(gather(&buffer.log_probs, 1), b, &dev)?;
    let returns = Tensor::from_vec(gather(&buffer.returns, 1), b, &dev)?;
    let adv = Tensor::from_vec(part.advantages.clone(), b, &dev)?;
    let per_sample = 1.0 / part.of.max(1) as f64;

    let eval = match frozen {
        Some(f) => {
            let features = Tensor::from_vec(gather(&f.policy, f.dim), (b, f.dim), &dev)?;
            let value = f
                .value
                .as_ref()
                .map(|v| Tensor::from_vec(gather(v, f.value_dim), (b, f.value_dim), &dev))
                .transpose()?;
            policy.evaluate_features(&features, value.as_ref(), &actions)?
        }
        None => {
            // The observations as the policy saw them when it acted (the buffer holds them normalised).
            policy.evaluate(&Tensor::from_vec(gather(&buffer.obs, obs_dim), (b, obs_dim), &dev)?, &actions)?
        }
    };
    // ratio = π(a|s) / π_old(a|s)
    let log_ratio = (&eval.log_prob - &old_log_prob)?;
    let ratio = log_ratio.exp()?;
    // L_clip = E[min(r A, clip(r, 1-ε, 1+ε) A)]; we minimise its negative.
    let surr1 = (&ratio * &adv)?;
    let surr2 = (ratio.clamp(1.0 - c.clip_range, 1.0 + c.clip_range)? * &adv)?;
    let policy_loss = (surr1.minimum(&surr2)?.sum_all()? * -per_sample)?;
    // L_V = E[(V(s) - R)^2]   (SB3's MSE, no value clipping)
    let value_loss = ((&eval.value - &returns)?.sqr()?.sum_all()? * per_sample)?;
    let entropy = (eval.entropy.sum_all()? * per_sample)?;
    let loss = ((&policy_loss - (&entropy * c.ent_coef as f64)?)? + (&value_loss * c.vf_coef as f64)?)?;
    Ok(MinibatchLoss { loss, policy_loss, value_loss, entropy, log_ratio })
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
    /// (so normalising at use time, with the statistics of the end, would have differed). Both
    /// the update's ratios and candle's graph's are checked.
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
        let (update, graph) = model.log_ratios(&buffer, &all).unwrap();
        update.iter().chain(&graph).map(|l| (l.exp() - 1.0).abs()).fold(0.0, f32::max)
    }

    #[test]
    fn the_first_minibatch_ratio_is_exactly_one_with_normalised_observations() {
        let config = PpoConfig { n_steps: 128, normalize_observations: true, ..PpoConfig::default() };
        let deviation = largest_first_ratio_deviation(&mut ClassicCartPole::new(4), config);
        assert!(deviation <= 1e-6, "|ratio - 1| up to {deviation}");
    }

    /// The weights after a few updates of minibatches large enough to split, trained in a pool
    /// of `threads`.
    fn weights_after_training_on(threads: usize, make: fn() -> Box<dyn VecEnv>) -> Vec<Vec<f32>> {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let mut env = make();
            let env = env.as_mut();
            let config = PpoConfig { n_steps: 64, batch_size: 128, n_epochs: 3, ..PpoConfig::default() };
            let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 11).unwrap();
            model
                .learn(env, 4 * 64 * 3, &mut |_: &UpdateStats, _: &dyn crate::Agent| Ok(crate::Flow::Continue))
                .unwrap();
            model
                .policy
                .named_vars()
                .iter()
                .map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1().unwrap())
                .collect()
        })
    }

    #[test]
    fn one_thread_or_two_train_the_same_bits() {
        let envs: [fn() -> Box<dyn VecEnv>; 2] =
            [|| Box::new(ClassicCartPole::new(4)), || Box::new(ClassicPendulum::new(4))];
        for make in envs {
            let one = weights_after_training_on(1, make);
            let two = weights_after_training_on(2, make);
            assert_eq!(one, two);
        }
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
