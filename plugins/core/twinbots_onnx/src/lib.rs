//! twinbots_onnx: a trained policy leaves the simulator as an ONNX graph ([`export`]) with its
//! description ([`metadata`]), and runs anywhere ONNX runs: here by tract ([`policy`]), on a
//! robot's computer by onnxruntime or any other runtime. docs/export.md describes the graph.

pub mod export;
pub mod metadata;
pub mod policy;

pub use export::{policy_bytes, policy_model, write_policy};
pub use metadata::PolicyMetadata;
pub use policy::OnnxPolicy;
