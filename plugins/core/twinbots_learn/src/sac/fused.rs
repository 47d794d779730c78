//! SAC's critic and actor losses and their gradients for networks on flat observations, over
//! slices ([`crate::nn::fused_mlp`]): the losses `update.rs` builds with candle's graph,
//! written out (tests check both agree), at the cost of their arithmetic. Camera policies keep
//! the graph.

use super::networks::{Actor, LOG_STD_MAX, LOG_STD_MIN, ReluMlp};
use super::update::{ActorGradient, LossGradient};
use super::Sac;
use crate::nn::fused_mlp::{Activation, Activations, SliceMlp};
use crate::nn::{Dense, Encoder};
use crate::replay_buffer::Batch;

/// ½ ln 2π, of the Gaussian's log-density.
const HALF_LOG_2PI: f32 = 0.918_938_5;

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

/// The actor's reparameterised samples a = tanh(μ + σ ε) of a batch, with log π(a|s), and
/// what the actor's backward pass needs.
pub(super) struct ActorSample {
    body: SliceMlp,
    mu: SliceMlp,
    log_std: SliceMlp,
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
    pub(super) fn new(actor: &Actor, obs: &[f32], eps: &[f32], rows: usize) -> anyhow::Result<Self> {
        let (body, mu, log_std) = (relu_mlp(&actor.body)?, linear(&actor.mu)?, linear(&actor.log_std)?);
        let features = body.forward(obs.to_vec(), rows);
        let mu_pass = mu.forward(features.output().to_vec(), rows);
        let log_std_pass = log_std.forward(features.output().to_vec(), rows);
        let act_dim = eps.len() / rows.max(1);
        let mut actions = Vec::with_capacity(eps.len());
        let mut log_pi = Vec::with_capacity(rows);
        for ((mu, raw), eps) in mu_pass.output().chunks_exact(act_dim).zip(log_std_pass.output().chunks_exact(act_dim)).zip(eps.chunks_exact(act_dim)) {
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
        Ok(Self { body, mu, log_std, features, mu_pass, log_std_pass, eps: eps.to_vec(), actions, log_pi, act_dim })
    }

    /// The actor's gradients (body, μ, log σ: its `named_vars` order) from ∂L/∂a and the weight
    /// `log_pi_weight` of Σ log π in the loss.
    fn backward(self, d_actions: &[f32], log_pi_weight: f32) -> Vec<Option<Vec<f32>>> {
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
        let mu = self.mu.backward(&self.mu_pass, d_mu, true, true);
        let log_std = self.log_std.backward(&self.log_std_pass, d_log_std, true, true);
        let mut d_features = mu.input.clone().unwrap_or_default();
        d_features.iter_mut().zip(log_std.input.iter().flatten()).for_each(|(d, e)| *d += e);
        let body = self.body.backward(&self.features, d_features, true, false);
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
    obs.chunks_exact(o.max(1)).zip(actions.chunks_exact(a.max(1))).flat_map(|(o, a)| o.iter().chain(a).copied()).collect()
}

/// The critics' loss ½ Σᵢ MSE(Qᵢ, y) with y = r + γ (1 − done) (min Q'(s', a') − α log π(a'|s')),
/// and its gradient (Q₁'s layers, then Q₂'s).
pub(super) fn critic_gradient(sac: &Sac, batch: &Batch, eps_next: &[f32], alpha: f32) -> anyhow::Result<LossGradient> {
    let b = batch.rewards.len();
    let next = ActorSample::new(&sac.actor, &batch.next_obs, eps_next, b)?;
    let next_input = joined(&batch.next_obs, &next.actions, b);
    let (t1, t2) = (relu_mlp(&sac.critic_target.q1)?, relu_mlp(&sac.critic_target.q2)?);
    let (t1, t2) = (t1.forward(next_input.clone(), b), t2.forward(next_input, b));
    let input = joined(&batch.obs, &batch.actions, b);
    let (q1, q2) = (relu_mlp(&sac.critic.q1)?, relu_mlp(&sac.critic.q2)?);
    let (q1_pass, q2_pass) = (q1.forward(input.clone(), b), q2.forward(input, b));
    let per_sample = 1.0 / b.max(1) as f32;
    let (mut loss, mut d_q1, mut d_q2) = (0.0, Vec::with_capacity(b), Vec::with_capacity(b));
    for i in 0..b {
        let next_q = t1.output()[i].min(t2.output()[i]) - alpha * next.log_pi[i];
        let y = batch.rewards[i] + (1.0 - batch.dones[i]) * next_q * sac.config.gamma;
        let (e1, e2) = (q1_pass.output()[i] - y, q2_pass.output()[i] - y);
        loss += 0.5 * (e1 * e1 + e2 * e2) * per_sample;
        d_q1.push(e1 * per_sample);
        d_q2.push(e2 * per_sample);
    }
    let gradients = q1.backward(&q1_pass, d_q1, true, false).into_flat().chain(q2.backward(&q2_pass, d_q2, true, false).into_flat()).map(Some).collect();
    Ok(LossGradient { loss, gradients })
}

/// The actor's loss E[α log π(a|s) − min Q(s, a)] over `sample` (taken from `obs`) through the
/// critics as they are now, and its gradient.
pub(super) fn actor_gradient(sac: &Sac, obs: &[f32], sample: ActorSample, alpha: f32) -> anyhow::Result<ActorGradient> {
    let b = sample.log_pi.len();
    let act_dim = sample.act_dim;
    let input = joined(obs, &sample.actions, b);
    let (q1, q2) = (relu_mlp(&sac.critic.q1)?, relu_mlp(&sac.critic.q2)?);
    let (q1_pass, q2_pass) = (q1.forward(input.clone(), b), q2.forward(input, b));
    let per_sample = 1.0 / b.max(1) as f32;
    let (mut loss, mut d_q1, mut d_q2) = (0.0, Vec::with_capacity(b), Vec::with_capacity(b));
    for i in 0..b {
        let (a, c) = (q1_pass.output()[i], q2_pass.output()[i]);
        loss += (alpha * sample.log_pi[i] - a.min(c)) * per_sample;
        // −min(Q₁, Q₂): the gradient goes to the smaller, half to each when they are equal.
        let share = |mine: f32, other: f32| if mine < other { 1.0 } else if mine == other { 0.5 } else { 0.0 };
        d_q1.push(-per_sample * share(a, c));
        d_q2.push(-per_sample * share(c, a));
    }
    let d_in1 = q1.backward(&q1_pass, d_q1, false, true).input.unwrap_or_default();
    let d_in2 = q2.backward(&q2_pass, d_q2, false, true).input.unwrap_or_default();
    let width = d_in1.len() / b.max(1);
    // ∂L/∂a: the action columns of the critics' input gradients.
    let d_actions: Vec<f32> = d_in1
        .chunks_exact(width.max(1))
        .zip(d_in2.chunks_exact(width.max(1)))
        .flat_map(|(r1, r2)| (width - act_dim..width).map(move |k| r1[k] + r2[k]))
        .collect();
    let entropy = -sample.log_pi.iter().sum::<f32>() * per_sample;
    let gradients = sample.backward(&d_actions, alpha * per_sample);
    Ok(ActorGradient { loss: LossGradient { loss, gradients }, entropy })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::classic::ClassicPendulum;
    use crate::sac::SacConfig;
    use crate::sac::update::ActorPass;
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
        let config = SacConfig { hidden: vec![16, 16], learning_starts: 64, batch_size: 32, learning_rate: 3e-3, ..SacConfig::default() };
        let mut sac = Sac::new(config, env.observation_space().clone(), env.action_space().clone(), 4).unwrap();
        sac.learn(&mut env, 400, &mut |_: &crate::UpdateStats, _: &dyn crate::Agent| Ok(crate::Flow::Continue)).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let batch = sac.buffer.as_ref().unwrap().sample(32, &mut rng, None);
        let (eps, eps_next) = (sac.noise(32), sac.noise(32));
        (sac, batch, eps, eps_next)
    }

    #[test]
    fn the_fused_critic_gradient_is_the_graphs() {
        let (sac, batch, _, eps_next) = trained_model_and_batch();
        let alpha = sac.ent_coef().unwrap();
        assert!((alpha - 1.0).abs() > 0.01, "α never moved: the test would not weigh the entropy term");
        let ours = critic_gradient(&sac, &batch, &eps_next, alpha).unwrap();
        let (theirs, _) = sac.critic_gradient_graph(&batch, &eps_next, alpha).unwrap();
        agree(&ours, &theirs, "critic");
    }

    #[test]
    fn the_fused_actor_gradient_is_the_graphs() {
        let (sac, batch, eps, _) = trained_model_and_batch();
        let alpha = sac.ent_coef().unwrap();
        let b = batch.rewards.len();
        let sample = ActorSample::new(&sac.actor, &batch.obs, &eps, b).unwrap();
        let ActorPass::Graph { actions, log_pi } = ActorPass::graph(&sac, &batch.obs, &eps).unwrap() else { unreachable!() };
        let theirs_log_pi: Vec<f32> = log_pi.to_vec1().unwrap();
        sample.log_pi.iter().zip(&theirs_log_pi).for_each(|(a, b)| close(*a, *b, "log π"));
        let ours = actor_gradient(&sac, &batch.obs, sample, alpha).unwrap();
        let features = Tensor::from_vec(batch.obs.clone(), (b, sac.observation_space.dim()), &Device::Cpu).unwrap();
        let theirs = sac.actor_gradient_graph(&actions, &log_pi, &features, alpha).unwrap();
        agree(&ours.loss, &theirs.loss, "actor");
        close(ours.entropy, theirs.entropy, "entropy");
    }
}
