//! Saving and loading a SAC model, in the files of a PPO one (`model_dir`): `model.safetensors`
//! (actor, critics, target critics, log α), `model.json`, `optimizer.safetensors` (the three
//! Adams' moments, prefixed `actor.`, `critic.`, `ent.`), `env_state.json`, and the replay
//! buffer in `replay_buffer.safetensors` (its ring position in `model.json`), so that a resumed
//! run samples what the uninterrupted one would have.

use std::path::Path;

use candle_core::Var;
use serde::{Deserialize, Serialize};
use twinbots_api::env_state::StreamState;

use super::{Sac, SacConfig};
use crate::model_dir::{SavedModel, load_model, save_model, saved_model_basics};
use crate::model_io::{self, METADATA_FILE, ModelError, file_error};
use crate::nn::Adam;
use crate::off_policy::replay_file::{BufferRing, load_replay, save_replay};

/// SAC's own fields of `model.json`.
#[derive(Serialize, Deserialize)]
struct Own {
    gradient_steps: u64,
    iterations: u64,
    sampling_stream: StreamState,
    /// Adam's step counts: actor, critic, entropy coefficient.
    optimizer_steps: [u64; 3],
    replay_buffer: Option<BufferRing>,
}

impl SavedModel for Sac {
    saved_model_basics!(Sac, SacConfig);
    const FORMAT: u32 = 1;
    fn weights(&self) -> Vec<(String, Var)> {
        let mut named = self.actor.named_vars();
        named.extend(self.critic.named_vars("critic"));
        named.extend(self.critic_target.named_vars("target"));
        named.push(("log_ent_coef".into(), self.log_ent_coef.clone()));
        named
    }
}

impl Sac {
    /// Each optimiser's prefix in `optimizer.safetensors` and the variables it steps, in the
    /// order of [`Sac::optimizers`].
    fn optimized_vars(&self) -> [(&'static str, Vec<(String, Var)>); 3] {
        [
            ("actor", self.actor.named_vars()),
            ("critic", self.critic.named_vars("critic")),
            ("ent", vec![("log_ent_coef".into(), self.log_ent_coef.clone())]),
        ]
    }

    fn optimizers(&mut self) -> [&mut Adam; 3] {
        [&mut self.actor_optimizer, &mut self.critic_optimizer, &mut self.ent_optimizer]
    }

    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        save_model(self, dir.as_ref(), |dir| {
            let [actor, critic, ent] = self.optimized_vars();
            let adams = [&self.actor_optimizer, &self.critic_optimizer, &self.ent_optimizer];
            let steps = model_io::save_optimizers(
                vec![(actor.0, actor.1, adams[0]), (critic.0, critic.1, adams[1]), (ent.0, ent.1, adams[2])],
                dir,
            )?;
            Ok(Own {
                gradient_steps: self.gradient_steps,
                iterations: self.iterations,
                sampling_stream: StreamState::of(&self.rng),
                optimizer_steps: [steps[0], steps[1], steps[2]],
                replay_buffer: save_replay(self.buffer.as_ref(), dir)?,
            })
        })
    }

    /// Loads a model saved by [`Sac::save`] (give a goal-conditioned task's goal again with
    /// [`Sac::with_goal`]).
    pub fn load(dir: impl AsRef<Path>) -> Result<Sac, ModelError> {
        let dir = dir.as_ref();
        let (mut model, own): (Sac, Own) = load_model(dir)?;
        (model.gradient_steps, model.iterations) = (own.gradient_steps, own.iterations);
        model.rng = own.sampling_stream.to_rng().map_err(|e| file_error(&dir.join(METADATA_FILE), e))?;
        let [actor, critic, ent] = model.optimized_vars();
        let [a, c, e] = model.optimizers();
        model_io::restore_optimizers(
            vec![(actor.0, actor.1, a), (critic.0, critic.1, c), (ent.0, ent.1, e)],
            &own.optimizer_steps,
            dir,
        )?;
        let (obs_dim, act_dim) = (model.state.observation_space.dim(), model.state.action_space.dim());
        model.buffer = load_replay(own.replay_buffer, dir, obs_dim, act_dim)?;
        Ok(model)
    }
}
