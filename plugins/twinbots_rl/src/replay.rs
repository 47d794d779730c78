//! Episode replay: the state of a vectorised env, kept as the starts and actions of its running
//! episodes, so a checkpoint can put the envs back exactly where they were.
//!
//! An arena's episode is a function of its random stream when it was reset and the actions it
//! got since (physics, devices, noise and randomization all draw from that stream; the device
//! schedule from the control-step clock). So instead of serialising the physics world and every
//! device, a checkpoint keeps, per arena, the stream state at its episode's reset and the
//! actions since ([`EnvState`]), and [`replay`] resets each arena from that stream and steps the
//! actions again. A resumed run then continues bit for bit as the uninterrupted one would.
//!
//! Arenas' episodes started at different steps. The replay starts with the clock where the
//! oldest running episode began, and starts each younger episode when its turn comes; until
//! then that arena steps with a neutral action, and what it does is thrown away by its reset.

use bevy::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use twinbots_sim::{Arena, SimClock};

use crate::env::VecEnv;

/// A ChaCha stream's exact position, as a file can keep it.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct StreamState {
    /// The 32-byte key, as hex.
    pub seed: String,
    pub stream: u64,
    /// 32-bit words consumed since the start of the stream (a u128, as a decimal string).
    pub word_pos: String,
}

impl StreamState {
    pub fn of(rng: &ChaCha8Rng) -> Self {
        Self {
            seed: rng.get_seed().iter().map(|b| format!("{b:02x}")).collect(),
            stream: rng.get_stream(),
            word_pos: rng.get_word_pos().to_string(),
        }
    }

    pub fn to_rng(&self) -> anyhow::Result<ChaCha8Rng> {
        let bad = || anyhow::anyhow!("a random stream's state is damaged: {self:?}");
        anyhow::ensure!(self.seed.len() == 64, bad());
        let mut seed = [0u8; 32];
        for (i, byte) in seed.iter_mut().enumerate() {
            *byte = u8::from_str_radix(&self.seed[2 * i..2 * i + 2], 16).map_err(|_| bad())?;
        }
        let mut rng = ChaCha8Rng::from_seed(seed);
        rng.set_stream(self.stream);
        rng.set_word_pos(self.word_pos.parse::<u128>().map_err(|_| bad())?);
        Ok(rng)
    }
}

/// An arena's running episode: its stream when it was reset, and the actions since.
#[derive(Component, Clone, Debug)]
pub struct EpisodeRecord {
    pub start: ChaCha8Rng,
    pub actions: Vec<f32>,
}

/// One env's running episode, as a checkpoint keeps it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunningEpisode {
    pub start: StreamState,
    /// Flat, `steps × action dimension`.
    pub actions: Vec<f32>,
}

/// A vectorised env's state: the control-step clock and each env's running episode.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EnvState {
    pub clock: u64,
    pub episodes: Vec<RunningEpisode>,
}

/// Notes that `arena`'s episode starts now, from its current stream (call before the reset draws).
pub(crate) fn record_start(world: &mut World, arena: Entity) {
    let Some(start) = world.get::<Arena>(arena).map(|a| a.rng.clone()) else { return };
    world.entity_mut(arena).insert(EpisodeRecord { start, actions: Vec::new() });
}

/// Appends the actions an arena got this step to its record.
pub(crate) fn record_actions(world: &mut World, arena: Entity, actions: &[f32]) {
    if let Some(mut record) = world.get_mut::<EpisodeRecord>(arena) {
        record.actions.extend_from_slice(actions);
    }
}

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
pub fn begin_episodes(world: &mut World, arenas: &[Entity], starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
    if let Some(clock) = clock {
        world.resource_mut::<SimClock>().control_steps = clock;
    }
    let mut chosen = Vec::with_capacity(starts.len());
    for (index, stream) in starts {
        let &arena = arenas.get(*index).ok_or_else(|| anyhow::anyhow!("no env {index} (there are {})", arenas.len()))?;
        let rng = stream.to_rng()?;
        world.get_mut::<Arena>(arena).ok_or_else(|| anyhow::anyhow!("env {index} is not an arena"))?.rng = rng;
        chosen.push(arena);
    }
    if !chosen.is_empty() {
        crate::task::reset(world, &chosen);
    }
    Ok(crate::env::observations(world, arenas))
}

/// Puts `env` back in `state` by replaying its running episodes; returns the observations the
/// envs are at (raw). `env` must be a fresh env of the same robot, task and arena count.
pub fn replay(env: &mut dyn VecEnv, state: &EnvState) -> anyhow::Result<Vec<f32>> {
    let n = env.num_envs();
    let dim = env.action_space().dim();
    anyhow::ensure!(
        state.episodes.len() == n,
        "the checkpoint's env has {} arenas, this one {n}: resume with the run's own arena count",
        state.episodes.len()
    );
    let lengths: Vec<usize> = state
        .episodes
        .iter()
        .map(|e| {
            anyhow::ensure!(e.actions.len() % dim == 0, "a recorded episode's actions do not fit the action dimension {dim}");
            Ok(e.actions.len() / dim)
        })
        .collect::<anyhow::Result<_>>()?;
    let longest = lengths.iter().copied().max().unwrap_or(0);
    anyhow::ensure!(state.clock >= longest as u64, "a recorded episode is older than the clock ({} steps at step {})", longest, state.clock);
    let neutral = env.action_space().neutral();
    let mut obs = Vec::new();
    for step in 0..=longest {
        // Episodes with `longest - step` steps to go start now.
        let starts: Vec<(usize, StreamState)> = (0..n)
            .filter(|&i| longest - lengths[i] == step)
            .map(|i| (i, state.episodes[i].start.clone()))
            .collect();
        let clock = (step == 0).then(|| state.clock - longest as u64);
        if !starts.is_empty() || clock.is_some() {
            obs = env.begin_episodes(&starts, clock)?;
        }
        if step == longest {
            break;
        }
        let mut actions = Vec::with_capacity(n * dim);
        for (i, episode) in state.episodes.iter().enumerate() {
            let started = longest - lengths[i];
            if step >= started {
                let k = step - started;
                actions.extend_from_slice(&episode.actions[k * dim..(k + 1) * dim]);
            } else {
                actions.extend_from_slice(&neutral);
            }
        }
        obs = env.step(&actions)?.obs;
    }
    Ok(obs)
}
