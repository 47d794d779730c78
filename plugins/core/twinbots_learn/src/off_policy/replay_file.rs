//! The replay buffer of an off-policy model (SAC's, TD3's) on disk: its rows in
//! `replay_buffer.safetensors` beside the model, its ring position in the model's `model.json`,
//! so that a resumed run samples what the uninterrupted one would have.

use std::collections::HashMap;
use std::path::Path;

use candle_core::{Device, Tensor};
use serde::{Deserialize, Serialize};

use crate::model_io::{self, ModelError, file_error};
use crate::replay_buffer::{ReplayBuffer, Rows};

pub const REPLAY_BUFFER_FILE: &str = "replay_buffer.safetensors";

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
