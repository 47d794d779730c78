//! A task in the manner of Isaac Lab's manager-based envs: named observation, reward and
//! termination terms and start events ([`terms`]) over the state a robot's controller reads,
//! evaluated into an arena's [`Episode`], and resets when an episode ends.
//!
//! Per arena entity: the [`Action`] to apply, the controller's state `S`, and the [`Episode`] it
//! produced. The generic part (evaluating terms, tallying, auto-reset with the final
//! observation kept) lives here; a robot plugin adds its state readers to [`TaskSet::Read`] and
//! [`ResetSet::Read`], and what puts a drawn start state in place to [`ResetSet::Place`].

use std::collections::BTreeMap;

use bevy::ecs::component::Mutable;
use bevy::ecs::schedule::ScheduleLabel;
use bevy::prelude::*;
use twinbots_sim::{Arena, ArenaConfig, SimSet, SimSettings, Supervisor};

pub use twinbots_api::{
    DesignPattern, EpisodeSummary, GoalChange, GoalSpec, Measure, SolvedCriterion, Space, TaskSpec,
};

pub mod record;
pub mod terms;
pub use terms::{ObservationTerm, RewardTerm, StartEvent, StepOutcome, TaskTerms, TerminationTerm};

/// The running task's spec, as the app's resource (inserted by the task's plugin).
#[derive(Resource, Clone, Debug, Deref)]
pub struct ActiveTask(pub TaskSpec);

/// The action the task applies on the next control step (flat, see [`Space`]); empty until the
/// first one arrives, which leaves the actuators as they are.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Action(pub Vec<f32>);

/// What the last control step produced in an arena: the observation, the step's outcome, the
/// running episode's figures, and the episode that ended on this step, if one did.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Episode {
    /// The observation after the last step (after an auto-reset: the next episode's first).
    pub observation: Vec<f32>,
    /// The last step's reward and whether (and by which term) it ended the episode.
    pub step: StepOutcome,
    /// The running episode's figures.
    pub running: EpisodeFigures,
    /// Set on the step an episode ended and the arena was auto-reset.
    pub ended: Option<EndedEpisode>,
}

/// The running episode's figures, as the task's terms report them; they go into its summary
/// when it ends.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EpisodeFigures {
    /// Steps and summed reward so far.
    pub length: u32,
    pub score: f32,
    pub success: Option<bool>,
    pub metrics: BTreeMap<String, f32>,
    /// The sum of each reward term, in the terms' order.
    pub reward_sums: Vec<f32>,
}

/// An episode that ended on the last step.
#[derive(Clone, Debug, PartialEq)]
pub struct EndedEpisode {
    /// Its last observation (for bootstrapping a truncated episode's value).
    pub final_observation: Vec<f32>,
    pub summary: EpisodeSummary,
}

impl Episode {
    /// Starts the count of a new episode (its observation is the caller's).
    pub fn begin(&mut self) {
        self.running = EpisodeFigures::default();
    }

    /// Counts the step just evaluated into the running episode.
    pub fn tally(&mut self) {
        self.running.length += 1;
        self.running.score += self.step.reward;
    }

    /// Whether the last step ended the episode.
    pub fn done(&self) -> bool {
        self.step.terminated || self.step.truncated
    }

    /// The summary of the episode that just ended, if one did.
    pub fn finished(&self) -> Option<&EpisodeSummary> {
        self.ended.as_ref().map(|e| &e.summary)
    }
}

impl EpisodeFigures {
    /// The summary of the episode these figures count; they are taken.
    pub fn summary(&mut self, reward_terms: &[String]) -> EpisodeSummary {
        EpisodeSummary {
            score: self.score,
            length: self.length,
            success: self.success.take(),
            metrics: std::mem::take(&mut self.metrics),
            rewards: reward_terms.iter().cloned().zip(self.reward_sums.iter().copied()).collect(),
        }
    }
}

/// Marks an arena while the [`EnvReset`] schedule resets it: reset systems act on `With<Resetting>`.
#[derive(Component, Clone, Copy, Debug, Default)]
pub struct Resetting;

/// A task's terms over the controller state `S`, as a resource (see [`TaskTerms`]).
#[derive(Resource)]
pub struct Terms<S: Send + Sync + 'static>(pub TaskTerms<S>);

/// Order of a task's work inside [`SimSet::Task`].
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum TaskSet {
    /// The robot's controller reads its state `S` (its devices, or the Supervisor where the
    /// pattern allows).
    Read,
    /// The terms turn the state into observation, reward, termination (generic).
    Evaluate,
    /// The task reports figures of episodes that ended (energy, cycle time, success judged by
    /// an evaluator).
    Report,
    /// Scores and lengths are tallied (generic).
    Tally,
}

/// Resets every arena marked [`Resetting`].
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct EnvReset;

/// Order inside [`EnvReset`].
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ResetSet {
    /// The Supervisor puts the arena back to its initial state (generic).
    Restore,
    /// The task's start events draw the new episode's command and start state (generic).
    Start,
    /// The robot plugin puts the drawn start state in place (through the Supervisor).
    Place,
    /// Sensors sample the new state (generic).
    Sense,
    /// The controller reads its state again…
    Read,
    /// …and the terms give the episode's first observation (generic).
    Observe,
}

/// The generic episode machinery of patterns 1 and 2: tallies, same-step auto-reset through
/// the Supervisor. [`TaskTermsPlugin`] adds it; robot plugins add their readers and placers.
pub struct TaskPlugin;

impl Plugin for TaskPlugin {
    fn build(&self, app: &mut App) {
        configure_task_sets(app);
        app.init_resource::<RewardTermNames>()
            .add_systems(Update, tally_episodes.in_set(TaskSet::Tally))
            .add_systems(Update, auto_reset.in_set(SimSet::Reset))
            .add_schedule(Schedule::new(EnvReset))
            .configure_sets(
                EnvReset,
                (
                    ResetSet::Restore,
                    ResetSet::Start,
                    ResetSet::Place,
                    ResetSet::Sense,
                    ResetSet::Read,
                    ResetSet::Observe,
                )
                    .chain(),
            )
            .add_systems(
                EnvReset,
                (
                    restore_arenas.in_set(ResetSet::Restore),
                    twinbots_sim::devices::sample_devices().in_set(ResetSet::Sense),
                ),
            );
    }
}

/// Orders [`TaskSet`] inside [`SimSet::Task`] (every pattern's task work runs in it).
pub fn configure_task_sets(app: &mut App) {
    app.configure_sets(
        Update,
        (TaskSet::Read, TaskSet::Evaluate, TaskSet::Report, TaskSet::Tally).chain().in_set(SimSet::Task),
    );
}

/// A task: its name, its terms over the controller state `S`, its action space, when it
/// counts as solved and, for a goal-conditioned task, its goal interface (what HER relabels
/// with). Its [`TaskSpec`] is derived from these alone.
pub struct TaskDefinition<S> {
    pub name: String,
    pub terms: TaskTerms<S>,
    pub action_space: Space,
    pub solved: Option<SolvedCriterion>,
    pub goal: Option<GoalSpec>,
}

impl<S> TaskDefinition<S> {
    pub fn spec(&self) -> TaskSpec {
        TaskSpec {
            name: self.name.clone(),
            observation_space: self.terms.observation_space(),
            action_space: self.action_space.clone(),
            solved: self.solved,
            observation_names: self.terms.observation_names(),
            reward_terms: self.terms.reward_names().into_iter().map(String::from).collect(),
            termination_terms: self.terms.termination_names(),
            reward_range: self.terms.reward_range(),
            observation_plausible: self.terms.observation_plausible(),
            goal: self.goal,
        }
    }
}

/// A task defined by its terms over the controller state `S` (a component on each arena):
/// inserts the [`Terms`] and the [`TaskSpec`] built from them, and, for patterns 1 and 2,
/// evaluates them every step and runs their start events at every reset. Under pattern 3 the
/// robot's conversation with its server runs the episodes with the same terms.
pub struct TaskTermsPlugin<S> {
    pub pattern: DesignPattern,
    task: std::sync::Mutex<Option<TaskDefinition<S>>>,
}

impl<S> TaskTermsPlugin<S> {
    pub fn new(task: TaskDefinition<S>, pattern: DesignPattern) -> Self {
        Self { pattern, task: std::sync::Mutex::new(Some(task)) }
    }
}

impl<S: Component<Mutability = Mutable>> Plugin for TaskTermsPlugin<S> {
    fn build(&self, app: &mut App) {
        let task = self.task.lock().expect("not poisoned").take().expect("a TaskTermsPlugin is built once");
        let spec = task.spec();
        configure_task_sets(app);
        if self.pattern != DesignPattern::Server {
            if !app.is_plugin_added::<TaskPlugin>() {
                app.add_plugins(TaskPlugin);
            }
            app.insert_resource(RewardTermNames(spec.reward_terms.clone()))
                .add_systems(Update, evaluate_terms::<S>.in_set(TaskSet::Evaluate))
                .add_systems(
                    EnvReset,
                    (start_episodes::<S>.in_set(ResetSet::Start), observe_terms::<S>.in_set(ResetSet::Observe)),
                );
        }
        app.insert_resource(ActiveTask(spec)).insert_resource(Terms(task.terms));
    }
}

/// Names of the running task's reward terms, for episode summaries.
#[derive(Resource, Clone, Debug, Default)]
struct RewardTermNames(Vec<String>);

fn evaluate_terms<S: Component>(terms: Res<Terms<S>>, mut arenas: Query<(&S, &mut Episode)>) {
    for (state, mut episode) in &mut arenas {
        let e = &mut *episode;
        terms.0.observe(state, &mut e.observation);
        e.step = terms.0.evaluate(state, e.running.length, &mut e.running.reward_sums);
        if e.step.success.is_some() {
            e.running.success = e.step.success;
        }
    }
}

fn start_episodes<S: Component<Mutability = Mutable>>(
    terms: Res<Terms<S>>,
    mut arenas: Query<(&mut S, &mut Arena), With<Resetting>>,
) {
    for (mut state, mut arena) in &mut arenas {
        terms.0.start(&mut state, &mut arena.rng);
    }
}

fn observe_terms<S: Component>(terms: Res<Terms<S>>, mut arenas: Query<(&S, &mut Episode), With<Resetting>>) {
    for (state, mut episode) in &mut arenas {
        terms.0.observe(state, &mut episode.observation);
    }
}

fn tally_episodes(mut episodes: Query<&mut Episode>) {
    for mut e in &mut episodes {
        e.tally();
        e.ended = None;
    }
}

/// Runs [`EnvReset`] on `arenas`: marks them [`Resetting`], runs the schedule, unmarks them.
/// Each arena's stream is recorded first, so its episode can be replayed (`crate::replay`).
pub fn reset(world: &mut World, arenas: &[Entity]) {
    for &arena in arenas {
        record::record_start(world, arena);
        world.entity_mut(arena).insert(Resetting);
    }
    world.run_schedule(EnvReset);
    for &arena in arenas {
        world.entity_mut(arena).remove::<Resetting>();
    }
}

/// Same-step auto-reset (as Stable-Baselines3's VecEnv): a finished episode's last observation
/// is kept in `final_observation`, and `observation` becomes the first of the next episode.
fn auto_reset(world: &mut World) {
    let names = world.resource::<RewardTermNames>().0.clone();
    let mut finished = Vec::new();
    let mut episodes = world.query::<(Entity, &mut Episode)>();
    for (arena, mut e) in episodes.iter_mut(world) {
        if e.done() {
            let summary = e.running.summary(&names);
            e.ended = Some(EndedEpisode { final_observation: e.observation.clone(), summary });
            finished.push(arena);
        }
    }
    if !finished.is_empty() {
        reset(world, &finished);
    }
}

fn restore_arenas(mut supervisor: Supervisor, mut episodes: Query<(Entity, &mut Episode), With<Resetting>>) {
    for (arena, mut e) in &mut episodes {
        supervisor.reset_arena(arena);
        e.begin();
    }
}

/// Spawns `ArenaConfig::count` arenas, each built by `build` (which spawns the cell and robot
/// into it and returns the components to keep on the arena entity), records each built state
/// as what a reset restores, and gives each an [`Action`] and an [`Episode`].
pub fn spawn_arenas<B: Bundle>(
    commands: &mut Commands,
    config: &ArenaConfig,
    settings: &SimSettings,
    mut build: impl FnMut(&mut Commands, Entity, &mut Arena) -> B,
) -> Vec<Entity> {
    (config.first..config.first + config.count)
        .map(|index| {
            let entity = commands.spawn_empty().id();
            let mut arena = Arena::new(index, config.seed, settings.dt, settings.gravity);
            let parts = build(commands, entity, &mut arena);
            arena.mark_initial();
            commands.entity(entity).insert((arena, parts, Action::default(), Episode::default()));
            entity
        })
        .collect()
}

pub fn episode(world: &World, arena: Entity) -> &Episode {
    world.get::<Episode>(arena).expect("every arena has an Episode")
}

/// The current observations of all arenas, flat.
pub fn observations(world: &World, arenas: &[Entity]) -> Vec<f32> {
    arenas.iter().flat_map(|&a| episode(world, a).observation.iter().copied()).collect()
}
