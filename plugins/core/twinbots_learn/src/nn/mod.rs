//! Neural-network pieces the learners share, built on candle where candle's general-purpose
//! versions cost too much for the small networks of RL policies (measured on a 2-core VM, see
//! docs/design/learners.md): a tanh activation that vectorises, a ReLU whose gradient is one
//! pass, Adam over plain slices, and
//! convolutions as patches times a matrix for the CNNs that read camera images.

mod adam;
mod conv;
mod dense;
mod encoder;
pub mod fused_mlp;
mod keypoints;
mod relu;
mod tanh;

pub use adam::{Adam, AdamConfig, GradientStep, flat_gradients, sum_gradients};
pub use conv::{Conv2d, Patches, unfold};
pub use dense::{Dense, layer_values};
pub use encoder::{CNN_MIN_SIZE, Encoder, NatureCnn, PolicyKind, check_normalization};
pub use keypoints::KeypointCnn;
pub use relu::relu;
pub use tanh::{fast_tanh, tanh};
