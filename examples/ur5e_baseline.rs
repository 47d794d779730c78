//! The UR5e cell driven by the classical resolved-rate controller (no learning): success rate,
//! cycle time, energy, joint-limit and collision events of the reach and of pick-and-place, the
//! figures `twinbots eval` reports for a trained model, for comparison; and the scripted
//! pick-and-place over the learned task's observation (`pick_place_learned::scripted`).
//!
//! `cargo run --release --example ur5e_baseline [episodes] [seed]`

use std::collections::BTreeMap;

use bevy::app::App;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_task::AppVecEnv;

fn run(name: &str, app: App, episodes: usize, seed: u64, policy: fn(&[f32]) -> Vec<f32>) {
    let mut env = AppVecEnv::new(app);
    let dim = env.observation_space().dim();
    let mut obs = env.reset(Some(seed)).expect("reset");
    let (mut done, mut successes) = (0, 0);
    let mut figures: BTreeMap<String, Vec<f32>> = BTreeMap::new();
    while done < episodes {
        let actions: Vec<f32> = obs.chunks(dim).flat_map(policy).collect();
        let step = env.step(&actions).expect("step");
        for ep in step.episodes.into_iter().flatten().take(episodes - done) {
            done += 1;
            if ep.success == Some(false) {
                println!("{name}: episode {done} failed: {:?}", ep.metrics);
            }
            successes += usize::from(ep.success == Some(true));
            for (k, v) in ep.metrics {
                figures.entry(k).or_default().push(v);
            }
        }
        obs = step.obs;
    }
    println!("{name}: {episodes} episodes, success rate {:.1} %", 100.0 * successes as f32 / episodes as f32);
    for (k, v) in figures {
        println!("  {k}: {:.3}", v.iter().sum::<f32>() / v.len() as f32);
    }
}

fn main() {
    let episodes = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(100);
    let seed = std::env::args().nth(2).and_then(|a| a.parse().ok()).unwrap_or(7);
    run("reach", ur5e::headless_app_with(8, seed, DesignPattern::Supervised), episodes, seed, ur5e::controller::act);
    run("pick-place", ur5e::pick_place_app(8, seed, DesignPattern::Supervised), episodes, seed, ur5e::controller::act);
    let learned = ur5e::robot()
        .app(Some("pick-place-learned"), 8, seed, DesignPattern::Supervised)
        .expect("the UR5e has the task");
    run("pick-place-learned (scripted)", learned, episodes, seed, ur5e::pick_place_learned::scripted);
}
