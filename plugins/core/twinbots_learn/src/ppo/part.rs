//! A part of a PPO minibatch, and what computing it gives: the pieces the update shares
//! between its two threads and its two ways of computing a gradient (`fused.rs`, `update.rs`).

/// Some samples of a minibatch of `of`, with their advantages (normalised over the whole
/// minibatch).
pub(super) struct Part {
    pub samples: Vec<usize>,
    pub advantages: Vec<f32>,
    pub of: usize,
}

/// A part's share of the minibatch's loss terms, its samples' log π/π_old, and its gradient
/// of every variable (`named_vars` order; none where the loss does not reach one).
pub(super) struct PartGradient {
    pub policy_loss: f32,
    pub value_loss: f32,
    pub entropy: f32,
    pub log_ratio: Vec<f32>,
    pub gradients: Vec<Option<Vec<f32>>>,
}
