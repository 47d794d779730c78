//! The pieces every model file is written and read with: atomic writes, safetensors, Adam's
//! moments, the envs' running episodes (`env_state.json`) and the errors that name the file.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor, Var};

use crate::nn::{Adam, Encoder};
use twinbots_api::env_state::EnvState;

pub const WEIGHTS_FILE: &str = "model.safetensors";
pub const METADATA_FILE: &str = "model.json";
pub const OPTIMIZER_FILE: &str = "optimizer.safetensors";
pub const ENV_STATE_FILE: &str = "env_state.json";

#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("{path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("the model was trained for {what} {model}, but this robot has {robot}")]
    SpaceMismatch { what: &'static str, model: String, robot: String },
}

pub fn file_error(path: &Path, e: impl std::fmt::Display) -> ModelError {
    ModelError::File { path: path.to_path_buf(), message: e.to_string() }
}

pub use twinbots_api::files::write_atomic;

/// The largest magnitude a saved weight may have. Trained networks here stay within ±100;
/// beyond this a file is damaged (3e38 once loaded, and every later update was skipped).
pub const MAX_WEIGHT: f32 = 1e4;

/// Sets every variable of `named` from `tensors` by name: a missing tensor, another shape, a
/// non-finite value or one beyond ±[`MAX_WEIGHT`] is an error naming it; extra tensors are
/// ignored.
pub fn set_vars(named: &[(String, Var)], tensors: &HashMap<String, Tensor>) -> anyhow::Result<()> {
    for (name, var) in named {
        let t = tensors.get(name).ok_or_else(|| anyhow::anyhow!("missing tensor '{name}'"))?;
        anyhow::ensure!(
            t.shape() == var.shape(),
            "tensor '{name}' has shape {:?}, expected {:?}",
            t.shape(),
            var.shape()
        );
        let values = t.flatten_all()?.to_dtype(candle_core::DType::F32)?.to_vec1::<f32>()?;
        anyhow::ensure!(
            values.iter().all(|x| x.is_finite()),
            "tensor '{name}' holds non-finite values (NaN or infinity): these weights are unusable"
        );
        if let Some(x) = values.iter().find(|x| x.abs() > MAX_WEIGHT) {
            anyhow::bail!(
                "tensor '{name}' holds {x:e}, beyond ±{MAX_WEIGHT:e}, which no trained network's weight reaches: the file is damaged"
            );
        }
        var.set(t)?;
    }
    Ok(())
}

/// Writes tensors as safetensors to `path` through a temporary file and a rename.
pub fn save_tensors(tensors: &HashMap<String, Tensor>, path: &Path) -> Result<(), ModelError> {
    twinbots_api::files::write_through(path, |tmp| Ok(candle_core::safetensors::save(tensors, tmp)?))
        .map_err(|e| file_error(path, e))
}

pub fn load_tensors(path: &Path) -> Result<HashMap<String, Tensor>, ModelError> {
    candle_core::safetensors::load(path, &Device::Cpu).map_err(|e| file_error(path, e))
}

/// Variables' current values by name.
pub fn var_tensors(named: &[(String, Var)]) -> HashMap<String, Tensor> {
    named.iter().map(|(name, var)| (name.clone(), var.as_tensor().clone())).collect()
}

/// Adam's moments as tensors `m.<name>` and `v.<name>` (in `out`), for the variables `named`
/// it optimises (in its order); returns its step count.
pub fn moment_tensors(
    adam: &Adam,
    named: &[(String, Var)],
    out: &mut HashMap<String, Tensor>,
    path: &Path,
) -> Result<u64, ModelError> {
    let (first, second, steps) = adam.moments();
    for (((name, var), m), v) in named.iter().zip(first).zip(second) {
        let tensor = |x: &Vec<f32>| {
            Tensor::from_vec(x.clone(), var.shape().clone(), &Device::Cpu).map_err(|e| file_error(path, e))
        };
        out.insert(format!("m.{name}"), tensor(m)?);
        out.insert(format!("v.{name}"), tensor(v)?);
    }
    Ok(steps)
}

/// Puts back into `adam` the moments [`moment_tensors`] wrote for `named`.
pub fn restore_moments(
    adam: &mut Adam,
    named: &[(String, Var)],
    tensors: &HashMap<String, Tensor>,
    steps: u64,
    path: &Path,
) -> Result<(), ModelError> {
    let take = |prefix: &str| -> Result<Vec<Vec<f32>>, ModelError> {
        named
            .iter()
            .map(|(name, _)| {
                let t = tensors
                    .get(&format!("{prefix}.{name}"))
                    .ok_or_else(|| file_error(path, format!("missing tensor '{prefix}.{name}'")))?;
                t.flatten_all().and_then(|t| t.to_vec1::<f32>()).map_err(|e| file_error(path, e))
            })
            .collect()
    };
    let (first, second) = (take("m")?, take("v")?);
    adam.restore_moments(first, second, steps).map_err(|e| file_error(path, e))
}

/// Several optimisers' moments in one `optimizer.safetensors` in `dir`, each's tensors prefixed
/// `<prefix>.` (`actor.m.<name>`); returns their step counts, in order.
pub fn save_optimizers(parts: Vec<(&str, Vec<(String, Var)>, &Adam)>, dir: &Path) -> Result<Vec<u64>, ModelError> {
    let mut moments = HashMap::new();
    let mut steps = Vec::new();
    for (prefix, named, adam) in parts {
        let mut part = HashMap::new();
        steps.push(moment_tensors(adam, &named, &mut part, dir)?);
        moments.extend(part.into_iter().map(|(name, t)| (format!("{prefix}.{name}"), t)));
    }
    save_tensors(&moments, &dir.join(OPTIMIZER_FILE))?;
    Ok(steps)
}

/// Puts back what [`save_optimizers`] saved in `dir`, with the step counts it returned.
pub fn restore_optimizers(
    parts: Vec<(&str, Vec<(String, Var)>, &mut Adam)>,
    steps: &[u64],
    dir: &Path,
) -> Result<(), ModelError> {
    let path = dir.join(OPTIMIZER_FILE);
    let moments = load_tensors(&path)?;
    if steps.len() != parts.len() {
        return Err(file_error(
            &dir.join(METADATA_FILE),
            format!("{} optimiser step counts for {} optimisers", steps.len(), parts.len()),
        ));
    }
    for ((prefix, named, adam), &count) in parts.into_iter().zip(steps) {
        let part: HashMap<String, Tensor> = moments
            .iter()
            .filter_map(|(name, t)| name.strip_prefix(&format!("{prefix}.")).map(|n| (n.to_string(), t.clone())))
            .collect();
        restore_moments(adam, &named, &part, count, &path)?;
    }
    Ok(())
}

/// Writes `env_state.json` into `dir`, or removes a stale one when there is no state.
pub fn save_env_state(dir: &Path, state: Option<&EnvState>) -> Result<(), ModelError> {
    let path = dir.join(ENV_STATE_FILE);
    match state {
        Some(state) => {
            let json = serde_json::to_vec(state).map_err(|e| file_error(&path, e))?;
            write_atomic(&path, &json).map_err(|e| file_error(&path, e))
        }
        None => {
            let _ = std::fs::remove_file(&path);
            Ok(())
        }
    }
}

/// Reads `env_state.json` from `dir`; `saved`: its model says it was written, so a missing
/// file is an error (the model could not resume exactly).
pub fn load_env_state(dir: &Path, saved: bool) -> Result<Option<EnvState>, ModelError> {
    let path = dir.join(ENV_STATE_FILE);
    if !path.is_file() {
        if saved {
            return Err(file_error(
                &path,
                "missing: its model.json says it was saved with the envs' running episodes, which a resumed run needs to go on exactly",
            ));
        }
        return Ok(None);
    }
    let text = std::fs::read_to_string(&path).map_err(|e| file_error(&path, e))?;
    Ok(Some(serde_json::from_str::<EnvState>(&text).map_err(|e| file_error(&path, e))?))
}

/// Writes `value` as pretty JSON to `dir/model.json`, atomically.
pub fn save_metadata(dir: &Path, value: &impl serde::Serialize) -> Result<(), ModelError> {
    let json = serde_json::to_vec_pretty(value).map_err(|e| file_error(dir, e))?;
    let path = dir.join(METADATA_FILE);
    write_atomic(&path, &json).map_err(|e| file_error(&path, e))
}

/// Reads `dir/model.json`, checking its format number and that `algorithm` saved it.
pub fn load_metadata<T: serde::de::DeserializeOwned>(
    dir: &Path,
    algorithm: &str,
    format: u32,
) -> Result<T, ModelError> {
    #[derive(serde::Deserialize)]
    struct Header {
        format: u32,
        algorithm: String,
    }
    let path = dir.join(METADATA_FILE);
    let text = std::fs::read_to_string(&path).map_err(|e| file_error(&path, e))?;
    let header: Header = serde_json::from_str(&text).map_err(|e| file_error(&path, e))?;
    if header.algorithm != algorithm {
        return Err(file_error(
            &path,
            format!("a {} model, not {algorithm} (load it with twinbots_learn::algos::load_agent)", header.algorithm),
        ));
    }
    if header.format != format {
        return Err(file_error(&path, format!("model format {} (this build reads {format})", header.format)));
    }
    serde_json::from_str(&text).map_err(|e| file_error(&path, e))
}

/// Sets an image encoder's variables to the tensors of the same names (`features.<i>.weight` /
/// `.bias`) in a safetensors file, such as `examples/pixel_probe.rs` saves: an encoder trained
/// apart from the policy (on labelled images) to start from. Every variable must be there, with
/// its shape and sound values (as a saved model's, [`set_vars`]); an encoder without variables
/// (no CNN) is an error.
pub fn set_encoder_from_file(encoder: &Encoder, path: &Path) -> anyhow::Result<()> {
    let vars = encoder.named_vars();
    anyhow::ensure!(
        !vars.is_empty(),
        "{}: the policy has no image encoder to start from it (policy = \"cnn\" or \"keypoints\")",
        path.display()
    );
    let tensors = load_tensors(path)?;
    set_vars(&vars, &tensors)
        .map_err(|e| anyhow::anyhow!("{}: {e} (it has {})", path.display(), sorted_names(&tensors)))
}

fn sorted_names(tensors: &HashMap<String, Tensor>) -> String {
    let mut names: Vec<&str> = tensors.keys().map(String::as_str).collect();
    names.sort();
    if names.is_empty() { "none".into() } else { names.join(", ") }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nn::PolicyKind;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use twinbots_api::spaces::Space;

    #[test]
    fn an_encoder_starts_from_a_files_tensors_of_its_names_and_shapes_or_says_what_is_wrong() {
        let dev = Device::Cpu;
        let image = Space::Image { height: 40, width: 40, channels: 3 };
        let encoder =
            |kind, seed| Encoder::new(kind, &image, 64, "ppo", &mut ChaCha8Rng::seed_from_u64(seed), &dev).unwrap();
        let values = |e: &Encoder| {
            e.named_vars()
                .into_iter()
                .map(|(n, v)| (n, v.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap()))
                .collect::<Vec<_>>()
        };
        let dir = std::env::temp_dir().join(format!("twinbots-encoder-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let save = |e: &Encoder, name: &str, skip: usize| {
            let path = dir.join(name);
            save_tensors(&var_tensors(&e.named_vars()[skip..]), &path).unwrap();
            path
        };
        let (trained, fresh) = (encoder(PolicyKind::Keypoints, 1), encoder(PolicyKind::Keypoints, 2));
        assert_ne!(values(&trained), values(&fresh));
        set_encoder_from_file(&fresh, &save(&trained, "keypoints.safetensors", 0)).unwrap();
        assert_eq!(values(&trained), values(&fresh), "every variable taken from the file");

        let e = set_encoder_from_file(&fresh, &save(&trained, "short.safetensors", 1)).unwrap_err().to_string();
        assert!(
            e.contains(
                "short.safetensors: missing tensor 'features.0.weight' (it has features.0.bias, features.1.bias"
            ),
            "{e}"
        );
        let e = set_encoder_from_file(&encoder(PolicyKind::Cnn, 3), &dir.join("keypoints.safetensors"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("keypoints.safetensors: tensor 'features.0.weight' has shape") && e.contains("expected"),
            "another encoder's shapes: {e}"
        );
        let e = set_encoder_from_file(&encoder(PolicyKind::Mlp, 3), &dir.join("keypoints.safetensors"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("the policy has no image encoder"), "{e}");
        let e = set_encoder_from_file(&fresh, &dir.join("missing.safetensors")).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{}", dir.join("missing.safetensors").display())), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
