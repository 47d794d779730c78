//! SAC's critic and actor losses and their gradients for networks on flat observations, over
//! slices ([`crate::nn::fused_mlp`]): the losses `update.rs` builds with candle's graph,
//! written out (tests check both agree), at the cost of their arithmetic. Camera policies keep
//! the graph.

use super::Sac;
use super::networks::{Actor, LOG_STD_MAX, LOG_STD_MIN};
use crate::nn::fused_mlp::{Activation, Activations, HALF_LOG_2PI, SliceMlp};
use crate::nn::{Dense, Encoder};
use crate::off_policy::networks::{ReluMlp, TwinCritic};
use crate::replay_buffer::Batch;

/// A loss's value and its gradient for every variable of one optimiser, flat, in its order.
pub(super) struct LossGradient {
    pub loss: f32,
    pub gradients: Vec<Option<Vec<f32>>>,
}

/// The actor's loss and gradient, and −log π of its samples averaged (the entropy figure).
pub(super) struct ActorGradient {
    pub loss: LossGradient,
    pub entropy: f32,
}

/// Whether the slices compute `sac`'s gradients: its actor and critics read flat observations.
pub(super) fn applies(sac: &Sac) -> bool {
    matches!(sac.actor.encoder, Encoder::Flat { .. }) && matches!(sac.critic.encoder, Encoder::Flat { .. })
}

fn relu_mlp(mlp: &ReluMlp) -> candle_core::Result<SliceMlp> {
    SliceMlp::read(&mlp.layers, Activation::Relu, mlp.relu_last)
}

/// One dense layer as a network of its own (no activation).
fn linear(layer: &Dense) -> candle_core::Result<SliceMlp> {
    SliceMlp::read(std::slice::from_ref(layer), Activation::Relu, false)
}

/// The actor's numbers, read once per gradient step and shared by its parts.
pub(super) struct ActorNets {
    body: SliceMlp,
    mu: SliceMlp,
    log_std: SliceMlp,
}

impl ActorNets {
    pub(super) fn read(actor: &Actor) -> anyhow::Result<Self> {
        Ok(Self { body: relu_mlp(&actor.body)?, mu: linear(&actor.mu)?, log_std: linear(&actor.log_std)? })
    }
}

/// Twin critics' numbers (the critics' or their targets').
pub(super) struct CriticNets {
    q1: SliceMlp,
    q2: SliceMlp,
}

impl CriticNets {
    pub(super) fn read(critic: &TwinCritic) -> anyhow::Result<Self> {
        Ok(Self { q1: relu_mlp(&critic.q1)?, q2: relu_mlp(&critic.q2)? })
    }
}

/// The actor's reparameterised samples a = tanh(μ + σ ε) of some rows, with log π(a|s), and
/// what the actor's backward pass needs.
pub(super) struct ActorSample {
    features: Activations,
    mu_pass: Activations,
    log_std_pass: Activations,
    /// The standard normal noise ε of each action (rows × actions).
    eps: Vec<f32>,
    /// tanh u, the actions (rows × actions).
    pub actions: Vec<f32>,
    /// log π(a|s) per row.
    pub log_pi: Vec<f32>,
    act_dim: usize,
}

impl ActorSample {
    /// Samples for the rows of `obs` (normalised) with the standard normal noise `eps`.
    pub(super) fn new(nets: &ActorNets, obs: &[f32], eps: &[f32], rows: usize) -> Self {
        let features = nets.body.forward(obs.to_vec(), rows);
        let mu_pass = nets.mu.forward(features.output().to_vec(), rows);
        let log_std_pass = nets.log_std.forward(features.output().to_vec(), rows);
        let act_dim = eps.len() / rows.max(1);
        let mut actions = Vec::with_capacity(eps.len());
        let mut log_pi = Vec::with_capacity(rows);
        for ((mu, raw), eps) in mu_pass
            .output()
            .chunks_exact(act_dim)
            .zip(log_std_pass.output().chunks_exact(act_dim))
            .zip(eps.chunks_exact(act_dim))
        {
            // log π = Σ log N(u; μ, σ) − log(1 − tanh²u), the latter as 2 (log 2 − u − softplus(−2u))
            let mut lp = 0.0;
            for k in 0..act_dim {
                let ls = clamp_log_std(raw[k]);
                let u = mu[k] + ls.exp() * eps[k];
                let squash = 2.0 * (std::f32::consts::LN_2 - u - softplus(-2.0 * u));
                lp += -0.5 * eps[k] * eps[k] - ls - HALF_LOG_2PI - squash;
                actions.push(u.tanh());
            }
            log_pi.push(lp);
        }
        Self { features, mu_pass, log_std_pass, eps: eps.to_vec(), actions, log_pi, act_dim }
    }

    /// The actor's gradients (body, μ, log σ: its `named_vars` order) from ∂L/∂a and the weight
    /// `log_pi_weight` of Σ log π in the loss.
    fn backward(self, nets: &ActorNets, d_actions: &[f32], log_pi_weight: f32) -> Vec<Option<Vec<f32>>> {
        let n = self.actions.len();
        let (mut d_mu, mut d_log_std) = (vec![0.0; n], vec![0.0; n]);
        for i in 0..n {
            let (a, raw) = (self.actions[i], self.log_std_pass.output()[i]);
            // ∂ log π/∂u = 2 tanh u (the squash term); ∂a/∂u = 1 − tanh²u
            let d_u = d_actions[i] * (1.0 - a * a) + log_pi_weight * 2.0 * a;
            d_mu[i] = d_u;
            // u = μ + e^{log σ} ε, and log π holds −log σ; the clamp passes the gradient inside its range
            let inside = (LOG_STD_MIN as f32..=LOG_STD_MAX as f32).contains(&raw);
            d_log_std[i] = if inside { d_u * clamp_log_std(raw).exp() * self.eps[i] - log_pi_weight } else { 0.0 };
        }
        let mu = nets.mu.backward(&self.mu_pass, d_mu, true, true);
        let log_std = nets.log_std.backward(&self.log_std_pass, d_log_std, true, true);
        let mut d_features = mu.input.clone().unwrap_or_default();
        d_features.iter_mut().zip(log_std.input.iter().flatten()).for_each(|(d, e)| *d += e);
        let body = nets.body.backward(&self.features, d_features, true, false);
        body.into_flat().chain(mu.into_flat()).chain(log_std.into_flat()).map(Some).collect()
    }
}

fn clamp_log_std(raw: f32) -> f32 {
    raw.clamp(LOG_STD_MIN as f32, LOG_STD_MAX as f32)
}

/// log(1 + eˣ), stable for large |x|.
fn softplus(x: f32) -> f32 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// Rows of [observation, action].
fn joined(obs: &[f32], actions: &[f32], rows: usize) -> Vec<f32> {
    let (o, a) = (obs.len() / rows.max(1), actions.len() / rows.max(1));
    obs.chunks_exact(o.max(1))
        .zip(actions.chunks_exact(a.max(1)))
        .flat_map(|(o, a)| o.iter().chain(a).copied())
        .collect()
}

/// The numbers of every network a gradient step's first phase reads.
pub(super) struct StepNets {
    pub actor: ActorNets,
    pub critic: CriticNets,
    pub target: CriticNets,
}

/// Some rows of a minibatch of `of` rows, with their noise: a part of a gradient step.
pub(super) struct Part {
    pub batch: Batch,
    pub eps: Vec<f32>,
    pub eps_next: Vec<f32>,
    pub of: usize,
}

/// A part's share of the critics' loss ½ Σᵢ MSE(Qᵢ, y), y = r + γ (1 − done) (min Q'(s', a') −
/// α log π(a'|s')), summed over its rows and divided by the minibatch's size, and its gradient
/// (Q₁'s layers, then Q₂'s); with the actor's samples of its rows, for α and the actor.
pub(super) fn critic_part(nets: &StepNets, part: &Part, alpha: f32, gamma: f32) -> (ActorSample, LossGradient) {
    let (batch, b) = (&part.batch, part.batch.rewards.len());
    let sample = ActorSample::new(&nets.actor, &batch.obs, &part.eps, b);
    let next = ActorSample::new(&nets.actor, &batch.next_obs, &part.eps_next, b);
    let next_input = joined(&batch.next_obs, &next.actions, b);
    let (t1, t2) = (nets.target.q1.forward(next_input.clone(), b), nets.target.q2.forward(next_input, b));
    let input = joined(&batch.obs, &batch.actions, b);
    let (q1, q2) = (nets.critic.q1.forward(input.clone(), b), nets.critic.q2.forward(input, b));
    let per_sample = 1.0 / part.of.max(1) as f32;
    let (mut loss, mut d_q1, mut d_q2) = (0.0, Vec::with_capacity(b), Vec::with_capacity(b));
    for i in 0..b {
        let next_q = t1.output()[i].min(t2.output()[i]) - alpha * next.log_pi[i];
        let y = batch.rewards[i] + (1.0 - batch.dones[i]) * next_q * gamma;
        let (e1, e2) = (q1.output()[i] - y, q2.output()[i] - y);
        loss += 0.5 * (e1 * e1 + e2 * e2) * per_sample;
        d_q1.push(e1 * per_sample);
        d_q2.push(e2 * per_sample);
    }
    let gradients = nets
        .critic
        .q1
        .backward(&q1, d_q1, true, false)
        .into_flat()
        .chain(nets.critic.q2.backward(&q2, d_q2, true, false).into_flat())
        .map(Some)
        .collect();
    (sample, LossGradient { loss, gradients })
}

/// A part's share of the actor's loss E[α log π(a|s) − min Q(s, a)] over its `sample` (taken
/// from `obs`) through the critics `critic` (as they are after their step), and its gradient.
pub(super) fn actor_part(
    actor: &ActorNets,
    critic: &CriticNets,
    obs: &[f32],
    sample: ActorSample,
    alpha: f32,
    of: usize,
) -> ActorGradient {
    let b = sample.log_pi.len();
    let act_dim = sample.act_dim;
    let input = joined(obs, &sample.actions, b);
    let (q1, q2) = (critic.q1.forward(input.clone(), b), critic.q2.forward(input, b));
    let per_sample = 1.0 / of.max(1) as f32;
    let (mut loss, mut d_q1, mut d_q2) = (0.0, Vec::with_capacity(b), Vec::with_capacity(b));
    for i in 0..b {
        let (a, c) = (q1.output()[i], q2.output()[i]);
        loss += (alpha * sample.log_pi[i] - a.min(c)) * per_sample;
        // −min(Q₁, Q₂): the gradient goes to the smaller, half to each when they are equal.
        let share = |mine: f32, other: f32| {
            if mine < other {
                1.0
            } else if mine == other {
                0.5
            } else {
                0.0
            }
        };
        d_q1.push(-per_sample * share(a, c));
        d_q2.push(-per_sample * share(c, a));
    }
    let d_in1 = critic.q1.backward(&q1, d_q1, false, true).input.unwrap_or_default();
    let d_in2 = critic.q2.backward(&q2, d_q2, false, true).input.unwrap_or_default();
    let width = d_in1.len() / b.max(1);
    // ∂L/∂a: the action columns of the critics' input gradients.
    let d_actions: Vec<f32> = d_in1
        .chunks_exact(width.max(1))
        .zip(d_in2.chunks_exact(width.max(1)))
        .flat_map(|(r1, r2)| (width - act_dim..width).map(move |k| r1[k] + r2[k]))
        .collect();
    let entropy = -sample.log_pi.iter().sum::<f32>() * per_sample;
    let gradients = sample.backward(actor, &d_actions, alpha * per_sample);
    ActorGradient { loss: LossGradient { loss, gradients }, entropy }
}

/// The rows `rows` of `values`, a flat array of rows of equal width.
pub(super) fn rows_of<T: Clone>(values: &[T], of: usize, rows: &std::ops::Range<usize>) -> Vec<T> {
    let width = values.len() / of.max(1);
    values[rows.start * width..rows.end * width].to_vec()
}

/// The minibatch with its noise in the parts of [`crate::threads::halves`].
#[cfg(test)]
pub(super) fn parts(batch: Batch, eps: Vec<f32>, eps_next: Vec<f32>) -> Vec<Part> {
    let of = batch.rewards.len();
    crate::threads::halves(of)
        .iter()
        .map(|r| Part {
            batch: Batch {
                obs: rows_of(&batch.obs, of, r),
                actions: rows_of(&batch.actions, of, r),
                rewards: rows_of(&batch.rewards, of, r),
                next_obs: rows_of(&batch.next_obs, of, r),
                dones: rows_of(&batch.dones, of, r),
            },
            eps: rows_of(&eps, of, r),
            eps_next: rows_of(&eps_next, of, r),
            of,
        })
        .collect()
}

/// The parts' losses added and gradients summed in order.
pub(super) fn sum(parts: Vec<LossGradient>) -> LossGradient {
    LossGradient {
        loss: parts.iter().map(|p| p.loss).sum(),
        gradients: crate::nn::sum_gradients(parts.iter().map(|p| p.gradients.as_slice())),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classic::ClassicPendulum;
    use crate::learner::Learner;
    use crate::off_policy::config::OffPolicyConfig;
    use crate::sac::SacConfig;
    use candle_core::{Device, Tensor};
    use rand::SeedableRng;
    use twinbots_api::env::VecEnv;

    fn close(a: f32, b: f32, what: &str) {
        assert!((a - b).abs() <= 2e-4 * (1.0 + b.abs()), "{what}: {a} vs {b}");
    }

    fn agree(ours: &LossGradient, theirs: &LossGradient, what: &str) {
        close(ours.loss, theirs.loss, what);
        assert_eq!(ours.gradients.len(), theirs.gradients.len(), "{what}: variables");
        for (i, (a, b)) in ours.gradients.iter().zip(&theirs.gradients).enumerate() {
            let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
            assert_eq!(a.len(), b.len());
            a.iter().zip(b).for_each(|(a, b)| close(*a, *b, &format!("{what}: gradient of variable {i}")));
        }
    }

    /// A model a few hundred steps into learning (its networks moved, α too), a batch of its
    /// replay buffer, and the noise of a step.
    fn trained_model_and_batch() -> (Sac, Batch, Vec<f32>, Vec<f32>) {
        let mut env = ClassicPendulum::new(2);
        let config = SacConfig {
            off_policy: OffPolicyConfig {
                learning_starts: 64,
                batch_size: 96,
                learning_rate: 3e-3,
                ..Default::default()
            },
            hidden: vec![16, 16],
            ..SacConfig::default()
        };
        let mut sac = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 4).unwrap();
        sac.learn(&mut env, 400, &mut |_: &crate::UpdateStats, _: &dyn crate::Agent| Ok(crate::Flow::Continue))
            .unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let batch = sac.buffer.as_ref().unwrap().sample(96, &mut rng, None);
        let (eps, eps_next) = (sac.noise(96), sac.noise(96));
        (sac, batch, eps, eps_next)
    }

    #[test]
    fn one_thread_or_two_train_the_same_bits() {
        let weights = |threads: usize| {
            rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| {
                let mut env = ClassicPendulum::new(2);
                let config = SacConfig {
                    off_policy: OffPolicyConfig { learning_starts: 64, batch_size: 96, ..Default::default() },
                    hidden: vec![16, 16],
                    ..SacConfig::default()
                };
                let mut sac = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 6).unwrap();
                sac.learn(&mut env, 300, &mut |_: &crate::UpdateStats, _: &dyn crate::Agent| Ok(crate::Flow::Continue))
                    .unwrap();
                let vars = sac
                    .actor
                    .named_vars()
                    .into_iter()
                    .chain(sac.critic.named_vars("critic"))
                    .chain(sac.critic_target.named_vars("target"));
                vars.map(|(_, v)| v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()).collect::<Vec<_>>()
            })
        };
        assert_eq!(weights(1), weights(2));
    }

    #[test]
    fn the_fused_critic_gradient_is_the_graphs() {
        let (sac, batch, _, eps_next) = trained_model_and_batch();
        let alpha = sac.ent_coef().unwrap();
        assert!((alpha - 1.0).abs() > 0.01, "α never moved: the test would not weigh the entropy term");
        let nets = StepNets {
            actor: ActorNets::read(&sac.actor).unwrap(),
            critic: CriticNets::read(&sac.critic).unwrap(),
            target: CriticNets::read(&sac.critic_target).unwrap(),
        };
        let (theirs, _) = sac.critic_gradient_graph(&batch, &eps_next, alpha).unwrap();
        // In one part, and in the two halves a step computes side by side.
        let whole =
            Part { of: batch.rewards.len(), batch: batch.clone(), eps: eps_next.clone(), eps_next: eps_next.clone() };
        agree(&critic_part(&nets, &whole, alpha, sac.config.off_policy.gamma).1, &theirs, "critic");
        let halves = parts(batch, eps_next.clone(), eps_next)
            .iter()
            .map(|p| critic_part(&nets, p, alpha, sac.config.off_policy.gamma).1)
            .collect::<Vec<_>>();
        assert_eq!(halves.len(), 2);
        agree(&sum(halves), &theirs, "critic in halves");
    }

    #[test]
    fn the_fused_actor_gradient_is_the_graphs() {
        let (sac, batch, eps, _) = trained_model_and_batch();
        let alpha = sac.ent_coef().unwrap();
        let b = batch.rewards.len();
        let nets = ActorNets::read(&sac.actor).unwrap();
        let sample = ActorSample::new(&nets, &batch.obs, &eps, b);
        let (actions, log_pi) = sac.actor_samples_graph(&batch.obs, &eps).unwrap();
        let theirs_log_pi: Vec<f32> = log_pi.to_vec1().unwrap();
        sample.log_pi.iter().zip(&theirs_log_pi).for_each(|(a, b)| close(*a, *b, "log π"));
        let ours = actor_part(&nets, &CriticNets::read(&sac.critic).unwrap(), &batch.obs, sample, alpha, b);
        let features =
            Tensor::from_vec(batch.obs.clone(), (b, sac.state.observation_space.dim()), &Device::Cpu).unwrap();
        let theirs = sac.actor_gradient_graph(&actions, &log_pi, &features, alpha).unwrap();
        agree(&ours.loss, &theirs.loss, "actor");
        close(ours.entropy, theirs.entropy, "entropy");
    }
}
