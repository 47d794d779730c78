//! `twinbots eval <run-dir>`: replays a trained model on its robot and reports episode scores.

use std::collections::BTreeMap;
use std::path::Path;

use bevy::app::App;
use serde::Serialize;
use twinbots_rl::{AppVecEnv, DesignPattern, Measure, Ppo, SolvedCriterion, VecEnv};

use crate::cli::train::{TrainSettings, load_model};
use crate::registry;

#[derive(Clone, Debug, Serialize)]
pub struct EvalResult {
    /// The task evaluated (the robot's own, or a variant given with `--task`).
    pub task: String,
    pub episodes: usize,
    pub mean_score: f32,
    pub std_score: f32,
    pub min_score: f32,
    pub max_score: f32,
    pub mean_length: f32,
    /// Share of episodes that reached their goal, for tasks that report success.
    pub success_rate: Option<f32>,
    /// Each figure the task reports (energy, events, cycle time…), averaged over the episodes
    /// that report it: cycle time over the successful ones.
    pub metrics: BTreeMap<String, f32>,
    pub scores: Vec<f32>,
}

impl EvalResult {
    /// Whether these episodes meet a solved criterion: at least its window of them, whose
    /// mean score (or success rate) exceeds its threshold.
    pub fn meets(&self, criterion: &SolvedCriterion) -> bool {
        let value = match criterion.measure {
            Measure::Score => self.mean_score,
            Measure::Success => self.success_rate.unwrap_or(0.0),
        };
        self.episodes >= criterion.window && value > criterion.threshold
    }

    /// One line per figure, for people.
    pub fn describe(&self) -> String {
        let mut out = format!(
            "{}: {} episodes, score {:.1} ± {:.1} (min {:.0}, max {:.0}), mean length {:.1}",
            self.task, self.episodes, self.mean_score, self.std_score, self.min_score, self.max_score, self.mean_length
        );
        if let Some(rate) = self.success_rate {
            out += &format!("\n  success rate {:.1} %", 100.0 * rate);
        }
        for (name, value) in &self.metrics {
            out += &format!("\n  {name}: {value:.3}");
        }
        out
    }
}

/// Runs the deterministic policy on a fresh app of `arenas` arenas until `episodes` episodes end.
pub fn evaluate(
    task: &str,
    make_app: &dyn Fn(usize, u64) -> anyhow::Result<App>,
    model: &Ppo,
    arenas: usize,
    episodes: usize,
    seed: u64,
) -> anyhow::Result<EvalResult> {
    let arenas = arenas.clamp(1, episodes.max(1));
    let mut env = AppVecEnv::new(make_app(arenas, seed)?);
    model.check_spaces(env.observation_space(), env.action_space())?;
    let mut obs = env.reset(Some(seed))?;
    let mut scores = Vec::new();
    let mut lengths = Vec::new();
    let mut successes = Vec::new();
    let mut figures: BTreeMap<String, Vec<f32>> = BTreeMap::new();
    while scores.len() < episodes {
        let step = env.step(&model.predict_deterministic(&obs)?)?;
        for ep in step.episodes.iter().flatten() {
            if scores.len() < episodes {
                scores.push(ep.score);
                lengths.push(ep.length as f32);
                successes.extend(ep.success.map(f32::from));
                for (name, value) in &ep.metrics {
                    figures.entry(name.clone()).or_default().push(*value);
                }
            }
        }
        obs = step.obs;
    }
    let n = scores.len() as f32;
    let mean = scores.iter().sum::<f32>() / n;
    let average = |xs: &[f32]| xs.iter().sum::<f32>() / xs.len() as f32;
    Ok(EvalResult {
        task: task.to_string(),
        success_rate: (!successes.is_empty()).then(|| average(&successes)),
        metrics: figures.iter().map(|(name, xs)| (name.clone(), average(xs))).collect(),
        episodes: scores.len(),
        mean_score: mean,
        std_score: (scores.iter().map(|s| (s - mean).powi(2)).sum::<f32>() / n).sqrt(),
        min_score: scores.iter().copied().fold(f32::INFINITY, f32::min),
        max_score: scores.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        mean_length: lengths.iter().sum::<f32>() / n,
        scores,
    })
}

/// The pattern a run's model is evaluated under: its own, except that a pattern-3 model runs
/// in-process (the policy is the same; only where it is hosted differs).
fn eval_pattern(settings: &TrainSettings) -> anyhow::Result<DesignPattern> {
    Ok(match settings.design_pattern()? {
        DesignPattern::Server => DesignPattern::Supervised,
        p => p,
    })
}

/// Loads the run's final model (or its newest checkpoint), evaluates it on the run's task or
/// on another `task` of the robot's cell, prints the figures and writes `eval.json` (or
/// `eval-<task>.json`) into the run directory.
pub fn eval_run(run: &Path, episodes: usize, arenas: Option<usize>, task: Option<&str>) -> anyhow::Result<EvalResult> {
    anyhow::ensure!(episodes > 0, "--episodes must be at least 1");
    let settings = TrainSettings::read(run)?;
    let entry = registry::find(&settings.robot)?;
    let model = load_model(run)?;
    let pattern = eval_pattern(&settings)?;
    let name = task.unwrap_or(entry.main_task().name);
    let make_app = |arenas: usize, seed: u64| entry.app(Some(name), arenas, seed, pattern);
    let result = evaluate(name, &make_app, &model, arenas.unwrap_or(settings.arenas), episodes, settings.seed + 2_000_003)?;
    println!("{}: {}", settings.robot, result.describe());
    let file = if name == entry.main_task().name { "eval.json".to_string() } else { format!("eval-{name}.json") };
    std::fs::write(run.join(file), serde_json::to_string_pretty(&result)?)?;
    Ok(result)
}

/// Writes the frames of one deterministic evaluation episode of the run's model.
pub fn record_episode(run: &Path, dir: &Path, size: (u32, u32), camera: &str, task: Option<&str>) -> anyhow::Result<()> {
    let settings = TrainSettings::read(run)?;
    let entry = registry::find(&settings.robot)?;
    let model = load_model(run)?;
    let mut env = AppVecEnv::new(entry.app(task, 1, settings.seed + 2_000_003, eval_pattern(&settings)?)?);
    model.check_spaces(env.observation_space(), env.action_space())?;
    let mut recorder = crate::cli::capture::Recorder::new(size, crate::cli::capture::camera(&entry, camera)?, dir)?;
    let mut obs = env.reset(Some(settings.seed + 2_000_003))?;
    recorder.frame(&mut env, 0)?;
    for step in 1.. {
        let out = env.step(&model.predict_deterministic(&obs)?)?;
        obs = out.obs;
        if out.episodes[0].is_some() {
            // The arena has auto-reset: the episode's last state is gone; stop at its end.
            break;
        }
        recorder.frame(&mut env, step)?;
    }
    println!("recorded {} frames of one episode to {}", recorder.written, dir.display());
    Ok(())
}
