//! The PPO loss and its gradient for an actor-critic on flat observations, over slices
//! ([`crate::nn::fused_mlp`]): the same loss as `update::part_loss` builds with candle's
//! autograd (a test checks both agree), at the cost of its arithmetic. Camera policies (a CNN
//! encoder, image observations) keep candle's path.

use super::part::{Part, PartGradient};
use super::policy::{ActorCritic, Head};
use super::{PpoConfig, RolloutBuffer};
use crate::nn::Encoder;
use crate::nn::fused_mlp::{Activation, HALF_LOG_2PI, SliceMlp};

/// Whether [`part_gradient`] computes this policy's gradients: flat observations into MLPs.
pub(super) fn applies(policy: &ActorCritic) -> bool {
    matches!(policy.encoder, Encoder::Flat { .. })
}

/// `part`'s share of its minibatch's loss L = L_clip − c_ent H + c_V L_V (each term summed
/// over the part and divided by the minibatch's size), and its gradient for every variable in
/// `named_vars` order.
pub(super) fn part_gradient(
    policy: &ActorCritic,
    c: &PpoConfig,
    buffer: &RolloutBuffer,
    part: &Part,
) -> anyhow::Result<PartGradient> {
    let b = part.samples.len();
    let per_sample = 1.0 / part.of.max(1) as f32;
    let gather = |src: &[f32], width: usize| -> Vec<f32> {
        part.samples.iter().flat_map(|&i| src[i * width..(i + 1) * width].iter().copied()).collect()
    };
    let obs = gather(&buffer.obs, buffer.obs_dim);
    let actions = gather(&buffer.actions, buffer.act_dim);
    let pi = SliceMlp::read(&policy.pi.layers, Activation::Tanh, false)?;
    let vf = SliceMlp::read(&policy.vf.layers, Activation::Tanh, false)?;
    let pi_out = pi.forward(obs.clone(), b);
    let vf_out = vf.forward(obs, b);

    // log π(a|s) of each sample and, for the Gaussian, its z = (a − μ) / σ.
    let head = HeadPass::new(&policy.head, pi_out.output(), &actions, b)?;
    let mut log_ratio = Vec::with_capacity(b);
    // ∂L/∂ log π(a|s) per sample, from the clipped surrogate.
    let mut d_log_prob = Vec::with_capacity(b);
    let mut surrogate = 0.0;
    for (k, &i) in part.samples.iter().enumerate() {
        let lr = head.log_prob()[k] - buffer.log_probs[i];
        let ratio = lr.exp();
        let advantage = part.advantages[k];
        // L_clip = −E[min(r A, clip(r, 1-ε, 1+ε) A)]
        let clipped = ratio.clamp(1.0 - c.clip_range, 1.0 + c.clip_range);
        let (unclipped_term, clipped_term) = (ratio * advantage, clipped * advantage);
        surrogate += unclipped_term.min(clipped_term);
        // The minimum's gradient flows through r A, or through clip(r) A where the clip lets it.
        let through = unclipped_term <= clipped_term || (1.0 - c.clip_range..=1.0 + c.clip_range).contains(&ratio);
        d_log_prob.push(if through { -advantage * ratio * per_sample } else { 0.0 });
        log_ratio.push(lr);
    }
    let (d_pi_out, entropy_sum, d_log_std) = head.backward(&d_log_prob, c.ent_coef * per_sample);

    // L_V = E[(V(s) − R)²]
    let mut value_sum = 0.0;
    let mut d_value = Vec::with_capacity(b);
    for (&v, &i) in vf_out.output().iter().zip(&part.samples) {
        let error = v - buffer.returns[i];
        value_sum += error * error;
        d_value.push(c.vf_coef * 2.0 * error * per_sample);
    }

    let mut gradients: Vec<Option<Vec<f32>>> =
        pi.backward(&pi_out, d_pi_out, true, false).into_flat().map(Some).collect();
    gradients.extend(vf.backward(&vf_out, d_value, true, false).into_flat().map(Some));
    if let Some(d_log_std) = d_log_std {
        gradients.push(Some(d_log_std));
    }
    Ok(PartGradient {
        policy_loss: -surrogate * per_sample,
        value_loss: value_sum * per_sample,
        entropy: entropy_sum * per_sample,
        log_ratio,
        gradients,
    })
}

/// The policy's numbers for a rollout's inference, read once: the weights stay as they are
/// until the update after it.
pub(super) struct Inference {
    pi: SliceMlp,
    vf: SliceMlp,
    log_std: Vec<f32>,
}

impl Inference {
    /// Reads `policy`'s numbers, when [`applies`] to it.
    pub(super) fn read(policy: &ActorCritic) -> anyhow::Result<Option<Self>> {
        if !applies(policy) {
            return Ok(None);
        }
        Ok(Some(Self {
            pi: SliceMlp::read(&policy.pi.layers, Activation::Tanh, false)?,
            vf: SliceMlp::read(&policy.vf.layers, Activation::Tanh, false)?,
            log_std: policy.log_std_values()?,
        }))
    }

    /// [`ActorCritic::act`] on `obs` (rows of normalised observations), sampling with `rng`.
    pub(super) fn act(
        &self,
        head: &Head,
        obs: &[f32],
        rows: usize,
        rng: &mut rand_chacha::ChaCha8Rng,
    ) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let out = self.pi.forward(obs.to_vec(), rows);
        let values = self.vf.forward(obs.to_vec(), rows);
        let (actions, log_probs) = super::policy::sample(head, out.output(), &self.log_std, false, rng);
        (actions, log_probs, values.output().to_vec())
    }
}

/// The action head's forward pass over a part: log-probabilities, and what its backward pass
/// needs.
enum HeadPass {
    Categorical { n: usize, log_p: Vec<f32>, actions: Vec<usize>, log_prob: Vec<f32> },
    Gaussian { dim: usize, log_std: Vec<f32>, z: Vec<f32>, log_prob: Vec<f32> },
}

impl HeadPass {
    fn new(head: &Head, out: &[f32], actions: &[f32], b: usize) -> anyhow::Result<Self> {
        Ok(match head {
            Head::Categorical { n } => {
                let n = *n;
                let mut log_p = out.to_vec();
                let mut chosen = Vec::with_capacity(b);
                let mut log_prob = Vec::with_capacity(b);
                for (row, &a) in log_p.chunks_exact_mut(n).zip(actions) {
                    // log softmax
                    let log_sum = super::policy::log_sum_exp(row);
                    row.iter_mut().for_each(|l| *l -= log_sum);
                    let a = a as usize;
                    anyhow::ensure!(a < n, "a stored action {a} is outside Discrete({n})");
                    chosen.push(a);
                    log_prob.push(row[a]);
                }
                HeadPass::Categorical { n, log_p, actions: chosen, log_prob }
            }
            Head::Gaussian { dim, log_std } => {
                let dim = *dim;
                let log_std: Vec<f32> = log_std.as_tensor().to_vec1()?;
                let mut z = Vec::with_capacity(b * dim);
                let mut log_prob = Vec::with_capacity(b);
                for (mean, action) in out.chunks_exact(dim).zip(actions.chunks_exact(dim)) {
                    // log N(a; μ, σ) = Σ −z²/2 − log σ − ½ ln 2π
                    let mut lp = 0.0;
                    for k in 0..dim {
                        let zk = (action[k] - mean[k]) / log_std[k].exp();
                        lp += -0.5 * zk * zk - log_std[k] - HALF_LOG_2PI;
                        z.push(zk);
                    }
                    log_prob.push(lp);
                }
                HeadPass::Gaussian { dim, log_std, z, log_prob }
            }
        })
    }

    /// log π(a|s) of each sample.
    fn log_prob(&self) -> &[f32] {
        match self {
            HeadPass::Categorical { log_prob, .. } | HeadPass::Gaussian { log_prob, .. } => log_prob,
        }
    }

    /// ∂L/∂(network output) from ∂L/∂ log π(a|s) per sample, with the entropy bonus
    /// −`entropy_weight` · H of every sample; returns it, the part's summed entropy, and the
    /// Gaussian's ∂L/∂ log σ.
    fn backward(&self, d_log_prob: &[f32], entropy_weight: f32) -> (Vec<f32>, f32, Option<Vec<f32>>) {
        match self {
            HeadPass::Categorical { n, log_p, actions, .. } => {
                let mut d_out = vec![0.0; log_p.len()];
                let mut entropy_sum = 0.0;
                for (k, (row, d_row)) in log_p.chunks_exact(*n).zip(d_out.chunks_exact_mut(*n)).enumerate() {
                    // H = −Σ p log p;  ∂H/∂l_j = −p_j (log p_j + H);  ∂ log p_a/∂l_j = δ_aj − p_j
                    let entropy: f32 = -row.iter().map(|l| l.exp() * l).sum::<f32>();
                    entropy_sum += entropy;
                    for (j, (l, d)) in row.iter().zip(d_row.iter_mut()).enumerate() {
                        let p = l.exp();
                        let chosen = if j == actions[k] { 1.0 } else { 0.0 };
                        *d = d_log_prob[k] * (chosen - p) + entropy_weight * p * (l + entropy);
                    }
                }
                (d_out, entropy_sum, None)
            }
            HeadPass::Gaussian { dim, log_std, z, .. } => {
                let mut d_out = vec![0.0; z.len()];
                let mut d_log_std = vec![0.0; *dim];
                for (k, (z_row, d_row)) in z.chunks_exact(*dim).zip(d_out.chunks_exact_mut(*dim)).enumerate() {
                    // ∂ log π/∂μ = z / σ;  ∂ log π/∂ log σ = z² − 1
                    for j in 0..*dim {
                        d_row[j] = d_log_prob[k] * z_row[j] / log_std[j].exp();
                        d_log_std[j] += d_log_prob[k] * (z_row[j] * z_row[j] - 1.0);
                    }
                }
                // H = Σ (log σ + ½ + ½ ln 2π) per sample, the same for every sample.
                let rows = z.len() / (*dim).max(1);
                let entropy: f32 = log_std.iter().map(|l| l + 0.5 + HALF_LOG_2PI).sum();
                d_log_std.iter_mut().for_each(|d| *d -= entropy_weight * rows as f32);
                (d_out, entropy * rows as f32, Some(d_log_std))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classic::{ClassicCartPole, ClassicPendulum};
    use crate::ppo::Ppo;
    use crate::ppo::part::PartGradient;
    use crate::ppo::update::part_loss;
    use twinbots_api::env::VecEnv;

    /// A rollout of a fresh policy, a few updates in (so the ratios differ from one and some
    /// clip), and the fused and candle gradients of one minibatch of it.
    fn both_gradients(env: &mut dyn VecEnv) -> (PartGradient, PartGradient) {
        let config = PpoConfig {
            n_steps: 64,
            batch_size: 64,
            n_epochs: 4,
            learning_rate: 3e-3,
            ent_coef: 0.01,
            ..PpoConfig::default()
        };
        let mut model = Ppo::new(config, env.observation_space().clone(), env.action_space().clone(), 5).unwrap();
        let mut obs = model.observe(&env.reset(Some(5)).unwrap());
        let mut buffer = RolloutBuffer::new(env.num_envs(), env.observation_space().dim(), env.action_space().dim());
        model.collect_rollout(env, &mut obs, &mut buffer).unwrap();
        let values = model.values(&obs).unwrap();
        buffer.compute_advantages(&values, model.config.gamma, model.config.gae_lambda);
        model.train(&buffer, std::time::Instant::now()).unwrap();
        let samples: Vec<usize> = (0..buffer.len()).step_by(3).collect();
        let advantages: Vec<f32> = samples.iter().map(|&i| buffer.advantages[i] * 0.7).collect();
        let part = Part { samples, advantages, of: 100 };
        let fused = part_gradient(&model.policy, &model.config, &buffer, &part).unwrap();
        let loss = part_loss(&model.policy, &model.config, &model.state.action_space, &buffer, None, &part).unwrap();
        (fused, PartGradient::of(&model.policy, loss).unwrap())
    }

    fn assert_agree(ours: &PartGradient, theirs: &PartGradient) {
        let close = |a: f32, b: f32, what: &str| assert!((a - b).abs() <= 2e-4 * (1.0 + b.abs()), "{what}: {a} vs {b}");
        close(ours.policy_loss, theirs.policy_loss, "policy loss");
        close(ours.value_loss, theirs.value_loss, "value loss");
        close(ours.entropy, theirs.entropy, "entropy");
        assert_eq!(ours.log_ratio.len(), theirs.log_ratio.len());
        ours.log_ratio.iter().zip(&theirs.log_ratio).for_each(|(a, b)| close(*a, *b, "log ratio"));
        assert!(
            theirs.log_ratio.iter().any(|l| l.abs() > 0.2),
            "no sample clips: the test would not reach the clipped branch"
        );
        assert_eq!(ours.gradients.len(), theirs.gradients.len());
        for (i, (a, b)) in ours.gradients.iter().zip(&theirs.gradients).enumerate() {
            let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
            a.iter().zip(b).for_each(|(a, b)| close(*a, *b, &format!("gradient of variable {i}")));
        }
    }

    #[test]
    fn the_fused_categorical_gradient_is_candles() {
        let (ours, theirs) = both_gradients(&mut ClassicCartPole::new(4));
        assert_agree(&ours, &theirs);
    }

    #[test]
    fn the_fused_gaussian_gradient_is_candles() {
        let (ours, theirs) = both_gradients(&mut ClassicPendulum::new(4));
        assert_agree(&ours, &theirs);
    }
}
