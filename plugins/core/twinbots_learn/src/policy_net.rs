//! A deterministic policy as plain numbers: the observation normaliser, the dense layers, and
//! how the action comes out of the last one. What an exporter (ONNX) needs of any algorithm's
//! policy, so that it knows no algorithm by name.

use crate::normalize::RunningMeanStd;

/// The activation after every layer but the last.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Activation {
    Tanh,
    Relu,
}

/// How the last layer's output becomes the action.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PolicyHead {
    /// Discrete actions: the arg max of the logits (the last of equal ones).
    ArgMax,
    /// The output is the action, clipped to the action box (a Gaussian's mean, as PPO acts).
    ClipToBox,
    /// tanh of the output, rescaled from [−1, 1] to the action box:
    /// `low + (a + 1) · (high − low) / 2` (SAC's and TD3's squashed actions).
    TanhToBox,
}

/// A dense layer `y = x Wᵀ + b`, with the name its model file gives it (`pi.0`).
#[derive(Clone, Debug, PartialEq)]
pub struct DenseLayer {
    pub name: String,
    pub inputs: usize,
    pub outputs: usize,
    /// `[outputs, inputs]`, row-major.
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

/// A policy's deterministic action as an MLP.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyNet {
    /// Observations are normalised with these statistics (clipped to ±10) first, if present.
    pub obs_rms: Option<RunningMeanStd>,
    /// From the input on.
    pub layers: Vec<DenseLayer>,
    pub hidden: Activation,
    pub head: PolicyHead,
}
