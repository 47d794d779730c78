//! A learner's model directory as every algorithm writes it: `model.safetensors` (the weights),
//! `env_state.json` (the envs' running episodes) and `model.json` (the [`ModelHeader`], the
//! hyperparameters, then the algorithm's own fields), around whatever files of its own the
//! algorithm keeps (Adam's moments, the replay buffer).

use std::path::Path;

use candle_core::Var;
use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use twinbots_api::spaces::Space;

use crate::learner_state::LearnerState;
use crate::model_header::ModelHeader;
use crate::model_io::{self, METADATA_FILE, ModelError, WEIGHTS_FILE, file_error};

/// `model.json`: the header every model has, the hyperparameters, the algorithm's own fields.
#[derive(Serialize, Deserialize)]
struct Metadata<C, E> {
    #[serde(flatten)]
    header: ModelHeader,
    hyperparameters: C,
    #[serde(flatten)]
    own: E,
}

/// What [`save_model`] and [`load_model`] need to know of a learner (the plain parts written by
/// [`saved_model_basics`]).
pub(crate) trait SavedModel: Sized {
    type Config: Clone + Serialize + DeserializeOwned;
    /// `model.json`'s `algorithm`.
    const SAVED_AS: &'static str;
    /// `model.json`'s `format`: the version of the algorithm's own files.
    const FORMAT: u32;
    fn config(&self) -> &Self::Config;
    fn learner_state(&self) -> &LearnerState;
    fn learner_state_mut(&mut self) -> &mut LearnerState;
    /// A fresh learner (its `new`), its weights then set from the files.
    fn create(config: Self::Config, observation_space: Space, action_space: Space, seed: u64) -> anyhow::Result<Self>;
    /// Its variables as `model.safetensors` names them.
    fn weights(&self) -> Vec<(String, Var)>;
}

/// Saves `learner` into `dir` (created if needed): the weights, then the algorithm's own files
/// (`own_files` writes them and returns its fields of `model.json`), the env state, and
/// `model.json` last.
pub(crate) fn save_model<L: SavedModel, E: Serialize>(
    learner: &L,
    dir: &Path,
    own_files: impl FnOnce(&Path) -> Result<E, ModelError>,
) -> Result<(), ModelError> {
    std::fs::create_dir_all(dir).map_err(|e| file_error(dir, e))?;
    model_io::save_tensors(&model_io::var_tensors(&learner.weights()), &dir.join(WEIGHTS_FILE))?;
    let own = own_files(dir)?;
    let state = learner.learner_state();
    model_io::save_env_state(dir, state.env_state.as_ref())?;
    let meta =
        Metadata { header: state.header(L::SAVED_AS, L::FORMAT), hyperparameters: learner.config().clone(), own };
    model_io::save_metadata(dir, &meta)
}

/// Loads what [`save_model`] saved: a learner with the saved weights, counters, history and env
/// state, and the algorithm's own fields of `model.json` (with which it restores its own files).
pub(crate) fn load_model<L: SavedModel, E: DeserializeOwned>(dir: &Path) -> Result<(L, E), ModelError> {
    let path = dir.join(METADATA_FILE);
    let meta: Metadata<L::Config, E> = model_io::load_metadata(dir, L::SAVED_AS, L::FORMAT)?;
    meta.header.check(&path)?;
    let h = &meta.header;
    let mut model = L::create(meta.hyperparameters, h.observation_space.clone(), h.action_space.clone(), h.seed)
        .map_err(|e| file_error(&path, e))?;
    let weights = dir.join(WEIGHTS_FILE);
    model_io::set_vars(&model.weights(), &model_io::load_tensors(&weights)?).map_err(|e| file_error(&weights, e))?;
    let saved_env_state = meta.header.env_state;
    model.learner_state_mut().take_saved(meta.header);
    model.learner_state_mut().env_state = model_io::load_env_state(dir, saved_env_state)?;
    Ok((model, meta.own))
}

/// The [`SavedModel`] items a learner `$ty` with a `config: $config` field, a `state` field and
/// `$ty::new` writes as every learner does, in the module beside its `SAVED_AS`.
macro_rules! saved_model_basics {
    ($ty:ident, $config:ident) => {
        type Config = $config;
        const SAVED_AS: &'static str = super::SAVED_AS;
        fn config(&self) -> &$config {
            &self.config
        }
        fn learner_state(&self) -> &$crate::learner_state::LearnerState {
            &self.state
        }
        fn learner_state_mut(&mut self) -> &mut $crate::learner_state::LearnerState {
            &mut self.state
        }
        fn create(
            config: $config,
            observation_space: twinbots_api::spaces::Space,
            action_space: twinbots_api::spaces::Space,
            seed: u64,
        ) -> anyhow::Result<Self> {
            $ty::new(config, observation_space, action_space, seed)
        }
    };
}
pub(crate) use saved_model_basics;
