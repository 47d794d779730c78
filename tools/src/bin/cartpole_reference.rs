//! A trained cart-pole model, evaluated at the fine-step reference timing (1 ms physics steps,
//! 16 solver iterations) instead of the twin's training timing: what `tests/sim/accuracy.rs`
//! bounds step by step, checked on the learned policy's score.
//!
//! `cargo run --release -p twinbots_tools --bin cartpole_reference <run-dir> [episodes]`

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::Ppo;
use twinbots_sim::SimSettings;
use twinbots_task::AppVecEnv;
use twinbots_task::robot::{AppRequest, headless_app};

fn main() -> anyhow::Result<()> {
    let run =
        std::env::args().nth(1).ok_or_else(|| anyhow::anyhow!("usage: cartpole_reference <run-dir> [episodes]"))?;
    let episodes: usize = std::env::args().nth(2).and_then(|a| a.parse().ok()).unwrap_or(20);
    let model = Ppo::load(std::path::Path::new(&run).join("model"))?;
    let training = cartpole::sim_settings();
    let reference = SimSettings {
        dt: 0.001,
        substeps: (training.control_dt() / 0.001).round() as u32,
        solver_iterations: 16,
        ..training
    };
    for (name, settings) in [("training timing", training), ("reference timing", reference)] {
        let request = AppRequest { task: "balance", arenas: 4, seed: 12345, pattern: DesignPattern::Supervised };
        let mut env = AppVecEnv::new(headless_app(settings, &request, cartpole::CartPolePlugin::default()));
        let mut obs = env.reset(Some(12345))?;
        let mut scores = Vec::new();
        while scores.len() < episodes {
            let step = env.step(&model.predict_deterministic(&obs)?)?;
            scores.extend(step.episodes.iter().flatten().map(|e| e.score));
            obs = step.obs;
        }
        let mean = scores.iter().sum::<f32>() / scores.len() as f32;
        let min = scores.iter().copied().fold(f32::INFINITY, f32::min);
        println!("{name}: {} episodes, mean score {mean:.1}, min {min:.0}", scores.len());
    }
    Ok(())
}
