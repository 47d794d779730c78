//! The robots this build knows, each a Bevy plugin crate under `plugins/`.

use bevy::app::App;

/// A registered robot: its name, what it is, and how to build a headless app of N arenas.
pub struct RobotEntry {
    pub name: &'static str,
    pub description: &'static str,
    pub headless_app: fn(arenas: usize, seed: u64) -> App,
    /// PPO settings that train this robot well (tuned like RL Zoo's per-env hyperparameters).
    pub ppo: fn() -> twinbots_rl::PpoConfig,
    /// Default arena count for training.
    pub arenas: usize,
    /// Default training budget (env steps summed over arenas).
    pub timesteps: u64,
}

/// Every robot of this build.
pub fn robots() -> Vec<RobotEntry> {
    vec![RobotEntry {
        name: "cartpole",
        description: "cart-pole twin (deepbots replica): 4 velocity-driven wheels, passive pole; Discrete(2), 32 ms step",
        headless_app: cartpole::headless_app,
        ppo: cartpole::ppo_config,
        arenas: 8,
        timesteps: 1_000_000,
    }]
}

/// Looks a robot up by name; the error lists the known ones.
pub fn find(name: &str) -> anyhow::Result<RobotEntry> {
    let all = robots();
    let known: Vec<&str> = all.iter().map(|r| r.name).collect();
    all.into_iter()
        .find(|r| r.name == name)
        .ok_or_else(|| anyhow::anyhow!("unknown robot '{name}'; known robots: {}", known.join(", ")))
}
