//! Saving and loading a SAC model, in the files of a PPO one (`model_io`): `model.safetensors`
//! (actor, critics, target critics, log α), `model.json`, `optimizer.safetensors` (the three
//! Adams' moments, prefixed `actor.`, `critic.`, `ent.`), `env_state.json`, and the replay
//! buffer in `replay_buffer.safetensors` (its ring position in `model.json`), so that a resumed
//! run samples what the uninterrupted one would have.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{Device, Tensor, Var};
use serde::{Deserialize, Serialize};

use super::{ReplayBuffer, Sac, SacConfig};
use crate::model_header::ModelHeader;
use crate::model_io::{self, METADATA_FILE, ModelError, WEIGHTS_FILE, file_error};
use crate::nn::Adam;
use crate::replay_buffer::Rows;
use twinbots_api::env_state::StreamState;

const FORMAT: u32 = 1;
pub const REPLAY_BUFFER_FILE: &str = "replay_buffer.safetensors";

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

/// Where the replay buffer's ring stands (its contents are in `replay_buffer.safetensors`).
#[derive(Serialize, Deserialize)]
pub(crate) struct BufferRing {
    n_envs: usize,
    capacity: usize,
    pos: usize,
    full: bool,
    episode_steps: Vec<u32>,
    /// The names the buffer's `ended_by` codes stand for (absent in buffers saved before they
    /// were kept: their steps count as ended by no term).
    #[serde(default)]
    terminations: Vec<String>,
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
        model_io::save_env_state(dir, self.env_state.as_ref())?;
        let meta = Metadata {
            header: ModelHeader::of(
                self,
                FORMAT,
                self.obs_rms.as_ref(),
                self.seed,
                self.updates,
                self.env_state.is_some(),
            ),
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
        let mut model = Sac::new(meta.hyperparameters, h.observation_space, h.action_space, h.seed)
            .map_err(|e| file_error(&path, e))?;
        let weights = dir.join(WEIGHTS_FILE);
        model_io::set_vars(&model.weights(), &model_io::load_tensors(&weights)?)
            .map_err(|e| file_error(&weights, e))?;
        (model.obs_rms, model.timesteps, model.episodes, model.updates, model.history) =
            (h.obs_rms, h.timesteps, h.episodes, h.updates, h.history);
        (model.gradient_steps, model.iterations) = (meta.gradient_steps, meta.iterations);
        model.rng = meta.sampling_stream.to_rng().map_err(|e| file_error(&path, e))?;
        let [actor, critic, ent] = model.optimized_vars();
        let [a, c, e] = model.optimizers();
        model_io::restore_optimizers(
            vec![(actor.0, actor.1, a), (critic.0, critic.1, c), (ent.0, ent.1, e)],
            &meta.optimizer_steps,
            dir,
        )?;
        model.buffer = load_replay(meta.replay_buffer, dir, model.observation_space.dim(), model.action_space.dim())?;
        model.env_state = model_io::load_env_state(dir, saved_env_state)?;
        Ok(model)
    }
}

/// Saves `buffer` (if any) into `dir`'s `replay_buffer.safetensors`; returns its ring position
/// for `model.json`.
pub(crate) fn save_replay(buffer: Option<&ReplayBuffer>, dir: &Path) -> Result<Option<BufferRing>, ModelError> {
    let Some(buffer) = buffer else { return Ok(None) };
    save_buffer(buffer, &dir.join(REPLAY_BUFFER_FILE))?;
    Ok(Some(BufferRing {
        n_envs: buffer.n_envs,
        capacity: buffer.capacity,
        pos: buffer.pos,
        full: buffer.full,
        episode_steps: buffer.episode_steps.clone(),
        terminations: buffer.terminations.clone(),
    }))
}

/// The replay buffer [`save_replay`] saved into `dir` at `ring`, checked against it.
pub(crate) fn load_replay(
    ring: Option<BufferRing>,
    dir: &Path,
    obs_dim: usize,
    act_dim: usize,
) -> Result<Option<ReplayBuffer>, ModelError> {
    let Some(ring) = ring else { return Ok(None) };
    let mut buffer = ReplayBuffer::new(ring.capacity, ring.n_envs, obs_dim, act_dim);
    let file = dir.join(REPLAY_BUFFER_FILE);
    load_buffer(&mut buffer, &file)?;
    let len = if ring.full { ring.capacity } else { ring.pos };
    let fits = buffer.capacity == ring.capacity
        && ring.pos < ring.capacity.max(1)
        && buffer.rewards.len() == len
        && ring.episode_steps.len() == ring.n_envs;
    if !fits {
        return Err(file_error(&file, "the replay buffer does not match its ring position in model.json"));
    }
    if buffer.ended_by.iter().any(|&code| code as usize > ring.terminations.len()) {
        return Err(file_error(
            &file,
            "the replay buffer's ended_by codes name more termination terms than model.json lists",
        ));
    }
    (buffer.pos, buffer.full, buffer.episode_steps, buffer.terminations) =
        (ring.pos, ring.full, ring.episode_steps, ring.terminations);
    Ok(Some(buffer))
}

fn save_buffer(buffer: &ReplayBuffer, path: &Path) -> Result<(), ModelError> {
    let dev = Device::Cpu;
    let len = buffer.len();
    let t = |data: &[f32], width: usize| {
        Tensor::from_vec(data.to_vec(), (len, width), &dev).map_err(|e| file_error(path, e))
    };
    // Rows as they are kept: f32, or u8 for camera images.
    let rows = |rows: &Rows| match rows {
        Rows::Floats(v) => t(v, buffer.obs_dim),
        Rows::Bytes(v) => Tensor::from_vec(v.clone(), (len, buffer.obs_dim), &dev).map_err(|e| file_error(path, e)),
    };
    let mut tensors = HashMap::new();
    tensors.insert("obs".to_string(), rows(&buffer.obs)?);
    tensors.insert("next_obs".to_string(), rows(&buffer.next_obs)?);
    tensors.insert("actions".to_string(), t(&buffer.actions, buffer.act_dim)?);
    tensors.insert("rewards".to_string(), t(&buffer.rewards, 1)?);
    tensors.insert("dones".to_string(), t(&buffer.dones, 1)?);
    let remaining = Tensor::from_vec(buffer.remaining.clone(), len, &dev).map_err(|e| file_error(path, e))?;
    tensors.insert("remaining".to_string(), remaining);
    let ended_by = Tensor::from_vec(buffer.ended_by.clone(), len, &dev).map_err(|e| file_error(path, e))?;
    tensors.insert("ended_by".to_string(), ended_by);
    model_io::save_tensors(&tensors, path)
}

fn load_buffer(buffer: &mut ReplayBuffer, path: &Path) -> Result<(), ModelError> {
    let tensors = model_io::load_tensors(path)?;
    let get = |name: &str| tensors.get(name).ok_or_else(|| file_error(path, format!("missing tensor '{name}'")));
    let floats = |name: &str| -> Result<Vec<f32>, ModelError> {
        let v = get(name)?.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|e| file_error(path, e))?;
        if v.iter().any(|x| !x.is_finite()) {
            return Err(file_error(path, format!("tensor '{name}' holds non-finite values")));
        }
        Ok(v)
    };
    let rows = |name: &str| -> Result<Rows, ModelError> {
        let tensor = get(name)?;
        if tensor.dtype() == candle_core::DType::U8 {
            return Ok(Rows::Bytes(
                tensor.flatten_all().and_then(|t| t.to_vec1::<u8>()).map_err(|e| file_error(path, e))?,
            ));
        }
        Ok(Rows::Floats(floats(name)?))
    };
    buffer.obs = rows("obs")?;
    buffer.next_obs = rows("next_obs")?;
    buffer.actions = floats("actions")?;
    buffer.rewards = floats("rewards")?;
    buffer.dones = floats("dones")?;
    buffer.remaining = get("remaining")?.to_vec1::<u32>().map_err(|e| file_error(path, e))?;
    let n = buffer.rewards.len();
    buffer.ended_by = match tensors.get("ended_by") {
        Some(t) => t.to_vec1::<u8>().map_err(|e| file_error(path, e))?,
        None => vec![0; n],
    };
    let same_kind = matches!(
        (&buffer.obs, &buffer.next_obs),
        (Rows::Floats(_), Rows::Floats(_)) | (Rows::Bytes(_), Rows::Bytes(_))
    );
    let consistent = same_kind
        && buffer.obs.len() == n * buffer.obs_dim
        && buffer.next_obs.len() == n * buffer.obs_dim
        && buffer.actions.len() == n * buffer.act_dim
        && buffer.dones.len() == n
        && buffer.remaining.len() == n
        && buffer.ended_by.len() == n;
    if !consistent {
        return Err(file_error(path, "the replay buffer's tensors differ in length"));
    }
    Ok(())
}
