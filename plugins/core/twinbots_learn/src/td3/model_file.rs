//! Saving and loading a TD3 model, in the files of the others (`model_dir`): `model.safetensors`
//! (actor, critics and their targets), `model.json`, `optimizer.safetensors` (the two Adams'
//! moments, prefixed `actor.`, `critic.`), `env_state.json`, and the replay buffer as SAC keeps
//! it, so that a resumed run samples what the uninterrupted one would have.

use std::path::Path;

use candle_core::Var;
use serde::{Deserialize, Serialize};
use twinbots_api::env_state::StreamState;

use super::{Td3, Td3Config};
use crate::model_dir::{SavedModel, load_model, save_model, saved_model_basics};
use crate::model_io::{self, METADATA_FILE, ModelError, file_error};
use crate::off_policy::replay_file::{BufferRing, load_replay, save_replay};

/// TD3's own fields of `model.json`.
#[derive(Serialize, Deserialize)]
struct Own {
    gradient_steps: u64,
    iterations: u64,
    noise_stream: StreamState,
    /// Adam's step counts: actor, critic.
    optimizer_steps: [u64; 2],
    replay_buffer: Option<BufferRing>,
}

impl SavedModel for Td3 {
    saved_model_basics!(Td3, Td3Config);
    const FORMAT: u32 = 1;
    fn weights(&self) -> Vec<(String, Var)> {
        let mut all = self.actor.vars("actor");
        all.extend(self.actor_target.vars("actor_target"));
        all.extend(self.critic.named_vars("critic"));
        all.extend(self.critic_target.named_vars("target"));
        all
    }
}

impl Td3 {
    fn optimized_vars(&self) -> [(&'static str, Vec<(String, Var)>); 2] {
        [("actor", self.actor.vars("actor")), ("critic", self.critic.named_vars("critic"))]
    }

    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        save_model(self, dir.as_ref(), |dir| {
            let [actor, critic] = self.optimized_vars();
            let adams = vec![(actor.0, actor.1, &self.actor_optimizer), (critic.0, critic.1, &self.critic_optimizer)];
            let steps = model_io::save_optimizers(adams, dir)?;
            Ok(Own {
                gradient_steps: self.gradient_steps,
                iterations: self.iterations,
                noise_stream: StreamState::of(&self.rng),
                optimizer_steps: [steps[0], steps[1]],
                replay_buffer: save_replay(self.buffer.as_ref(), dir)?,
            })
        })
    }

    /// Loads a model saved by [`Td3::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Td3, ModelError> {
        let dir = dir.as_ref();
        let (mut model, own): (Td3, Own) = load_model(dir)?;
        (model.gradient_steps, model.iterations) = (own.gradient_steps, own.iterations);
        model.rng = own.noise_stream.to_rng().map_err(|e| file_error(&dir.join(METADATA_FILE), e))?;
        let [actor, critic] = model.optimized_vars();
        let parts =
            vec![(actor.0, actor.1, &mut model.actor_optimizer), (critic.0, critic.1, &mut model.critic_optimizer)];
        model_io::restore_optimizers(parts, &own.optimizer_steps, dir)?;
        let (obs_dim, act_dim) = (model.state.observation_space.dim(), model.state.action_space.dim());
        model.buffer = load_replay(own.replay_buffer, dir, obs_dim, act_dim)?;
        Ok(model)
    }
}
