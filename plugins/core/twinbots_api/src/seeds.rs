//! Every seed a run derives from its own, in one table, so that no two random streams of a run
//! can coincide and a reader sees them all at once. A run's seed `s` gives:
//!
//! | stream | seed |
//! | --- | --- |
//! | the training arenas (arena `i`: `twinbots_sim::arena_rng(s, i)`), the networks' weights | `s` |
//! | periodic evaluations | `s + PERIODIC_EVALUATION` |
//! | the final evaluation (`eval.json`, `twinbots eval`) | `s + FINAL_EVALUATION` |
//! | DAgger round `r`'s rollouts (`twinbots distill`) | `s + DISTILL_ROUND + r` |
//! | PPO's action sampling and minibatches | `s ^ PPO_ACTIONS` |
//! | PPO's CNN weights, its value's own CNN | `s ^ PPO_ENCODER`, `s ^ PPO_VALUE_ENCODER` |
//! | SAC's action sampling | `s ^ SAC_SAMPLING` |
//! | TD3's exploration and target noise | `s ^ TD3_NOISE` |
//! | behaviour cloning's minibatches | `s ^ BC_SAMPLING` |
//! | an arena's looks (visual randomization), apart from its physics | arena seed `^ LOOKS` |
//! | a recording's sensor noise (`twinbots record`) | recording seed `^ RECORDING_NOISE` |
//!
//! Offsets are primes far apart, so no run's range of seeds reaches another's streams; salts
//! are XORed, so they keep a stream apart whatever the seed.

/// Periodic evaluations (the same seed each time, so they compare).
pub const PERIODIC_EVALUATION: u64 = 1_000_003;
/// The final model's evaluation.
pub const FINAL_EVALUATION: u64 = 2_000_003;
/// The first DAgger round's rollouts; round `r` adds `r`.
pub const DISTILL_ROUND: u64 = 3_000_003;

/// PPO's action-sampling and minibatch stream.
pub const PPO_ACTIONS: u64 = 0x0005_eed0_fa11;
/// PPO's CNN weights.
pub const PPO_ENCODER: u64 = 0xc0_5e_ed;
/// The weights of PPO's value's own CNN (features not shared with the policy).
pub const PPO_VALUE_ENCODER: u64 = 0x7a_1e_ed;
/// SAC's action-sampling stream.
pub const SAC_SAMPLING: u64 = 0x5ac_5eed;
/// TD3's noise stream.
pub const TD3_NOISE: u64 = 0x7d3_5eed;
/// Behaviour cloning's minibatch stream.
pub const BC_SAMPLING: u64 = 0xbc_5eed;
/// An arena's looks under visual randomization ("look").
pub const LOOKS: u64 = 0x6c6f_6f6b;
/// A recording's sensor noise.
pub const RECORDING_NOISE: u64 = 0x5e75_0a15;

// The offsets keep their order: each stream's seeds start past the one before.
const _: () = assert!(PERIODIC_EVALUATION < FINAL_EVALUATION && FINAL_EVALUATION < DISTILL_ROUND);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn no_two_streams_share_a_salt_or_an_offset() {
        let salts =
            [PPO_ACTIONS, PPO_ENCODER, PPO_VALUE_ENCODER, SAC_SAMPLING, TD3_NOISE, BC_SAMPLING, LOOKS, RECORDING_NOISE];
        for (i, a) in salts.iter().enumerate() {
            assert!(salts[i + 1..].iter().all(|b| a != b), "salt {a:#x} is used twice");
        }
    }
}
