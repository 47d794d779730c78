//! One SAC gradient step on a minibatch from the replay buffer: the entropy coefficient, the
//! twin critics towards the soft Bellman target, the actor, then the targets by Polyak.

use candle_core::{Device, Tensor};

use super::networks::polyak_update;
use super::{Sac, SacLosses};

impl Sac {
    /// One gradient step of every part; `None` when a loss or gradient was not finite (that
    /// part's weights stay as they were, and the step counts as skipped).
    pub fn gradient_step(&mut self) -> anyhow::Result<Option<SacLosses>> {
        let Some(buffer) = &self.buffer else { return Ok(None) };
        if buffer.is_empty() {
            return Ok(None);
        }
        let her = self.goal.as_ref().filter(|_| self.config.her_goals > 0).map(|g| (g, self.config.her_goals));
        let batch = buffer.sample(self.config.batch_size, &mut self.rng, her);
        let b = batch.rewards.len();
        let dev = Device::Cpu;
        let (obs, next_obs) = (self.batch(&batch.obs)?, self.batch(&batch.next_obs)?);
        let actions = Tensor::from_vec(batch.actions, (b, self.act_dim()), &dev)?;
        let rewards = Tensor::from_vec(batch.rewards, b, &dev)?;
        let not_done = (Tensor::from_vec(batch.dones, b, &dev)?.neg()? + 1.0)?;
        let mut applied = true;

        // α: J(α) = E[−α (log π(a|s) + H̄)], stepped on log α; this step uses α before it.
        let eps = self.noise(b)?;
        let (actions_pi, log_pi) = self.actor.sample(&obs, &eps)?;
        let alpha = self.ent_coef()?;
        let target_entropy = self.config.target_entropy.unwrap_or(-(self.act_dim() as f32));
        let mut ent_coef_loss = f32::NAN;
        if self.config.learn_ent_coef {
            let loss = (self.log_ent_coef.as_tensor().broadcast_mul(&(log_pi.detach() + target_entropy as f64)?)?.mean_all()?).neg()?;
            ent_coef_loss = loss.to_scalar::<f32>()?;
            applied &= self.ent_optimizer.step(&loss.backward()?, None)?.applied;
        }

        // Critics: y = r + γ (1 − done) (min Q'(s', a') − α log π(a'|s')), a' ~ π(·|s').
        let eps_next = self.noise(b)?;
        let (next_actions, next_log_pi) = self.actor.sample(&next_obs, &eps_next)?;
        let next_q = (self.critic_target.min_q(&next_obs, &next_actions.detach())? - (next_log_pi.detach() * alpha as f64)?)?;
        let target = (rewards + (not_done * next_q)? * self.config.gamma as f64)?.detach();
        let critic_features = self.critic.encoder.forward(&obs)?;
        let (q1, q2) = self.critic.q_of(&critic_features, &actions)?;
        // ½ Σᵢ MSE(Qᵢ, y), as SB3.
        let critic_loss = ((((&q1 - &target)?.sqr()?.mean_all()? + (&q2 - &target)?.sqr()?.mean_all()?)?) * 0.5)?;
        applied &= self.critic_optimizer.step(&critic_loss.backward()?, None)?.applied;

        // Actor: J(π) = E[α log π(a|s) − min Q(s, a)], a ~ π(·|s) reparameterised (the critics'
        // gradients of this loss are not applied: only the actor's optimiser steps, so the
        // critics' image features are reused, detached, rather than computed again).
        let q_pi = self.critic.min_q_of(&critic_features.detach(), &actions_pi)?;
        let actor_loss = ((&log_pi * alpha as f64)? - q_pi)?.mean_all()?;
        applied &= self.actor_optimizer.step(&actor_loss.backward()?, None)?.applied;

        self.gradient_steps += 1;
        if self.gradient_steps % self.config.target_update_interval as u64 == 0 {
            polyak_update(&self.critic_target.named_vars("target"), &self.critic.named_vars("critic"), self.config.tau)?;
        }
        if !applied {
            return Ok(None);
        }
        Ok(Some(SacLosses {
            actor_loss: actor_loss.to_scalar::<f32>()?,
            critic_loss: critic_loss.to_scalar::<f32>()?,
            ent_coef: alpha,
            ent_coef_loss,
            entropy: -log_pi.mean_all()?.to_scalar::<f32>()?,
            gradient_steps: self.gradient_steps,
        }))
    }
}
