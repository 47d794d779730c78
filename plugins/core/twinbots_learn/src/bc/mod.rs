//! Behaviour cloning: a policy fitted, as supervised learning, to the actions of demonstrations
//! — any LeRobot dataset whose observation and action features match the robot's (`twinbots
//! demos` writes them from a scripted program or a trained policy). Continuous actions are
//! regressed in the action box's [−1, 1] (mean squared error of tanh(net(s)), the squashed
//! head SAC and TD3 export); discrete ones are classified (cross-entropy of the logits, arg max
//! to act). The env is not stepped to learn: it is where the evaluations run, so the cloned
//! policy is judged with the twin's figures like any other.
//!
//! `timesteps` count the demonstration frames learnt from (batch size × gradient steps), the
//! one budget `train` gives every algorithm; a row of `progress.csv` every `log_interval`
//! gradient steps. Minibatches are drawn from a stream of the run's seed, saved with the
//! model, so a resumed run takes the uninterrupted one's steps.

mod config;
mod model_file;

use std::path::Path;
use std::time::Instant;

use candle_core::{DType, Device, Tensor, Var};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use twinbots_api::spaces::Space;
use twinbots_api::{TaskSpec, VecEnv};
use twinbots_dataset::Demonstrations;

pub use config::BcConfig;

use crate::agent::{Agent, LoadAgent};
use crate::callbacks::Callback;
use crate::learner::{Algorithm, Learner, checked_table, config_from, load_learner};
use crate::learner_state::LearnerState;
use crate::model_io::ModelError;
use crate::nn::{Adam, AdamConfig};
use crate::normalize::RunningMeanStd;
use crate::off_policy::networks::ReluMlp;
use crate::policy_net::{Activation, InputEncoding, PolicyHead, PolicyNet};
use crate::stats::{TrainingEnd, UpdateStats, figures};

/// The name `--algo` and the settings' `[bc]` table use.
pub const NAME: &str = "bc";
/// `model.json`'s `algorithm`.
pub const SAVED_AS: &str = "BC";
/// Its figure in `progress.csv`: the mean loss of the row's gradient steps.
pub const TRAIN_FIGURES: &[&str] = &["loss"];
/// A feature's standard deviation in the demonstrations is taken as at least this: one that
/// never changed there (a constant goal height) would otherwise scale the first change the
/// policy meets by 1/√1e-8.
const MIN_STD: f64 = 1e-3;
/// The policy's name in `model.safetensors` and the exported graph (`policy.0.weight`).
const POLICY: &str = "policy";

/// Behaviour cloning's line in [`crate::algos::ALGOS`].
pub const ALGORITHM: Algorithm = Algorithm {
    name: NAME,
    saved_as: SAVED_AS,
    summary: "Behaviour cloning: a policy fitted to a LeRobot dataset's demonstrations (--demos DIR)",
    continuous_only: false,
    serves: false,
    config: |keys, _arenas| checked_table::<BcConfig>(keys, NAME),
    new: |config, spec, seed| Ok(Box::new(Bc::for_task(config_from(config, NAME)?, spec, seed)?)),
    load: load_learner::<Bc>,
};

/// A behaviour-cloning learner: the policy, its optimiser, the minibatch stream and the
/// demonstrations (read from `config.demos` when it first learns).
pub struct Bc {
    pub config: BcConfig,
    pub state: LearnerState,
    /// The action's tanh pre-image (continuous) or the logits (discrete).
    pub policy: ReluMlp,
    /// Gradient steps taken.
    pub gradient_steps: u64,
    /// The mean loss of the last row's gradient steps.
    pub last_loss: f32,
    optimizer: Adam,
    rng: ChaCha8Rng,
    demos: Option<Demos>,
    /// Frames of the dataset the model learnt from (checked when a resumed run reads it again).
    learnt_frames: Option<usize>,
}

/// The demonstrations as the policy learns from them: observations as recorded, actions as
/// targets (in [−1, 1], or the class index).
struct Demos {
    states: Vec<f32>,
    targets: Vec<f32>,
    frames: usize,
}

impl Bc {
    /// A fresh policy for these spaces (the demonstrations are read when it learns).
    pub fn new(config: BcConfig, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self> {
        crate::tuning::for_small_networks();
        config.validate()?;
        anyhow::ensure!(
            observation_space.image_shape().is_none(),
            "BC does not read camera images ({observation_space}): its datasets hold state only"
        );
        let outputs = match &action_space {
            Space::Box { low, high } => {
                anyhow::ensure!(
                    low.iter().chain(high).all(|x| x.is_finite()),
                    "BC needs a bounded action box, not {action_space}"
                );
                low.len()
            }
            Space::Discrete { n } => *n,
            other => anyhow::bail!("BC learns Box or Discrete actions, not {other}"),
        };
        let obs_dim = observation_space.dim();
        let mut init = ChaCha8Rng::seed_from_u64(seed);
        let sizes: Vec<usize> =
            std::iter::once(obs_dim).chain(config.hidden.iter().copied()).chain(std::iter::once(outputs)).collect();
        let policy = ReluMlp::new(&sizes, false, &mut init, &Device::Cpu)?;
        let optimizer = Adam::new(
            policy.vars(POLICY).into_iter().map(|(_, v)| v).collect(),
            AdamConfig { learning_rate: config.learning_rate, eps: 1e-8, ..AdamConfig::default() },
        );
        Ok(Self {
            state: LearnerState::new(observation_space, action_space, None, seed),
            policy,
            gradient_steps: 0,
            last_loss: f32::NAN,
            optimizer,
            rng: ChaCha8Rng::seed_from_u64(seed ^ twinbots_api::seeds::BC_SAMPLING),
            demos: None,
            learnt_frames: None,
            config,
        })
    }

    /// A fresh policy for the task `spec`, its demonstrations read and checked now, so that a
    /// dataset that does not fit the robot is an error before anything starts.
    pub fn for_task(config: BcConfig, spec: &TaskSpec, seed: u64) -> anyhow::Result<Self> {
        anyhow::ensure!(
            !config.demos.is_empty(),
            "bc.demos is empty: behaviour cloning needs demonstrations (`--demos DIR`, a LeRobot dataset; `twinbots demos` writes one)"
        );
        let mut bc = Self::new(config, spec.observation_space.clone(), spec.action_space.clone(), seed)?;
        bc.read_demos()?;
        Ok(bc)
    }

    /// Reads `config.demos` and checks it against the model's spaces; a fresh model takes its
    /// observation statistics from it.
    fn read_demos(&mut self) -> anyhow::Result<()> {
        let c = &self.config;
        let data = twinbots_dataset::read_demonstrations(Path::new(&c.demos), &c.observation_key, &c.action_key)?;
        let targets = self.targets(&data)?;
        let frames = data.frames();
        if let Some(learnt) = self.learnt_frames {
            anyhow::ensure!(
                learnt == frames,
                "{}: {frames} frames, but the model learnt from {learnt}: the dataset changed since",
                c.demos
            );
        }
        if self.state.timesteps == 0 {
            self.state.obs_rms = self.config.normalize_observations.then(|| statistics(&data));
        }
        self.learnt_frames = Some(frames);
        self.demos = Some(Demos { states: data.states, targets, frames });
        Ok(())
    }

    /// The demonstrations' actions as the policy's targets; an error names the dataset, the
    /// feature and the frame that does not fit the robot's spaces.
    fn targets(&self, data: &Demonstrations) -> anyhow::Result<Vec<f32>> {
        let root = data.root.display();
        let obs_dim = self.state.observation_space.dim();
        anyhow::ensure!(
            data.state_dim == obs_dim,
            "{root}: {:?} has {} values a frame, the robot observes {obs_dim}",
            data.state_key,
            data.state_dim
        );
        let targets = match &self.state.action_space {
            Space::Box { low, .. } => {
                anyhow::ensure!(
                    data.action_dim == low.len(),
                    "{root}: {:?} has {} values a frame, the robot's actions {}",
                    data.action_key,
                    data.action_dim,
                    low.len()
                );
                // Into [−1, 1] as the policy's tanh gives it; an action beyond the box is what
                // the robot would have clipped it to.
                crate::off_policy::to_unit(&self.state.action_space, &data.actions)
            }
            Space::Discrete { n } => {
                anyhow::ensure!(
                    data.action_dim == 1,
                    "{root}: {:?} has {} values a frame, a discrete action is one",
                    data.action_key,
                    data.action_dim
                );
                if let Some(frame) = data.actions.iter().position(|&a| a.fract() != 0.0 || a < 0.0 || a >= *n as f32) {
                    anyhow::bail!(
                        "{root}: frame {frame}: action {} is not one of the robot's {n} (0..{n})",
                        data.actions[frame]
                    );
                }
                data.actions.clone()
            }
            other => anyhow::bail!("BC learns Box or Discrete actions, not {other}"),
        };
        Ok(targets)
    }

    /// The network's output for raw observation rows.
    fn outputs(&self, obs: &[f32]) -> anyhow::Result<Tensor> {
        Ok(self.policy.forward(&self.state.batch(obs)?)?)
    }

    /// The policy's action for each raw observation row.
    pub fn predict_deterministic(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let out = self.outputs(obs)?;
        match &self.state.action_space {
            Space::Discrete { n } => {
                let logits = out.flatten_all()?.to_vec1::<f32>()?;
                Ok(logits.chunks(*n).map(|row| crate::policy_net::arg_max(row) as f32).collect())
            }
            space => Ok(crate::off_policy::to_env(space, &out.tanh()?.flatten_all()?.to_vec1::<f32>()?)),
        }
    }

    /// A cloned policy has no exploration of its own: the same action either way.
    pub fn predict(&mut self, obs: &[f32], _deterministic: bool) -> anyhow::Result<Vec<f32>> {
        self.predict_deterministic(obs)
    }

    /// One gradient step on a minibatch drawn from the demonstrations: its loss, or `None` when
    /// the loss or a gradient was not finite (the weights stay, the step counts as skipped).
    pub fn gradient_step(&mut self) -> anyhow::Result<Option<f32>> {
        let demos = self.demos.as_ref().ok_or_else(|| anyhow::anyhow!("BC has no demonstrations read"))?;
        let (obs_dim, b) = (self.state.observation_space.dim(), self.config.batch_size);
        let width = demos.targets.len() / demos.frames;
        let (mut obs, mut targets) = (Vec::with_capacity(b * obs_dim), Vec::with_capacity(b * width));
        for _ in 0..b {
            let i = self.rng.random_range(0..demos.frames);
            obs.extend_from_slice(&demos.states[i * obs_dim..(i + 1) * obs_dim]);
            targets.extend_from_slice(&demos.targets[i * width..(i + 1) * width]);
        }
        let out = self.outputs(&obs)?;
        let loss = match &self.state.action_space {
            Space::Discrete { .. } => {
                let classes = Tensor::from_vec(targets, b, &Device::Cpu)?.to_dtype(DType::U32)?;
                candle_nn::loss::cross_entropy(&out, &classes)?
            }
            _ => (out.tanh()? - Tensor::from_vec(targets, (b, width), &Device::Cpu)?)?.sqr()?.mean_all()?,
        };
        let value = loss.to_scalar::<f32>()?;
        let applied = value.is_finite() && self.optimizer.step(&loss.backward()?, None)?.applied;
        self.gradient_steps += 1;
        Ok(applied.then_some(value))
    }

    fn weights(&self) -> Vec<(String, Var)> {
        self.policy.vars(POLICY)
    }

    /// Fits the policy for `more_steps` demonstration frames (batch size × gradient steps), a
    /// row for the callbacks every `log_interval` gradient steps and at the budget's end.
    fn fit(&mut self, more_steps: u64, callback: &mut dyn Callback) -> anyhow::Result<TrainingEnd> {
        if self.demos.is_none() {
            self.read_demos()?;
        }
        let target = self.state.timesteps.saturating_add(more_steps);
        let (mut losses, mut applied, mut skipped, mut row_started) = (Vec::new(), 0, 0, Instant::now());
        let mut row_steps = 0u64;
        while self.state.timesteps < target {
            let started = Instant::now();
            match self.gradient_step()? {
                Some(loss) => {
                    losses.push(loss);
                    applied += 1;
                }
                None => skipped += 1,
            }
            self.state.times.update_s += started.elapsed().as_secs_f64();
            self.state.timesteps += self.config.batch_size as u64;
            row_steps += self.config.batch_size as u64;
            let due = self.gradient_steps.is_multiple_of(self.config.log_interval as u64);
            if !due && self.state.timesteps < target {
                continue;
            }
            self.last_loss =
                if losses.is_empty() { f32::NAN } else { losses.iter().sum::<f32>() / losses.len() as f32 };
            self.state.updates += 1;
            let s = &self.state;
            let stats = UpdateStats {
                train: figures(TRAIN_FIGURES, &[self.last_loss]),
                learning_rate: self.config.learning_rate,
                steps_per_s: row_steps as f32 / row_started.elapsed().as_secs_f32(),
                skipped_steps: skipped,
                applied_steps: applied,
                ..s.history.row(s.updates, s.timesteps, s.episodes)
            };
            let started = Instant::now();
            let flow = callback.on_update(&stats, self)?;
            self.state.times.callbacks_s += started.elapsed().as_secs_f64();
            if let Some(end) = TrainingEnd::after(flow, self.state.timesteps) {
                return Ok(end);
            }
            (losses, applied, skipped, row_started, row_steps) = (Vec::new(), 0, 0, Instant::now(), 0);
        }
        Ok(TrainingEnd::BudgetSpent { timesteps: self.state.timesteps })
    }
}

/// The demonstrations' observation statistics: exact mean and variance over every frame, the
/// variance floored at [`MIN_STD`]².
fn statistics(data: &Demonstrations) -> RunningMeanStd {
    let (dim, n) = (data.state_dim, data.frames() as f64);
    let mut rms = RunningMeanStd::new(dim);
    for k in 0..dim {
        let column = || data.states.iter().skip(k).step_by(dim).map(|&x| f64::from(x));
        let mean = column().sum::<f64>() / n;
        rms.mean[k] = mean;
        rms.var[k] = (column().map(|x| (x - mean).powi(2)).sum::<f64>() / n).max(MIN_STD * MIN_STD);
    }
    rms.count = n;
    rms
}

impl Agent for Bc {
    crate::agent::agent_basics!(Bc);
    fn policy_net(&self) -> anyhow::Result<PolicyNet> {
        Ok(PolicyNet {
            obs_rms: self.state.obs_rms.clone(),
            encoding: InputEncoding::Flat,
            layers: crate::nn::layer_values(&self.policy.layers, POLICY)?,
            hidden: Activation::Relu,
            head: match self.state.action_space {
                Space::Discrete { .. } => PolicyHead::ArgMax,
                _ => PolicyHead::TanhToBox,
            },
        })
    }
    /// `train/loss` and `train/n_updates`, as SB3 tags a learner's figures.
    fn train_scalars(&self, _stats: &UpdateStats) -> Vec<(String, f32)> {
        crate::off_policy::train_scalars(TRAIN_FIGURES, &[self.last_loss], self.gradient_steps)
    }
}

impl Learner for Bc {
    /// Fits the policy to the demonstrations; `env` is not stepped (the callbacks' evaluations
    /// build their own).
    fn learn(
        &mut self,
        env: &mut dyn VecEnv,
        more_steps: u64,
        callback: &mut dyn Callback,
    ) -> anyhow::Result<TrainingEnd> {
        let _ = env;
        self.fit(more_steps, callback)
    }
}

impl LoadAgent for Bc {
    fn load(dir: &Path) -> Result<Self, ModelError> {
        Bc::load(dir)
    }
}

#[cfg(test)]
mod tests;
