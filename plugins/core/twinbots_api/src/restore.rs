//! Restoring a vectorised env's state: kept as the starts and actions of its running episodes,
//! so a checkpoint can put the envs back exactly where they were. (Replaying a *robot log* on
//! the twin is `twinbots_sysid`'s, not this.)
//!
//! An arena's episode is a function of its random stream when it was reset and the actions it
//! got since (physics, devices, noise and randomization all draw from that stream; the device
//! schedule from the control-step clock). So instead of serialising the physics world and every
//! device, a checkpoint keeps, per arena, the stream state at its episode's reset and the
//! actions since ([`EnvState`]), and [`restore`] resets each arena from that stream and steps the
//! actions again. A resumed run then continues bit for bit as the uninterrupted one would.
//!
//! Arenas' episodes started at different steps. The restore starts with the clock where the
//! oldest running episode began, and starts each younger episode when its turn comes; until
//! then that arena steps with a neutral action, and what it does is thrown away by its reset.

use crate::env::VecEnv;
use crate::env_state::{EnvState, StreamState};

/// Puts `env` back in `state` by stepping its running episodes again; returns the observations the
/// envs are at (raw). `env` must be a fresh env of the same robot, task and arena count.
pub fn restore(env: &mut dyn VecEnv, state: &EnvState) -> anyhow::Result<Vec<f32>> {
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
            anyhow::ensure!(
                e.actions.len() % dim == 0,
                "a recorded episode's actions do not fit the action dimension {dim}"
            );
            Ok(e.actions.len() / dim)
        })
        .collect::<anyhow::Result<_>>()?;
    let longest = lengths.iter().copied().max().unwrap_or(0);
    anyhow::ensure!(
        state.clock >= longest as u64,
        "a recorded episode is older than the clock ({} steps at step {})",
        longest,
        state.clock
    );
    let neutral = env.action_space().neutral();
    let mut obs = Vec::new();
    for step in 0..=longest {
        // Episodes with `longest - step` steps to go start now.
        let starts: Vec<(usize, StreamState)> =
            (0..n).filter(|&i| longest - lengths[i] == step).map(|i| (i, state.episodes[i].start.clone())).collect();
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
