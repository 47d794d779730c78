//! The vectorised env API (Gymnasium / Stable-Baselines3 VecEnv semantics), the world-level
//! operations behind it, and its direct implementation over a Bevy app whose arenas are the envs.

use bevy::prelude::*;
use twinbots_sim::Arena;

use crate::replay::{EnvState, StreamState};
use crate::spaces::Space;
use crate::task::{Action, Episode, EpisodeSummary, TaskSpec};

/// What one vectorised step returns. Vectors are flat: env `i`'s observation is
/// `obs[i * obs_dim..(i + 1) * obs_dim]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StepResult {
    pub obs: Vec<f32>,
    pub rewards: Vec<f32>,
    pub terminated: Vec<bool>,
    pub truncated: Vec<bool>,
    /// For envs whose episode ended this step: the last observation of that episode (the
    /// `obs` entry is already the first of the next one).
    pub final_obs: Vec<Option<Vec<f32>>>,
    pub episodes: Vec<Option<EpisodeSummary>>,
}

/// N environments stepped together, with auto-reset. Errors mean the simulation is gone
/// (its thread ended or panicked), never bad luck: callers stop.
pub trait VecEnv {
    fn num_envs(&self) -> usize;
    fn observation_space(&self) -> &Space;
    fn action_space(&self) -> &Space;
    /// Resets every env; `seed` restarts their random streams (env `i` gets stream `i`).
    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>>;
    /// Applies `actions` (flat, `num_envs * action_dim`) and advances one control step.
    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult>;
    /// The envs' state as their running episodes (`crate::replay`), for a checkpoint; `None`
    /// for envs that cannot be replayed (a resumed run then starts fresh episodes).
    fn state(&mut self) -> anyhow::Result<Option<EnvState>> {
        Ok(None)
    }
    /// Starts new episodes in the envs of `starts`, each from its stream state, after setting
    /// the control-step clock to `clock` if given; returns every env's observation. What
    /// [`crate::replay::replay`] is made of.
    fn begin_episodes(&mut self, starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
        let _ = (starts, clock);
        anyhow::bail!("this env cannot replay episodes")
    }
}

/// Arena entities in env order (by `Arena::index`), found once the world is built.
#[derive(Resource, Clone, Debug, Default)]
pub struct ArenaOrder(pub Vec<Entity>);

/// Finds the arenas and records their order; call after start-up.
pub fn index_arenas(world: &mut World) -> Vec<Entity> {
    let mut arenas: Vec<(usize, Entity)> = world
        .query::<(Entity, &Arena)>()
        .iter(world)
        .map(|(e, a)| (a.index, e))
        .collect();
    arenas.sort();
    let order: Vec<Entity> = arenas.into_iter().map(|(_, e)| e).collect();
    world.insert_resource(ArenaOrder(order.clone()));
    order
}

fn episode(world: &World, arena: Entity) -> &Episode {
    world.get::<Episode>(arena).expect("every arena has an Episode")
}

/// The current observations of all arenas, flat.
pub fn observations(world: &World, arenas: &[Entity]) -> Vec<f32> {
    arenas.iter().flat_map(|&a| episode(world, a).observation.iter().copied()).collect()
}

/// Resets every arena (re-seeding their streams if `seed` is given) and returns observations.
pub fn reset_arenas(world: &mut World, arenas: &[Entity], seed: Option<u64>) -> Vec<f32> {
    if let Some(seed) = seed {
        for &arena in arenas {
            if let Some(mut a) = world.get_mut::<Arena>(arena) {
                a.reseed(seed);
            }
        }
    }
    crate::task::reset(world, arenas);
    observations(world, arenas)
}

/// Writes each arena's slice of the flat `actions` into its [`Action`].
pub fn write_actions(world: &mut World, arenas: &[Entity], actions: &[f32]) -> anyhow::Result<()> {
    let dim = world.resource::<TaskSpec>().action_space.dim();
    anyhow::ensure!(
        actions.len() == dim * arenas.len(),
        "step: got {} action values, expected {} arenas × dimension {dim}",
        actions.len(),
        arenas.len()
    );
    for (i, &arena) in arenas.iter().enumerate() {
        let own = &actions[i * dim..(i + 1) * dim];
        if let Some(mut a) = world.get_mut::<Action>(arena) {
            a.0.clear();
            a.0.extend_from_slice(own);
        }
        crate::replay::record_actions(world, arena, own);
    }
    Ok(())
}

/// What the last control step produced, for all arenas.
pub fn collect_step(world: &World, arenas: &[Entity]) -> StepResult {
    let mut out = StepResult {
        obs: observations(world, arenas),
        ..default()
    };
    for &arena in arenas {
        let e = episode(world, arena);
        out.rewards.push(e.reward);
        out.terminated.push(e.terminated);
        out.truncated.push(e.truncated);
        out.final_obs.push(e.final_observation.clone());
        out.episodes.push(e.finished.clone());
    }
    out
}

/// Builds an app's world: plugins finished, start-up run (arenas exist), no step taken.
pub fn start(app: &mut App) -> anyhow::Result<(Vec<Entity>, TaskSpec)> {
    app.finish();
    app.cleanup();
    app.update();
    let spec = app
        .world()
        .get_resource::<TaskSpec>()
        .cloned()
        .ok_or_else(|| anyhow::anyhow!("the app has no robot task plugin (nothing inserted a TaskSpec)"))?;
    let arenas = index_arenas(app.world_mut());
    anyhow::ensure!(!arenas.is_empty(), "the app has no arenas");
    Ok((arenas, spec))
}

/// A Bevy app stepped directly on the caller's thread: one `update` per vectorised step.
pub struct AppVecEnv {
    app: App,
    arenas: Vec<Entity>,
    spec: TaskSpec,
}

impl AppVecEnv {
    /// Takes an app with the sim, task and robot plugins added, and builds its world.
    pub fn new(mut app: App) -> Self {
        let (arenas, spec) = start(&mut app).expect("a robot app with arenas");
        Self { app, arenas, spec }
    }

    pub fn app(&self) -> &App {
        &self.app
    }

    pub fn app_mut(&mut self) -> &mut App {
        &mut self.app
    }

    /// Arena entities in env order.
    pub fn arenas(&self) -> &[Entity] {
        &self.arenas
    }

    pub fn task(&self) -> &TaskSpec {
        &self.spec
    }
}

impl VecEnv for AppVecEnv {
    fn num_envs(&self) -> usize {
        self.arenas.len()
    }

    fn observation_space(&self) -> &Space {
        &self.spec.observation_space
    }

    fn action_space(&self) -> &Space {
        &self.spec.action_space
    }

    fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<Vec<f32>> {
        Ok(reset_arenas(self.app.world_mut(), &self.arenas, seed))
    }

    fn step(&mut self, actions: &[f32]) -> anyhow::Result<StepResult> {
        write_actions(self.app.world_mut(), &self.arenas, actions)?;
        self.app.update();
        Ok(collect_step(self.app.world(), &self.arenas))
    }

    fn state(&mut self) -> anyhow::Result<Option<EnvState>> {
        Ok(crate::replay::env_state(self.app.world(), &self.arenas))
    }

    fn begin_episodes(&mut self, starts: &[(usize, StreamState)], clock: Option<u64>) -> anyhow::Result<Vec<f32>> {
        crate::replay::begin_episodes(self.app.world_mut(), &self.arenas, starts, clock)
    }
}

/// Gymnasium's `info` for one env: set on the step an episode ended (auto-reset happened).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Info {
    pub final_observation: Option<Vec<f32>>,
    pub episode: Option<EpisodeSummary>,
}

/// One transition, Gymnasium's `(obs, reward, terminated, truncated, info)`.
pub type Transition = (Vec<f32>, f32, bool, bool, Info);

/// Gymnasium's single-env surface over a one-env [`VecEnv`]. Finished episodes auto-reset
/// (the vectorised semantics); the finished episode's last observation is in `info`.
pub struct SingleEnv<V: VecEnv>(pub V);

impl<V: VecEnv> SingleEnv<V> {
    pub fn new(env: V) -> anyhow::Result<Self> {
        anyhow::ensure!(env.num_envs() == 1, "SingleEnv wraps exactly one env, got {}", env.num_envs());
        Ok(Self(env))
    }

    /// `reset(seed) -> (obs, info)`
    pub fn reset(&mut self, seed: Option<u64>) -> anyhow::Result<(Vec<f32>, Info)> {
        Ok((self.0.reset(seed)?, Info::default()))
    }

    /// `step(action) -> (obs, reward, terminated, truncated, info)`; the action must lie in the
    /// action space.
    pub fn step(&mut self, action: &[f32]) -> anyhow::Result<Transition> {
        anyhow::ensure!(
            self.0.action_space().contains(action),
            "action {action:?} is not in the action space {}",
            self.0.action_space()
        );
        let mut r = self.0.step(action)?;
        let info = Info {
            final_observation: r.final_obs.pop().flatten(),
            episode: r.episodes.pop().flatten(),
        };
        Ok((r.obs, r.rewards[0], r.terminated[0], r.truncated[0], info))
    }
}
