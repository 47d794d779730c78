//! `twinbots eval <run-dir>`: replays a trained model on its robot and reports episode scores.

use std::path::Path;

use bevy::app::App;
use serde::Serialize;
use twinbots_rl::{AppVecEnv, Ppo, VecEnv};

use crate::cli::train::{TrainSettings, load_model};
use crate::registry;

#[derive(Clone, Debug, Serialize)]
pub struct EvalResult {
    pub episodes: usize,
    pub mean_score: f32,
    pub std_score: f32,
    pub min_score: f32,
    pub max_score: f32,
    pub mean_length: f32,
    pub scores: Vec<f32>,
}

/// Runs the deterministic policy on a fresh app of `arenas` arenas until `episodes` episodes end.
pub fn evaluate(
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
    while scores.len() < episodes {
        let step = env.step(&model.predict_deterministic(&obs)?)?;
        for ep in step.episodes.iter().flatten() {
            if scores.len() < episodes {
                scores.push(ep.score);
                lengths.push(ep.length as f32);
            }
        }
        obs = step.obs;
    }
    let n = scores.len() as f32;
    let mean = scores.iter().sum::<f32>() / n;
    Ok(EvalResult {
        episodes: scores.len(),
        mean_score: mean,
        std_score: (scores.iter().map(|s| (s - mean).powi(2)).sum::<f32>() / n).sqrt(),
        min_score: scores.iter().copied().fold(f32::INFINITY, f32::min),
        max_score: scores.iter().copied().fold(f32::NEG_INFINITY, f32::max),
        mean_length: lengths.iter().sum::<f32>() / n,
        scores,
    })
}

/// Loads the run's final model (or its newest checkpoint), evaluates it, prints and writes
/// `eval.json` into the run directory.
pub fn eval_run(run: &Path, episodes: usize, arenas: Option<usize>) -> anyhow::Result<EvalResult> {
    let settings = TrainSettings::read(run)?;
    let entry = registry::find(&settings.robot)?;
    let model = load_model(run)?;
    let pattern = settings.design_pattern()?;
    let make_app = |arenas: usize, seed: u64| entry.headless_app(arenas, seed, pattern);
    let result = evaluate(&make_app, &model, arenas.unwrap_or(settings.arenas), episodes, settings.seed + 2_000_003)?;
    println!(
        "{}: {} episodes, score {:.1} ± {:.1} (min {:.0}, max {:.0}), mean length {:.1}",
        settings.robot, result.episodes, result.mean_score, result.std_score, result.min_score, result.max_score, result.mean_length
    );
    std::fs::write(run.join("eval.json"), serde_json::to_string_pretty(&result)?)?;
    Ok(result)
}

/// Writes the frames of one deterministic evaluation episode of the run's model.
pub fn record_episode(run: &Path, dir: &Path, size: (u32, u32), camera: &str) -> anyhow::Result<()> {
    let settings = TrainSettings::read(run)?;
    let entry = registry::find(&settings.robot)?;
    let model = load_model(run)?;
    let mut env = AppVecEnv::new(entry.headless_app(1, settings.seed + 2_000_003, settings.design_pattern()?)?);
    model.check_spaces(env.observation_space(), env.action_space())?;
    let mut recorder = crate::cli::capture::Recorder::new(size, crate::cli::capture::camera(camera)?, dir)?;
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
