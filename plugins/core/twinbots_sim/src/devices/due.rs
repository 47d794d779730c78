//! Whether a device samples now: the rule [`super::sampling`] states, asked by each device.

use super::mount::SamplingPeriod;
use crate::arena::Arena;

/// Whether a device of `arena` with `period` samples now (control step `step`).
pub(crate) fn samples_now(arena: &Arena, period: Option<&SamplingPeriod>, step: u64) -> bool {
    let changes = arena.unsampled;
    changes.restored || (changes.stepped && SamplingPeriod::due(period, step))
}

/// Whether `arena` changed at all since its devices last sampled: sensors that track the
/// world every step (an accelerometer's velocity history) follow it then.
pub(crate) fn world_changed(arena: &Arena) -> bool {
    arena.unsampled.stepped || arena.unsampled.restored
}

/// Whether `arena` was restored since its devices last sampled (histories must restart).
pub(crate) fn world_restored(arena: &Arena) -> bool {
    arena.unsampled.restored
}
