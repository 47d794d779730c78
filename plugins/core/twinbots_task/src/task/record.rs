//! What episode replay (`crate::replay`) needs kept per arena: the stream its running episode
//! was reset from and the actions it got since.

use bevy::prelude::*;
use rand_chacha::ChaCha8Rng;
use twinbots_sim::Arena;

/// An arena's running episode: its stream when it was reset, and the actions since.
#[derive(Component, Clone, Debug)]
pub struct EpisodeRecord {
    pub start: ChaCha8Rng,
    pub actions: Vec<f32>,
}

/// Notes that `arena`'s episode starts now, from its current stream (call before the reset draws).
pub fn record_start(world: &mut World, arena: Entity) {
    let Some(start) = world.get::<Arena>(arena).map(|a| a.rng.clone()) else { return };
    world.entity_mut(arena).insert(EpisodeRecord { start, actions: Vec::new() });
}

/// Appends the actions an arena got this step to its record.
pub fn record_actions(world: &mut World, arena: Entity, actions: &[f32]) {
    if let Some(mut record) = world.get_mut::<EpisodeRecord>(arena) {
        record.actions.extend_from_slice(actions);
    }
}
