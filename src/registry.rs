//! The robots this build knows, each a Bevy plugin crate under `plugins/`.

use bevy::app::App;
use twinbots_rl::DesignPattern;

/// A registered robot: its name, what it is, and how to build a headless app of N arenas.
#[derive(Clone, Copy)]
pub struct RobotEntry {
    pub name: &'static str,
    pub description: &'static str,
    /// The design patterns (paper §3) the robot's task supports.
    pub patterns: &'static [DesignPattern],
    build: fn(arenas: usize, seed: u64, pattern: DesignPattern) -> App,
    /// The task's spaces and solved criterion.
    pub task: fn() -> twinbots_rl::TaskSpec,
    /// A design-pattern-3 robot process (no Supervisor), connecting to a RobotServer.
    pub server_robot: Option<fn(usize, u64, cartpole::server::ServerAddress) -> App>,
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
        patterns: &[DesignPattern::Supervised, DesignPattern::Radio],
        build: cartpole::headless_app_with,
        task: cartpole::task_spec,
        server_robot: Some(cartpole::robot_app),
        ppo: cartpole::ppo_config,
        arenas: 8,
        timesteps: 1_000_000,
    }, RobotEntry {
        name: "pioneer3at",
        description: "Pioneer 3-AT skid-steer base, 16 sonars, inverted pendulum; Box([-6.4],[6.4]) wheel speed, 64 ms step",
        patterns: &[DesignPattern::Supervised],
        build: pioneer3at::headless_app_with,
        task: pioneer3at::task_spec,
        server_robot: None,
        ppo: pioneer3at::ppo_config,
        arenas: 8,
        timesteps: 1_000_000,
    }]
}

impl RobotEntry {
    pub fn task(&self) -> twinbots_rl::TaskSpec {
        (self.task)()
    }

    /// A headless app of `arenas` arenas under `pattern`; an unsupported pattern is an error.
    pub fn headless_app(&self, arenas: usize, seed: u64, pattern: DesignPattern) -> anyhow::Result<App> {
        anyhow::ensure!(
            pattern != DesignPattern::Server,
            "design pattern 3 has no in-process env: use `twinbots serve` and `twinbots robot`"
        );
        anyhow::ensure!(
            self.patterns.contains(&pattern),
            "{} does not support design pattern {} (supported: {})",
            self.name,
            pattern.number(),
            self.patterns.iter().map(|p| p.number().to_string()).collect::<Vec<_>>().join(", ")
        );
        Ok((self.build)(arenas, seed, pattern))
    }
}

/// Looks a robot up by name; the error lists the known ones.
pub fn find(name: &str) -> anyhow::Result<RobotEntry> {
    let all = robots();
    let known: Vec<&str> = all.iter().map(|r| r.name).collect();
    all.into_iter()
        .find(|r| r.name == name)
        .ok_or_else(|| anyhow::anyhow!("unknown robot '{name}'; known robots: {}", known.join(", ")))
}
