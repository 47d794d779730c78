//! Neural-network pieces the learners share, built on candle where candle's general-purpose
//! versions cost too much for the small networks of RL policies (measured on a 2-core VM, see
//! docs/architecture.md): a tanh activation that vectorises, and Adam over plain slices.

mod adam;
mod dense;
mod tanh;

pub use adam::{Adam, AdamConfig, GradientStep};
pub use dense::Dense;
pub use tanh::{fast_tanh, tanh};
