//! `summary.json`: how a run went, the same for `train` and `serve`.

use serde::{Deserialize, Serialize};

use crate::agent::Agent;
use crate::evaluation::EvalResult;
use crate::stats::TrainingEnd;

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    pub robot: String,
    /// Design pattern (paper §3) it trained under.
    pub pattern: u8,
    pub timesteps: u64,
    pub episodes: u64,
    /// Wall-clock seconds of this session: a resumed run counts from its resumption.
    pub wall_clock_s_this_session: f64,
    /// Over the last 100 training episodes (none: no episode ended).
    pub mean_reward_last_100: Option<f32>,
    /// Over the last 100 training episodes that reported success.
    pub success_rate_last_100: Option<f32>,
    /// Why training ended, in words.
    pub ended: String,
    pub solved: bool,
    pub solved_at_timesteps: Option<u64>,
    /// What the solved criterion was judged on: "training episodes" or "evaluation".
    pub solved_by: Option<String>,
    /// The final model's evaluation, where the run had an in-process env to evaluate on.
    pub evaluation: Option<EvaluationSummary>,
    /// Where this session's wall clock went (`train`, headless).
    #[serde(default)]
    pub time_breakdown: Option<TimeBreakdown>,
}

/// Seconds of a training session by part. `simulation` is the app's stepping and resetting,
/// `bridge` the channel around it (the learner's wait for the env less the simulation),
/// `logging` the callbacks (progress, curve, evaluations, checkpoints), `other` the rest of the
/// wall clock (start-up, the final save).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TimeBreakdown {
    pub simulation_s: f64,
    pub inference_s: f64,
    pub update_s: f64,
    pub bridge_s: f64,
    pub logging_s: f64,
    pub other_s: f64,
}

impl TimeBreakdown {
    /// From the learner's times, the app's simulation time and the session's wall clock.
    pub fn new(learner: &crate::stats::TrainingTimes, simulation_s: f64, wall_clock_s: f64) -> Self {
        let bridge_s = (learner.env_s - simulation_s).max(0.0);
        let accounted = simulation_s + bridge_s + learner.inference_s + learner.update_s + learner.callbacks_s;
        Self {
            simulation_s,
            inference_s: learner.inference_s,
            update_s: learner.update_s,
            bridge_s,
            logging_s: learner.callbacks_s,
            other_s: (wall_clock_s - accounted).max(0.0),
        }
    }

    pub fn describe(&self) -> String {
        format!(
            "simulation {:.1} s, policy inference {:.1} s, learner updates {:.1} s, bridge {:.1} s, logging/evaluation/checkpoints {:.1} s, other {:.1} s",
            self.simulation_s, self.inference_s, self.update_s, self.bridge_s, self.logging_s, self.other_s
        )
    }
}

/// The headline figures of an [`EvalResult`] (the whole of it is in `eval.json`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EvaluationSummary {
    pub episodes: usize,
    pub mean_score: f32,
    pub std_score: f32,
    pub success_rate: Option<f32>,
}

impl Summary {
    /// The summary of a run of `robot` under `pattern` that left `model` and ended as `end`.
    pub fn new(
        robot: &str,
        pattern: u8,
        model: &dyn Agent,
        end: &TrainingEnd,
        wall_clock_s: f64,
        evaluation: Option<&EvalResult>,
    ) -> Self {
        let mean = model.history().mean_score();
        let solved_at = match end {
            TrainingEnd::Solved { timesteps, by } => Some((*timesteps, by.to_string())),
            _ => None,
        };
        Self {
            robot: robot.to_string(),
            pattern,
            timesteps: model.timesteps(),
            episodes: model.episodes(),
            wall_clock_s_this_session: wall_clock_s,
            mean_reward_last_100: mean.is_finite().then_some(mean),
            success_rate_last_100: model.history().success_rate(),
            ended: end.to_string(),
            solved: solved_at.is_some(),
            solved_at_timesteps: solved_at.as_ref().map(|(t, _)| *t),
            solved_by: solved_at.map(|(_, by)| by),
            evaluation: evaluation.map(|e| EvaluationSummary {
                episodes: e.episodes,
                mean_score: e.mean_score,
                std_score: e.std_score,
                success_rate: e.success_rate,
            }),
            time_breakdown: None,
        }
    }
}
