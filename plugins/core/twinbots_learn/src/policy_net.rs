//! A deterministic policy as plain numbers: the observation normaliser, what the dense layers
//! read (the observation, or a camera image's CNN features), the dense layers, and how the
//! action comes out of the last one. What an exporter (ONNX) needs of any algorithm's
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

/// The index of the largest logit, the last of equal ones: a discrete policy's deterministic
/// choice, as [`PolicyHead::ArgMax`] exports it.
pub fn arg_max(logits: &[f32]) -> usize {
    (0..logits.len()).max_by(|&i, &j| logits[i].total_cmp(&logits[j])).unwrap_or(0)
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

/// A convolution of an image `[height, width, in_channels]` (channels last, no padding):
/// `filters` outputs per pixel, ReLU after.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvLayer {
    pub name: String,
    pub kernel: usize,
    pub stride: usize,
    pub in_channels: usize,
    pub filters: usize,
    /// `[filters, kernel · kernel · in_channels]`, row-major; a patch's values in (kernel row,
    /// kernel column, channel) order.
    pub weight: Vec<f32>,
    pub bias: Vec<f32>,
}

/// Features of a camera image: values times `scale`, the convolutions, then `head`.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvEncoder {
    pub height: usize,
    pub width: usize,
    pub channels: usize,
    pub scale: f32,
    pub convs: Vec<ConvLayer>,
    pub head: ConvHead,
    /// State values after the image's, passed beside its features as they are.
    pub state: usize,
}

/// What follows a [`ConvEncoder`]'s convolutions.
#[derive(Clone, Debug, PartialEq)]
pub enum ConvHead {
    /// NatureCNN: ReLU after every convolution, the last one's maps flattened in (row, column,
    /// channel) order through this layer, ReLU after.
    Dense(DenseLayer),
    /// Keypoints: ReLU after every convolution but the last; per map of the last a softmax over
    /// its pixels and the expected (x, y) under it, the pixel centres spread evenly over
    /// [−1, 1] (left to right, top to bottom): each map's x, then its y.
    Keypoints,
}

/// Pixel centres of an `h × w` map, row by row, as (x, y) in [−1, 1]: where a keypoint of
/// [`ConvHead::Keypoints`] lies when its map's softmax sits on one pixel.
pub fn keypoint_grid(h: usize, w: usize) -> Vec<f32> {
    let at = |i: usize, n: usize| if n > 1 { -1.0 + 2.0 * i as f32 / (n - 1) as f32 } else { 0.0 };
    (0..h).flat_map(|y| (0..w).flat_map(move |x| [at(x, w), at(y, h)])).collect()
}

/// What the dense layers read.
#[derive(Clone, Debug, PartialEq)]
pub enum InputEncoding {
    /// The (normalised) observation as it is.
    Flat,
    /// Every value times `scale` (an MLP on pixels: 1/255).
    Scaled {
        scale: f32,
    },
    Cnn(ConvEncoder),
}

/// A policy's deterministic action as an MLP.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyNet {
    /// Observations are normalised with these statistics (clipped to ±10) first, if present.
    pub obs_rms: Option<RunningMeanStd>,
    pub encoding: InputEncoding,
    /// From the input on.
    pub layers: Vec<DenseLayer>,
    pub hidden: Activation,
    pub head: PolicyHead,
}
