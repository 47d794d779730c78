//! The learner a run trains with, PPO or SAC (`algo` in its settings): made fresh, taken from a
//! run's newest checkpoint, and run on the learner's thread. Everything else about a run (the
//! callbacks, evaluation, the run directory) sees it as a `twinbots_learn::Agent`.

use std::path::PathBuf;

use twinbots_learn::ppo::TrainingTimes;
use twinbots_api::{TaskSpec, VecEnv};
use twinbots_learn::{Agent, Callback, Ppo, RunDir, Sac, TrainingEnd};

use crate::cli::runs::TrainSettings;
use twinbots::settings::Algo;

pub enum Learner {
    Ppo(Box<Ppo>),
    Sac(Box<Sac>),
}

impl Learner {
    /// A new learner for the task `spec` (whose goal, if any, SAC's HER relabels with).
    pub fn new(settings: &TrainSettings, spec: &TaskSpec) -> anyhow::Result<Self> {
        let (obs, act) = (spec.observation_space.clone(), spec.action_space.clone());
        Ok(match settings.algo {
            Algo::Ppo => Self::Ppo(Box::new(Ppo::new(settings.ppo.clone(), obs, act, settings.seed)?)),
            Algo::Sac => Self::Sac(Box::new(Sac::new(settings.sac.clone(), obs, act, settings.seed)?.with_goal(spec.goal)?)),
        })
    }

    /// The newest checkpoint of `run` that loads, of the run's algorithm.
    pub fn resume(run: &RunDir, settings: &TrainSettings, spec: &TaskSpec) -> anyhow::Result<(PathBuf, Self)> {
        Ok(match settings.algo {
            Algo::Ppo => {
                let (dir, model) = run.load_newest_checkpoint::<Ppo>()?;
                (dir, Self::Ppo(Box::new(model)))
            }
            Algo::Sac => {
                let (dir, model) = run.load_newest_checkpoint::<Sac>()?;
                (dir, Self::Sac(Box::new(model.with_goal(spec.goal)?)))
            }
        })
    }

    pub fn agent(&self) -> &dyn Agent {
        match self {
            Self::Ppo(m) => m.as_ref(),
            Self::Sac(m) => m.as_ref(),
        }
    }

    /// Trains for `timesteps` more steps; returns the trained model and why training ended.
    pub fn learn(self, env: &mut dyn VecEnv, timesteps: u64, callbacks: &mut dyn Callback) -> anyhow::Result<(Trained, TrainingEnd)> {
        Ok(match self {
            Self::Ppo(mut m) => {
                let end = m.learn(env, timesteps, callbacks)?;
                let times = m.times;
                (Trained { model: m, times }, end)
            }
            Self::Sac(mut m) => {
                let end = m.learn(env, timesteps, callbacks)?;
                let times = m.times;
                (Trained { model: m, times }, end)
            }
        })
    }
}

/// A trained model and where its training time went.
pub struct Trained {
    pub model: Box<dyn Agent + Send>,
    pub times: TrainingTimes,
}
