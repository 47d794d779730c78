//! Running an exported policy without the simulator or candle: the ONNX graph loaded and
//! optimised by tract, with the metadata that says what it observes and how it acts.

use std::path::Path;
use std::sync::Arc;

use prost::Message;
use tract_onnx::pb;
use tract_onnx::prelude::*;
use twinbots_api::Space;

use crate::metadata::PolicyMetadata;

/// An exported policy, ready to act.
pub struct OnnxPolicy {
    pub metadata: PolicyMetadata,
    plan: Arc<TypedRunnableModel>,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy").field("metadata", &self.metadata).finish_non_exhaustive()
    }
}

impl OnnxPolicy {
    /// Loads a policy file written by `twinbots export`; a file that is not one (unreadable,
    /// not ONNX, ONNX without twinbots' metadata) is an error naming it.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Self::from_bytes(&bytes).map_err(|e| anyhow::anyhow!("{}: {e:#}", path.display()))
    }

    pub fn from_bytes(bytes: &[u8]) -> anyhow::Result<Self> {
        let proto = pb::ModelProto::decode(bytes).map_err(|e| anyhow::anyhow!("not an ONNX model ({e})"))?;
        anyhow::ensure!(proto.graph.as_ref().is_some_and(|g| !g.node.is_empty()), "not an ONNX model (no graph)");
        let props: Vec<(String, String)> =
            proto.metadata_props.iter().map(|p| (p.key.clone(), p.value.clone())).collect();
        let metadata = PolicyMetadata::from_props(&props)?;
        let plan = tract_onnx::onnx()
            .model_for_proto_model(&proto)
            .and_then(|m| m.into_optimized())
            .and_then(|m| m.into_runnable())
            .map_err(|e| anyhow::anyhow!("the ONNX graph does not load: {e:#}"))?;
        Ok(Self { metadata, plan })
    }

    /// The actions for rows of raw observations (flat in, flat out, as the task's spaces: a
    /// discrete choice is its index as a float).
    pub fn act(&self, obs: &[f32]) -> anyhow::Result<Vec<f32>> {
        let n = self.metadata.observation_space.dim();
        anyhow::ensure!(
            n > 0 && !obs.is_empty() && obs.len().is_multiple_of(n),
            "observations come in rows of {n} values, got {} values",
            obs.len()
        );
        let input = Tensor::from_shape(&[obs.len() / n, n], obs)?;
        let outputs = self.plan.run(tvec!(input.into()))?;
        let action = &outputs[0];
        Ok(match self.metadata.action_space {
            Space::Discrete { .. } => action.to_plain_array_view::<i64>()?.iter().map(|&a| a as f32).collect(),
            _ => action.to_plain_array_view::<f32>()?.iter().copied().collect(),
        })
    }
}
