//! One SAC gradient step on a minibatch from the replay buffer: the entropy coefficient, the
//! twin critics towards the soft Bellman target, the actor, then the targets by Polyak.
//!
//! Each loss's gradient comes from candle's graph, or for networks on flat observations from
//! the same loss written out over slices (`fused.rs`, checked against the graph): the step
//! itself, the optimisers and the order are one.

use candle_core::{Device, Tensor};

use super::networks::polyak_update;
use super::{Sac, SacLosses};
use crate::nn::flat_gradients;
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

impl Sac {
    /// One gradient step of every part; `None` when a loss or gradient was not finite (that
    /// part's weights stay as they were, and the step counts as skipped).
    pub fn gradient_step(&mut self) -> anyhow::Result<Option<SacLosses>> {
        let Some(buffer) = &self.buffer else { return Ok(None) };
        if buffer.is_empty() {
            return Ok(None);
        }
        let her = self.goal.as_ref().filter(|_| self.config.her_goals > 0).map(|g| (g, self.config.her_goals));
        let mut batch = buffer.sample(self.config.batch_size, &mut self.rng, her);
        batch.obs = crate::normalize::normalized(self.obs_rms.as_ref(), &batch.obs);
        batch.next_obs = crate::normalize::normalized(self.obs_rms.as_ref(), &batch.next_obs);
        let b = batch.rewards.len();
        let eps = self.noise(b);
        let eps_next = self.noise(b);
        let alpha = self.ent_coef()?;
        let fused = super::fused::applies(self);
        let mut applied = true;

        // The actor's reparameterised samples a ~ π(·|s), for α and the actor's loss.
        let actor_pass = if fused { ActorPass::Slices(super::fused::ActorSample::new(&self.actor, &batch.obs, &eps, b)?) } else { ActorPass::graph(self, &batch.obs, &eps)? };
        let log_pi = actor_pass.log_pi()?;

        // α: J(α) = E[−α (log π(a|s) + H̄)], stepped on log α; this step uses α before it.
        let mut ent_coef_loss = f32::NAN;
        if self.config.learn_ent_coef {
            let target_entropy = self.config.target_entropy.unwrap_or(-(self.act_dim() as f32));
            let mean = log_pi.iter().map(|l| l + target_entropy).sum::<f32>() / b.max(1) as f32;
            let log_alpha = self.log_ent_coef.as_tensor().to_vec1::<f32>()?[0];
            ent_coef_loss = -log_alpha * mean;
            applied &= self.ent_optimizer.step_flat(vec![Some(vec![-mean])], None)?.applied;
        }

        // Critics: y = r + γ (1 − done) (min Q'(s', a') − α log π(a'|s')), a' ~ π(·|s').
        let (critic, critic_features) = if fused {
            (super::fused::critic_gradient(self, &batch, &eps_next, alpha)?, None)
        } else {
            let (critic, features) = self.critic_gradient_graph(&batch, &eps_next, alpha)?;
            (critic, Some(features))
        };
        applied &= self.critic_optimizer.step_flat(critic.gradients, None)?.applied;

        // Actor: J(π) = E[α log π(a|s) − min Q(s, a)], a ~ π(·|s) reparameterised, through the
        // critics just stepped (their gradients of this loss are not applied, so the critics'
        // image features are reused, detached, rather than computed again).
        let actor = match (actor_pass, &critic_features) {
            (ActorPass::Graph { actions, log_pi }, Some(features)) => self.actor_gradient_graph(&actions, &log_pi, features, alpha)?,
            (ActorPass::Slices(sample), _) => super::fused::actor_gradient(self, &batch.obs, sample, alpha)?,
            (ActorPass::Graph { .. }, None) => anyhow::bail!("the critics' features are missing"),
        };
        applied &= self.actor_optimizer.step_flat(actor.loss.gradients, None)?.applied;

        self.gradient_steps += 1;
        if self.gradient_steps % self.config.target_update_interval as u64 == 0 {
            polyak_update(&self.critic_target.named_vars("target"), &self.critic.named_vars("critic"), self.config.tau)?;
        }
        if !applied {
            return Ok(None);
        }
        Ok(Some(SacLosses {
            actor_loss: actor.loss.loss,
            critic_loss: critic.loss,
            ent_coef: alpha,
            ent_coef_loss,
            entropy: actor.entropy,
            gradient_steps: self.gradient_steps,
        }))
    }

    /// The critics' loss ½ Σᵢ MSE(Qᵢ, y) (SB3's) and gradient through candle's graph, and the
    /// critics' features of the observations (detached).
    pub(super) fn critic_gradient_graph(&self, batch: &Batch, eps_next: &[f32], alpha: f32) -> anyhow::Result<(LossGradient, Tensor)> {
        let (b, dev) = (batch.rewards.len(), Device::Cpu);
        let rows = |v: &[f32], width: usize| Tensor::from_vec(v.to_vec(), (b, width), &dev);
        let (obs, next_obs) = (rows(&batch.obs, self.observation_space.dim())?, rows(&batch.next_obs, self.observation_space.dim())?);
        let actions = rows(&batch.actions, self.act_dim())?;
        let rewards = Tensor::from_vec(batch.rewards.clone(), b, &dev)?;
        let not_done = (Tensor::from_vec(batch.dones.clone(), b, &dev)?.neg()? + 1.0)?;
        let (next_actions, next_log_pi) = self.actor.sample(&next_obs, &rows(eps_next, self.act_dim())?)?;
        let next_q = (self.critic_target.min_q(&next_obs, &next_actions.detach())? - (next_log_pi.detach() * alpha as f64)?)?;
        let target = (rewards + (not_done * next_q)? * self.config.gamma as f64)?.detach();
        let features = self.critic.encoder.forward(&obs)?;
        let (q1, q2) = self.critic.q_of(&features, &actions)?;
        let loss = ((((&q1 - &target)?.sqr()?.mean_all()? + (&q2 - &target)?.sqr()?.mean_all()?)?) * 0.5)?;
        let vars: Vec<_> = self.critic.named_vars("critic").into_iter().map(|(_, v)| v).collect();
        Ok((LossGradient { loss: loss.to_scalar()?, gradients: flat_gradients(&vars, &loss.backward()?)? }, features.detach()))
    }

    /// The actor's loss and gradient through candle's graph, over its samples `actions` with
    /// their `log_pi`, read by the critics from their `features` of the observations.
    pub(super) fn actor_gradient_graph(&self, actions: &Tensor, log_pi: &Tensor, features: &Tensor, alpha: f32) -> anyhow::Result<ActorGradient> {
        let q_pi = self.critic.min_q_of(features, actions)?;
        let loss = ((log_pi * alpha as f64)? - q_pi)?.mean_all()?;
        let vars: Vec<_> = self.actor.named_vars().into_iter().map(|(_, v)| v).collect();
        Ok(ActorGradient {
            loss: LossGradient { loss: loss.to_scalar()?, gradients: flat_gradients(&vars, &loss.backward()?)? },
            entropy: -log_pi.mean_all()?.to_scalar::<f32>()?,
        })
    }
}

/// The actor's samples of a step: as graph tensors (with their gradients), or over slices.
pub(super) enum ActorPass {
    Graph { actions: Tensor, log_pi: Tensor },
    Slices(super::fused::ActorSample),
}

impl ActorPass {
    pub(super) fn graph(sac: &Sac, obs: &[f32], eps: &[f32]) -> anyhow::Result<Self> {
        let (dev, act_dim) = (Device::Cpu, sac.act_dim());
        let rows = eps.len() / act_dim.max(1);
        let obs = Tensor::from_vec(obs.to_vec(), (rows, sac.observation_space.dim()), &dev)?;
        let (actions, log_pi) = sac.actor.sample(&obs, &Tensor::from_vec(eps.to_vec(), (rows, act_dim), &dev)?)?;
        Ok(ActorPass::Graph { actions, log_pi })
    }

    /// log π(a|s) of each sample.
    fn log_pi(&self) -> anyhow::Result<Vec<f32>> {
        Ok(match self {
            ActorPass::Graph { log_pi, .. } => log_pi.to_vec1()?,
            ActorPass::Slices(sample) => sample.log_pi.clone(),
        })
    }
}
