//! `twinbots train <robot>`: PPO on N arenas, headless, into a run directory.
//!
//! The run directory holds `config.toml` (the resolved settings), `progress.csv` (one row per
//! update), `checkpoints/` (atomic, every `checkpoint_every` updates), `model/` (the final model)
//! and `summary.json`. Training stops at `--timesteps` or when the task's solved criterion holds.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use twinbots_rl::{AppVecEnv, Flow, Ppo, PpoConfig, UpdateStats, VecEnv};

use crate::registry;

#[derive(Clone, Debug, Serialize)]
pub struct TrainSettings {
    pub robot: String,
    pub timesteps: u64,
    pub arenas: usize,
    pub seed: u64,
    pub checkpoint_every: usize,
    pub ppo: PpoConfig,
}

const CSV_HEADER: &str = "update,timesteps,episodes,mean_reward,min_reward,max_reward,mean_length,policy_loss,value_loss,entropy,approx_kl,clip_fraction,learning_rate,steps_per_s";

fn csv_row(s: &UpdateStats) -> String {
    format!(
        "{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
        s.update, s.timesteps, s.episodes, s.mean_reward, s.min_reward, s.max_reward, s.mean_length,
        s.policy_loss, s.value_loss, s.entropy, s.approx_kl, s.clip_fraction, s.learning_rate, s.steps_per_s
    )
}

/// Default run directory: `runs/<robot>-<unix seconds>`.
pub fn default_run_dir(robot: &str) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    PathBuf::from("runs").join(format!("{robot}-{secs}"))
}

pub fn train(settings: TrainSettings, out: &Path) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    anyhow::ensure!(settings.arenas > 0, "--arenas must be at least 1");
    std::fs::create_dir_all(out.join("checkpoints"))?;
    std::fs::write(out.join("config.toml"), toml::to_string_pretty(&settings)?)?;
    let mut csv = std::fs::File::create(out.join("progress.csv"))?;
    writeln!(csv, "{CSV_HEADER}")?;

    let mut env = AppVecEnv::new((entry.headless_app)(settings.arenas, settings.seed));
    let solved = env.task().solved;
    let mut model = Ppo::new(
        settings.ppo.clone(),
        env.observation_space().clone(),
        env.action_space().clone(),
        settings.seed,
    )?;

    let bar = ProgressBar::new(settings.timesteps);
    bar.set_style(
        ProgressStyle::with_template("{elapsed_precise} [{bar:30}] {pos}/{len} steps {msg}")?
            .progress_chars("=> "),
    );
    let started = Instant::now();
    let mut solved_at = None;
    let mut callback = |s: &UpdateStats, m: &Ppo| -> anyhow::Result<Flow> {
        writeln!(csv, "{}", csv_row(s))?;
        bar.set_position(s.timesteps.min(settings.timesteps));
        bar.set_message(format!("{:.0} steps/s, mean reward {:.1} ({} episodes)", s.steps_per_s, s.mean_reward, s.episodes));
        if s.update % settings.checkpoint_every.max(1) == 0 {
            m.save(out.join("checkpoints").join(format!("step_{:010}", s.timesteps)))?;
        }
        let scores: Vec<f32> = m.recent_scores.iter().copied().collect();
        if let Some(c) = solved
            && c.is_met(&scores)
        {
            solved_at = Some(s.timesteps);
            return Ok(Flow::Stop);
        }
        Ok(Flow::Continue)
    };
    model.learn(&mut env, settings.timesteps, &mut callback)?;
    bar.finish();
    let wall = started.elapsed().as_secs_f64();
    model.save(out.join("model"))?;
    let summary = serde_json::json!({
        "robot": settings.robot,
        "timesteps": model.timesteps,
        "episodes": model.episodes,
        "wall_clock_s": wall,
        "mean_reward_last_100": model.mean_recent_score(),
        "solved": solved_at.is_some(),
        "solved_at_timesteps": solved_at,
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)?)?;
    match solved_at {
        Some(t) => println!("solved after {t} steps in {wall:.1} s (mean of last 100 episodes {:.1})", model.mean_recent_score()),
        None => println!("not solved: {} steps in {wall:.1} s, mean of last 100 episodes {:.1}", model.timesteps, model.mean_recent_score()),
    }
    println!("run directory: {}", out.display());
    Ok(())
}
