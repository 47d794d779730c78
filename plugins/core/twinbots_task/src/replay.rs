//! The world side of episode replay (`twinbots_api::env_state`): each arena's running episode
//! is recorded as the stream it was reset from and the actions it got since, and new episodes
//! are begun from given streams.

use bevy::prelude::*;
use twinbots_sim::{Arena, SimClock};

use twinbots_api::{EnvState, RunningEpisode, StreamState};

use crate::task::record::EpisodeRecord;
use crate::task::{observations, reset};

/// The state of the env made of `arenas`; `None` if an arena has not been reset through
/// [`crate::task::reset`] (nothing recorded its episode).
pub fn env_state(world: &World, arenas: &[Entity]) -> Option<EnvState> {
    let episodes = arenas
        .iter()
        .map(|&a| {
            let record = world.get::<EpisodeRecord>(a)?;
            Some(RunningEpisode { start: StreamState::of(&record.start), actions: record.actions.clone() })
        })
        .collect::<Option<Vec<_>>>()?;
    let clock = world.get_resource::<SimClock>()?.control_steps;
    Some(EnvState { clock, episodes })
}

/// Starts new episodes in `starts` (arena position, stream), with the clock set to `clock`
/// first if given; returns every arena's observation.
pub fn begin_episodes(
    world: &mut World,
    arenas: &[Entity],
    starts: &[(usize, StreamState)],
    clock: Option<u64>,
) -> anyhow::Result<Vec<f32>> {
    if let Some(clock) = clock {
        world.resource_mut::<SimClock>().control_steps = clock;
    }
    let mut chosen = Vec::with_capacity(starts.len());
    for (index, stream) in starts {
        let &arena =
            arenas.get(*index).ok_or_else(|| anyhow::anyhow!("no env {index} (there are {})", arenas.len()))?;
        let rng = stream.to_rng()?;
        world.get_mut::<Arena>(arena).ok_or_else(|| anyhow::anyhow!("env {index} is not an arena"))?.rng = rng;
        chosen.push(arena);
    }
    if !chosen.is_empty() {
        reset(world, &chosen);
    }
    Ok(observations(world, arenas))
}
