//! One SAC gradient step on a minibatch from the replay buffer: the entropy coefficient, the
//! twin critics towards the soft Bellman target, the actor, then the targets by Polyak.
//!
//! Each loss's gradient comes from candle's graph, or for networks on flat observations from
//! the same loss written out over slices (`fused.rs`, checked against the graph): the step
//! itself, the optimisers and the order are one.

use std::sync::Arc;

use candle_core::{Device, Tensor};

use super::fused::{self, ActorGradient, ActorNets, ActorSample, CriticNets, LossGradient, Part, StepNets};
use super::{Sac, SacLosses};
use crate::nn::flat_gradients;
use crate::off_policy::networks::polyak_update;
use crate::replay_buffer::{Batch, Draw, ReplayBuffer};
use crate::threads::Helper;
use twinbots_api::GoalSpec;

impl Sac {
    /// `n` gradient steps of every part, each one's losses handed to `each` in turn (`None`
    /// when a loss or gradient was not finite: that part's weights stay as they were, and the
    /// step counts as skipped). Over slices, one helper thread serves the `n` steps: a thread
    /// started per step made the step wait for it.
    pub fn run_gradient_steps(&mut self, n: usize, each: &mut dyn FnMut(Option<SacLosses>)) -> anyhow::Result<()> {
        // The buffer is lent to the steps' threads while the steps change the rest.
        let Some(buffer) = self.buffer.take() else {
            (0..n).for_each(|_| each(None));
            return Ok(());
        };
        let steps = self.run_gradient_steps_on(&buffer, n, each);
        self.buffer = Some(buffer);
        steps
    }

    /// A step's minibatch, its noise and α, drawn in this order.
    fn next_minibatch(&mut self, buffer: &ReplayBuffer, goal: Option<&GoalSpec>) -> anyhow::Result<Minibatch> {
        let draws = buffer.draw(self.config.off_policy.batch_size, &mut self.rng, goal.map(|_| self.config.her_goals));
        let b = draws.len();
        let (eps, eps_next) = (self.noise(b), self.noise(b));
        Ok(Minibatch { draws, eps, eps_next, alpha: self.ent_coef()? })
    }

    fn run_gradient_steps_on(
        &mut self,
        buffer: &ReplayBuffer,
        n: usize,
        each: &mut dyn FnMut(Option<SacLosses>),
    ) -> anyhow::Result<()> {
        if buffer.is_empty() {
            (0..n).for_each(|_| each(None));
            return Ok(());
        }
        let goal = self.goal.filter(|_| self.config.her_goals > 0);
        // The observation statistics hold still over the steps: only the env's steps move them.
        let obs_rms = self.state.obs_rms.clone();
        // Rows relabelled (HER) and normalised with the statistics in force.
        let assemble = |draws: &[Draw]| {
            let mut batch = buffer.assemble(draws, goal.as_ref());
            batch.obs = crate::normalize::normalized(obs_rms.as_ref(), &batch.obs);
            batch.next_obs = crate::normalize::normalized(obs_rms.as_ref(), &batch.next_obs);
            batch
        };
        if !fused::applies(self) {
            for _ in 0..n {
                let Minibatch { draws, eps, eps_next, alpha } = self.next_minibatch(buffer, goal.as_ref())?;
                each(self.gradient_step_graph(assemble(&draws), eps, eps_next, alpha)?);
            }
            return Ok(());
        }
        // Over slices, each half of a minibatch on its own thread (`threads::halves`): its rows
        // assembled, the actor's samples and the critics' gradient; then, after the critics'
        // step, the actor's gradient.
        let gamma = self.config.off_policy.gamma;
        let work = |job: Job| match job {
            Job::Critic { nets, draws, eps, eps_next, alpha, of } => {
                let part = Part { batch: assemble(&draws), eps, eps_next, of };
                let (sample, gradient) = fused::critic_part(&nets, &part, alpha, gamma);
                Answer::Critic(sample, gradient, part.batch.obs)
            }
            Job::Actor { nets, critic, obs, sample, alpha, of } => {
                Answer::Actor(fused::actor_part(&nets.actor, &critic, &obs, sample, alpha, of))
            }
        };
        crate::threads::with_helper(work, |helper| {
            for _ in 0..n {
                let minibatch = self.next_minibatch(buffer, goal.as_ref())?;
                each(self.step_over_slices(helper, &work, minibatch)?);
            }
            Ok(())
        })
    }

    /// One step over slices, the minibatch's second half on `helper`.
    fn step_over_slices(
        &mut self,
        helper: Option<&Helper<Job, Answer>>,
        work: &impl Fn(Job) -> Answer,
        Minibatch { draws, eps, eps_next, alpha }: Minibatch,
    ) -> anyhow::Result<Option<SacLosses>> {
        let b = draws.len();
        let nets = Arc::new(StepNets {
            actor: ActorNets::read(&self.actor)?,
            critic: CriticNets::read(&self.critic)?,
            target: CriticNets::read(&self.critic_target)?,
        });
        let jobs = crate::threads::halves(b)
            .iter()
            .map(|r| Job::Critic {
                nets: nets.clone(),
                draws: fused::rows_of(&draws, b, r),
                eps: fused::rows_of(&eps, b, r),
                eps_next: fused::rows_of(&eps_next, b, r),
                alpha,
                of: b,
            })
            .collect();
        let (mut samples, mut critic) = (Vec::new(), Vec::new());
        for answer in crate::threads::share(helper, work, jobs)? {
            let Answer::Critic(sample, gradient, obs) = answer else {
                anyhow::bail!("a critic job answered as the actor's")
            };
            samples.push((sample, obs));
            critic.push(gradient);
        }
        let log_pi: Vec<f32> = samples.iter().flat_map(|(s, _)| s.log_pi.iter().copied()).collect();
        let (mut applied, ent_coef_loss) = self.step_ent_coef(&log_pi)?;
        let mut critic = fused::sum(critic);
        applied &= self.critic_optimizer.step_flat(std::mem::take(&mut critic.gradients), None)?.applied;

        let critic_now = Arc::new(CriticNets::read(&self.critic)?);
        let jobs = samples
            .into_iter()
            .map(|(sample, obs)| Job::Actor {
                nets: nets.clone(),
                critic: critic_now.clone(),
                obs,
                sample,
                alpha,
                of: b,
            })
            .collect();
        let (mut actor, mut entropy) = (Vec::new(), 0.0);
        for answer in crate::threads::share(helper, work, jobs)? {
            let Answer::Actor(part) = answer else { anyhow::bail!("an actor job answered as the critics'") };
            entropy += part.entropy;
            actor.push(part.loss);
        }
        let actor = ActorGradient { loss: fused::sum(actor), entropy };
        self.finish_step(critic.loss, actor, (applied, ent_coef_loss), alpha)
    }

    /// The step through candle's graph (camera policies).
    fn gradient_step_graph(
        &mut self,
        batch: Batch,
        eps: Vec<f32>,
        eps_next: Vec<f32>,
        alpha: f32,
    ) -> anyhow::Result<Option<SacLosses>> {
        let (actions, log_pi) = self.actor_samples_graph(&batch.obs, &eps)?;
        let (mut applied, ent_coef_loss) = self.step_ent_coef(&log_pi.to_vec1::<f32>()?)?;
        let (critic, features) = self.critic_gradient_graph(&batch, &eps_next, alpha)?;
        applied &= self.critic_optimizer.step_flat(critic.gradients, None)?.applied;
        // The critics' image features are reused, detached, rather than computed again.
        let actor = self.actor_gradient_graph(&actions, &log_pi, &features, alpha)?;
        self.finish_step(critic.loss, actor, (applied, ent_coef_loss), alpha)
    }

    /// α: J(α) = E[−α (log π(a|s) + H̄)], stepped on log α (the step uses α before it).
    /// Whether the step was applied (true when α is not learnt), and J(α) (NaN then).
    fn step_ent_coef(&mut self, log_pi: &[f32]) -> anyhow::Result<(bool, f32)> {
        if !self.config.learn_ent_coef {
            return Ok((true, f32::NAN));
        }
        let target_entropy = self.config.target_entropy.unwrap_or(-(self.act_dim() as f32));
        let mean = log_pi.iter().map(|l| l + target_entropy).sum::<f32>() / log_pi.len().max(1) as f32;
        let log_alpha = self.log_ent_coef.as_tensor().to_vec1::<f32>()?[0];
        Ok((self.ent_optimizer.step_flat(vec![Some(vec![-mean])], None)?.applied, -log_alpha * mean))
    }

    /// The actor's step, the targets' Polyak update and the step's figures.
    fn finish_step(
        &mut self,
        critic_loss: f32,
        actor: ActorGradient,
        (mut applied, ent_coef_loss): (bool, f32),
        alpha: f32,
    ) -> anyhow::Result<Option<SacLosses>> {
        applied &= self.actor_optimizer.step_flat(actor.loss.gradients, None)?.applied;
        self.gradient_steps += 1;
        if self.gradient_steps.is_multiple_of(self.config.target_update_interval as u64) {
            polyak_update(
                &self.critic_target.named_vars("target"),
                &self.critic.named_vars("critic"),
                self.config.off_policy.tau,
            )?;
        }
        if !applied {
            return Ok(None);
        }
        Ok(Some(SacLosses {
            actor_loss: actor.loss.loss,
            critic_loss,
            ent_coef: alpha,
            ent_coef_loss,
            entropy: actor.entropy,
            gradient_steps: self.gradient_steps,
        }))
    }

    /// The critics' loss ½ Σᵢ MSE(Qᵢ, y) (SB3's) and gradient through candle's graph, and the
    /// critics' features of the observations (detached).
    pub(super) fn critic_gradient_graph(
        &self,
        batch: &Batch,
        eps_next: &[f32],
        alpha: f32,
    ) -> anyhow::Result<(LossGradient, Tensor)> {
        let (b, dev) = (batch.rewards.len(), Device::Cpu);
        let rows = |v: &[f32], width: usize| Tensor::from_vec(v.to_vec(), (b, width), &dev);
        let (obs, next_obs) = (
            rows(&batch.obs, self.state.observation_space.dim())?,
            rows(&batch.next_obs, self.state.observation_space.dim())?,
        );
        let actions = rows(&batch.actions, self.act_dim())?;
        let rewards = Tensor::from_vec(batch.rewards.clone(), b, &dev)?;
        let not_done = (Tensor::from_vec(batch.dones.clone(), b, &dev)?.neg()? + 1.0)?;
        let (next_actions, next_log_pi) = self.actor.sample(&next_obs, &rows(eps_next, self.act_dim())?)?;
        let next_q =
            (self.critic_target.min_q(&next_obs, &next_actions.detach())? - (next_log_pi.detach() * alpha as f64)?)?;
        let target = (rewards + (not_done * next_q)? * self.config.off_policy.gamma as f64)?.detach();
        let features = self.critic.encoder.forward(&obs)?;
        let (q1, q2) = self.critic.q_of(&features, &actions)?;
        let loss = ((((&q1 - &target)?.sqr()?.mean_all()? + (&q2 - &target)?.sqr()?.mean_all()?)?) * 0.5)?;
        let vars: Vec<_> = self.critic.named_vars("critic").into_iter().map(|(_, v)| v).collect();
        Ok((
            LossGradient { loss: loss.to_scalar()?, gradients: flat_gradients(&vars, &loss.backward()?)? },
            features.detach(),
        ))
    }

    /// The actor's loss and gradient through candle's graph, over its samples `actions` with
    /// their `log_pi`, read by the critics from their `features` of the observations.
    pub(super) fn actor_gradient_graph(
        &self,
        actions: &Tensor,
        log_pi: &Tensor,
        features: &Tensor,
        alpha: f32,
    ) -> anyhow::Result<ActorGradient> {
        let q_pi = self.critic.min_q_of(features, actions)?;
        let loss = ((log_pi * alpha as f64)? - q_pi)?.mean_all()?;
        let vars: Vec<_> = self.actor.named_vars().into_iter().map(|(_, v)| v).collect();
        Ok(ActorGradient {
            loss: LossGradient { loss: loss.to_scalar()?, gradients: flat_gradients(&vars, &loss.backward()?)? },
            entropy: -log_pi.mean_all()?.to_scalar::<f32>()?,
        })
    }
}

/// A gradient step's draws from the replay buffer, its noise for the actor's samples of the
/// observations and of the next ones, and α.
struct Minibatch {
    draws: Vec<Draw>,
    eps: Vec<f32>,
    eps_next: Vec<f32>,
    alpha: f32,
}

/// A job of a step over slices, for either thread: a part's critics' gradient (with the
/// networks' numbers, the part's draws from the buffer and its noise), or a part's actor's
/// gradient (with the critics' numbers after their step, the part's observations and samples).
/// Each carries the step's α and its minibatch's size (`of`).
enum Job {
    Critic { nets: Arc<StepNets>, draws: Vec<Draw>, eps: Vec<f32>, eps_next: Vec<f32>, alpha: f32, of: usize },
    Actor { nets: Arc<StepNets>, critic: Arc<CriticNets>, obs: Vec<f32>, sample: ActorSample, alpha: f32, of: usize },
}

enum Answer {
    /// The part's actor samples, critics' gradient, and observations (normalised).
    Critic(ActorSample, LossGradient, Vec<f32>),
    Actor(ActorGradient),
}

impl Sac {
    /// The actor's reparameterised samples of the rows of `obs` (normalised) with the noise
    /// `eps`, and their log π, through candle's graph (with their gradients).
    pub(super) fn actor_samples_graph(&self, obs: &[f32], eps: &[f32]) -> anyhow::Result<(Tensor, Tensor)> {
        let (dev, act_dim) = (Device::Cpu, self.act_dim());
        let rows = eps.len() / act_dim.max(1);
        let obs = Tensor::from_vec(obs.to_vec(), (rows, self.state.observation_space.dim()), &dev)?;
        Ok(self.actor.sample(&obs, &Tensor::from_vec(eps.to_vec(), (rows, act_dim), &dev)?)?)
    }
}
