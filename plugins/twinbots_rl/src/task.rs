//! A task in the manner of Isaac Lab's manager-based envs: observation, reward and termination
//! systems that write an arena's [`Episode`], and reset events that run when an episode ends.
//!
//! Per arena entity: the [`Action`] to apply and the [`Episode`] it produced. The generic part
//! (tallying scores, auto-reset with the final observation kept) lives here; a robot plugin adds
//! its terms to [`TaskSet`] and its reset events to [`ResetSet`].

use std::collections::BTreeMap;

use bevy::ecs::schedule::ScheduleLabel;
use bevy::prelude::*;
use twinbots_sim::{SimSet, Supervisor};

use crate::spaces::Space;

/// The paper's three ways (§3) to put a robot and its RL model together.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum DesignPattern {
    /// 1. RLRobot + RLModel: the task reads the robot's sensors and may use the Supervisor.
    #[default]
    Supervised,
    /// 2. SupervisorRobot + SlaveRobot: the slave only has sensors, actuators and a radio; the
    ///    supervisor robot relays readings to the model and actions back, one step late each way.
    Radio,
    /// 3. Supervisor-free: a RobotServer hosts the model; the robot's Communicator talks to it.
    Server,
}

impl DesignPattern {
    /// From the paper's numbering (1, 2, 3).
    pub fn from_number(n: u8) -> Option<Self> {
        match n {
            1 => Some(Self::Supervised),
            2 => Some(Self::Radio),
            3 => Some(Self::Server),
            _ => None,
        }
    }

    pub fn number(self) -> u8 {
        match self {
            Self::Supervised => 1,
            Self::Radio => 2,
            Self::Server => 3,
        }
    }
}

/// What a robot's task promises: its spaces and when it counts as solved.
#[derive(Resource, Clone, Debug)]
pub struct TaskSpec {
    pub name: String,
    pub observation_space: Space,
    pub action_space: Space,
    pub solved: Option<SolvedCriterion>,
}

/// Solved when the mean of the last `window` episodes' `measure` exceeds `threshold`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolvedCriterion {
    pub window: usize,
    pub threshold: f32,
    pub measure: Measure,
}

/// What a solved criterion averages over episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Measure {
    /// The episode's score (summed reward).
    #[default]
    Score,
    /// 1 for an episode that reached its goal, 0 otherwise: the mean is the success rate.
    Success,
}

impl SolvedCriterion {
    /// Mean score of the last `window` episodes above `threshold`.
    pub fn mean_score(window: usize, threshold: f32) -> Self {
        Self { window, threshold, measure: Measure::Score }
    }

    /// Success rate of the last `window` episodes at least `rate`.
    pub fn success_rate(window: usize, rate: f32) -> Self {
        // Rates are multiples of 1/window: a hair below makes "at least" exact.
        Self { window, threshold: rate - 0.5 / window as f32, measure: Measure::Success }
    }

    /// Whether these episodes' values of `measure` (oldest first) meet the criterion.
    pub fn is_met(&self, values: &[f32]) -> bool {
        if values.len() < self.window {
            return false;
        }
        let last = &values[values.len() - self.window..];
        last.iter().sum::<f32>() / self.window as f32 > self.threshold
    }
}

/// The action the task applies on the next control step (flat, see [`Space`]).
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Action(pub Vec<f32>);

/// The score and length of a finished episode, and what the task reported of it.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct EpisodeSummary {
    pub score: f32,
    pub length: u32,
    /// Whether it reached the task's goal (Stable-Baselines3's `info["is_success"]`); `None`
    /// for tasks without a goal.
    pub success: Option<bool>,
    /// Named figures of the episode (Isaac Lab's episode log), e.g. energy or cycle time.
    pub metrics: BTreeMap<String, f32>,
}

/// What the last control step produced in an arena.
#[derive(Component, Clone, Debug, Default, PartialEq)]
pub struct Episode {
    pub observation: Vec<f32>,
    pub reward: f32,
    pub terminated: bool,
    pub truncated: bool,
    /// Steps and summed reward of the running episode.
    pub length: u32,
    pub score: f32,
    /// Set on the step an episode ended and the arena was auto-reset: its last observation
    /// (for bootstrapping truncated episodes) and its summary.
    pub final_observation: Option<Vec<f32>>,
    pub finished: Option<EpisodeSummary>,
    /// Asks for the arena to be reset by the next [`EnvReset`] run.
    pub needs_reset: bool,
    /// The running episode's success and figures, as the task's terms report them; they go
    /// into its summary when it ends.
    pub success: Option<bool>,
    pub metrics: BTreeMap<String, f32>,
}

/// Order of the task's terms inside [`SimSet::Task`].
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum TaskSet {
    Observe,
    Reward,
    Terminate,
    /// Scores and lengths are tallied (generic).
    Tally,
}

/// Runs reset for every arena whose [`Episode::needs_reset`] is set.
#[derive(ScheduleLabel, Clone, Debug, PartialEq, Eq, Hash)]
pub struct EnvReset;

/// Order inside [`EnvReset`].
#[derive(SystemSet, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ResetSet {
    /// The Supervisor puts the arena back to its initial state (generic).
    Restore,
    /// The task's reset events (randomisation of the start state).
    Events,
    /// Sensors sample the new state (generic).
    Sense,
    /// The task's observation term runs again, so the reset observation is fresh.
    Observe,
    /// Flags are cleared (generic).
    Finish,
}

/// The generic episode machinery. Robot plugins add their terms.
pub struct TaskPlugin;

impl Plugin for TaskPlugin {
    fn build(&self, app: &mut App) {
        app.configure_sets(
            Update,
            (TaskSet::Observe, TaskSet::Reward, TaskSet::Terminate, TaskSet::Tally)
                .chain()
                .in_set(SimSet::Task),
        )
        .add_systems(Update, tally_episodes.in_set(TaskSet::Tally))
        .add_systems(Update, auto_reset.in_set(SimSet::Reset))
        .add_schedule(Schedule::new(EnvReset))
        .configure_sets(
            EnvReset,
            (
                ResetSet::Restore,
                ResetSet::Events,
                ResetSet::Sense,
                ResetSet::Observe,
                ResetSet::Finish,
            )
                .chain(),
        )
        .add_systems(
            EnvReset,
            (
                restore_arenas.in_set(ResetSet::Restore),
                twinbots_sim::devices::sample_devices().in_set(ResetSet::Sense),
                finish_reset.in_set(ResetSet::Finish),
            ),
        );
    }
}

fn tally_episodes(mut episodes: Query<&mut Episode>) {
    for mut e in &mut episodes {
        e.length += 1;
        e.score += e.reward;
        e.final_observation = None;
        e.finished = None;
    }
}

/// Same-step auto-reset (as Stable-Baselines3's VecEnv): a finished episode's last observation
/// is kept in `final_observation`, and `observation` becomes the first of the next episode.
fn auto_reset(world: &mut World) {
    let mut any = false;
    let mut episodes = world.query::<&mut Episode>();
    for mut e in episodes.iter_mut(world) {
        if e.terminated || e.truncated {
            e.final_observation = Some(e.observation.clone());
            e.finished = Some(EpisodeSummary {
                score: e.score,
                length: e.length,
                success: e.success.take(),
                metrics: std::mem::take(&mut e.metrics),
            });
            e.needs_reset = true;
            any = true;
        }
    }
    if any {
        world.run_schedule(EnvReset);
    }
}

fn restore_arenas(mut supervisor: Supervisor, mut episodes: Query<(Entity, &mut Episode)>) {
    for (arena, mut e) in &mut episodes {
        if e.needs_reset {
            supervisor.reset_arena(arena);
            e.length = 0;
            e.score = 0.0;
            e.success = None;
            e.metrics.clear();
        }
    }
}

fn finish_reset(mut episodes: Query<&mut Episode>) {
    for mut e in &mut episodes {
        e.needs_reset = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_success_rate_criterion_needs_its_window_and_at_least_its_rate() {
        let c = SolvedCriterion::success_rate(20, 0.95);
        let mut values = vec![1.0; 19];
        assert!(!c.is_met(&values), "19 episodes are not a window of 20");
        values.push(0.0);
        assert!(c.is_met(&values), "19 of 20 is 95 %");
        values.push(0.0);
        assert!(!c.is_met(&values), "18 of the last 20 is 90 %");
    }
}

