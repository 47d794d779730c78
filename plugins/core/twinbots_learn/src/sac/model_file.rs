//! Saving and loading a SAC model, in the files of a PPO one (`model_io`): `model.safetensors`
//! (actor, critics, target critics, log α), `model.json`, `optimizer.safetensors` (the three
//! Adams' moments, prefixed `actor.`, `critic.`, `ent.`), `env_state.json`, and the replay
//! buffer in `replay_buffer.safetensors` (its ring position in `model.json`), so that a resumed
//! run samples what the uninterrupted one would have.

use std::path::Path;

use candle_core::Var;
use serde::{Deserialize, Serialize};

use super::{Sac, SacConfig};
use crate::model_header::ModelHeader;
use crate::model_io::{self, METADATA_FILE, ModelError, WEIGHTS_FILE, file_error};
use crate::nn::Adam;
use crate::off_policy::replay_file::{BufferRing, load_replay, save_replay};
use twinbots_api::env_state::StreamState;

const FORMAT: u32 = 1;

#[derive(Serialize, Deserialize)]
struct Metadata {
    #[serde(flatten)]
    header: ModelHeader,
    hyperparameters: SacConfig,
    gradient_steps: u64,
    iterations: u64,
    sampling_stream: StreamState,
    /// Adam's step counts: actor, critic, entropy coefficient.
    optimizer_steps: [u64; 3],
    replay_buffer: Option<BufferRing>,
}

impl Sac {
    fn weights(&self) -> Vec<(String, Var)> {
        let mut named = self.actor.named_vars();
        named.extend(self.critic.named_vars("critic"));
        named.extend(self.critic_target.named_vars("target"));
        named.push(("log_ent_coef".into(), self.log_ent_coef.clone()));
        named
    }

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
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
        model_io::save_tensors(&model_io::var_tensors(&self.weights()), &dir.join(WEIGHTS_FILE))?;
        let [actor, critic, ent] = self.optimized_vars();
        let adams = [&self.actor_optimizer, &self.critic_optimizer, &self.ent_optimizer];
        let steps = model_io::save_optimizers(
            vec![(actor.0, actor.1, adams[0]), (critic.0, critic.1, adams[1]), (ent.0, ent.1, adams[2])],
            dir,
        )?;
        let optimizer_steps = [steps[0], steps[1], steps[2]];
        let replay_buffer = save_replay(self.buffer.as_ref(), dir)?;
        model_io::save_env_state(dir, self.state.env_state.as_ref())?;
        let meta = Metadata {
            header: self.state.header(super::SAVED_AS, FORMAT),
            hyperparameters: self.config.clone(),
            gradient_steps: self.gradient_steps,
            iterations: self.iterations,
            sampling_stream: StreamState::of(&self.rng),
            optimizer_steps,
            replay_buffer,
        };
        model_io::save_metadata(dir, &meta)
    }

    /// Loads a model saved by [`Sac::save`] (give a goal-conditioned task's goal again with
    /// [`Sac::with_goal`]).
    pub fn load(dir: impl AsRef<Path>) -> Result<Sac, ModelError> {
        let dir = dir.as_ref();
        let path = dir.join(METADATA_FILE);
        let meta: Metadata = model_io::load_metadata(dir, super::SAVED_AS, FORMAT)?;
        meta.hyperparameters.validate().map_err(|e| file_error(&path, e))?;
        let h = meta.header;
        h.check(&path)?;
        let saved_env_state = h.env_state;
        let mut model = Sac::new(meta.hyperparameters, h.observation_space.clone(), h.action_space.clone(), h.seed)
            .map_err(|e| file_error(&path, e))?;
        let weights = dir.join(WEIGHTS_FILE);
        model_io::set_vars(&model.weights(), &model_io::load_tensors(&weights)?)
            .map_err(|e| file_error(&weights, e))?;
        model.state.take_saved(h);
        (model.gradient_steps, model.iterations) = (meta.gradient_steps, meta.iterations);
        model.rng = meta.sampling_stream.to_rng().map_err(|e| file_error(&path, e))?;
        let [actor, critic, ent] = model.optimized_vars();
        let [a, c, e] = model.optimizers();
        model_io::restore_optimizers(
            vec![(actor.0, actor.1, a), (critic.0, critic.1, c), (ent.0, ent.1, e)],
            &meta.optimizer_steps,
            dir,
        )?;
        model.buffer =
            load_replay(meta.replay_buffer, dir, model.state.observation_space.dim(), model.state.action_space.dim())?;
        model.state.env_state = model_io::load_env_state(dir, saved_env_state)?;
        Ok(model)
    }
}
