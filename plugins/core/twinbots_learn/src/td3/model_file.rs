//! Saving and loading a TD3 model, in the files of the others (`model_io`): `model.safetensors`
//! (actor, critics and their targets), `model.json`, `optimizer.safetensors` (the two Adams'
//! moments, prefixed `actor.`, `critic.`), `env_state.json`, and the replay buffer as SAC keeps
//! it, so that a resumed run samples what the uninterrupted one would have.

use std::path::Path;

use candle_core::Var;
use serde::{Deserialize, Serialize};
use twinbots_api::env_state::StreamState;

use super::{Td3, Td3Config, named};
use crate::model_header::ModelHeader;
use crate::model_io::set_vars;
use crate::model_io::{self, METADATA_FILE, ModelError, WEIGHTS_FILE, file_error};
use crate::off_policy::replay_file::{BufferRing, load_replay, save_replay};

const FORMAT: u32 = 1;

#[derive(Serialize, Deserialize)]
struct Metadata {
    #[serde(flatten)]
    header: ModelHeader,
    hyperparameters: Td3Config,
    gradient_steps: u64,
    iterations: u64,
    noise_stream: StreamState,
    /// Adam's step counts: actor, critic.
    optimizer_steps: [u64; 2],
    replay_buffer: Option<BufferRing>,
}

impl Td3 {
    fn weights(&self) -> Vec<(String, Var)> {
        let mut all = named(&self.actor, "actor");
        all.extend(named(&self.actor_target, "actor_target"));
        all.extend(self.critic.named_vars("critic"));
        all.extend(self.critic_target.named_vars("target"));
        all
    }

    fn optimized_vars(&self) -> [(&'static str, Vec<(String, Var)>); 2] {
        [("actor", named(&self.actor, "actor")), ("critic", self.critic.named_vars("critic"))]
    }

    /// Saves into the directory `dir` (created if needed).
    pub fn save(&self, dir: impl AsRef<Path>) -> Result<(), ModelError> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
        model_io::save_tensors(&model_io::var_tensors(&self.weights()), &dir.join(WEIGHTS_FILE))?;
        let [actor, critic] = self.optimized_vars();
        let steps = model_io::save_optimizers(
            vec![(actor.0, actor.1, &self.actor_optimizer), (critic.0, critic.1, &self.critic_optimizer)],
            dir,
        )?;
        let optimizer_steps = [steps[0], steps[1]];
        let replay_buffer = save_replay(self.buffer.as_ref(), dir)?;
        model_io::save_env_state(dir, self.state.env_state.as_ref())?;
        let meta = Metadata {
            header: self.state.header(super::SAVED_AS, FORMAT),
            hyperparameters: self.config.clone(),
            gradient_steps: self.gradient_steps,
            iterations: self.iterations,
            noise_stream: StreamState::of(&self.rng),
            optimizer_steps,
            replay_buffer,
        };
        model_io::save_metadata(dir, &meta)
    }

    /// Loads a model saved by [`Td3::save`].
    pub fn load(dir: impl AsRef<Path>) -> Result<Td3, ModelError> {
        let dir = dir.as_ref();
        let path = dir.join(METADATA_FILE);
        let meta: Metadata = model_io::load_metadata(dir, super::SAVED_AS, FORMAT)?;
        let h = meta.header;
        h.check(&path)?;
        let saved_env_state = h.env_state;
        let mut model = Td3::new(meta.hyperparameters, h.observation_space.clone(), h.action_space.clone(), h.seed)
            .map_err(|e| file_error(&path, e))?;
        let weights = dir.join(WEIGHTS_FILE);
        set_vars(&model.weights(), &model_io::load_tensors(&weights)?).map_err(|e| file_error(&weights, e))?;
        model.state.take_saved(h);
        (model.gradient_steps, model.iterations) = (meta.gradient_steps, meta.iterations);
        model.rng = meta.noise_stream.to_rng().map_err(|e| file_error(&path, e))?;
        let [actor, critic] = model.optimized_vars();
        let parts =
            vec![(actor.0, actor.1, &mut model.actor_optimizer), (critic.0, critic.1, &mut model.critic_optimizer)];
        model_io::restore_optimizers(parts, &meta.optimizer_steps, dir)?;
        model.buffer =
            load_replay(meta.replay_buffer, dir, model.state.observation_space.dim(), model.state.action_space.dim())?;
        model.state.env_state = model_io::load_env_state(dir, saved_env_state)?;
        Ok(model)
    }
}
