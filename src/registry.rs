//! The robots this build knows, each a Bevy plugin crate under `plugins/`.

use bevy::app::App;
use bevy::math::Vec3;
use twinbots_render::Framing;
use twinbots_rl::DesignPattern;

type AppBuilder = fn(arenas: usize, seed: u64, pattern: DesignPattern) -> App;

/// Another task of a robot's cell that a model trained on the robot's task runs unchanged
/// (the same spaces), such as the UR5e's pick-and-place driven by its reach model.
#[derive(Clone, Copy)]
pub struct TaskVariant {
    pub name: &'static str,
    pub description: &'static str,
    build: AppBuilder,
}

/// A registered robot: its name, what it is, and how to build a headless app of N arenas.
#[derive(Clone, Copy)]
pub struct RobotEntry {
    pub name: &'static str,
    pub description: &'static str,
    /// The design patterns (paper §3) the robot's task supports.
    pub patterns: &'static [DesignPattern],
    /// The task `train` learns.
    pub task_name: &'static str,
    build: AppBuilder,
    /// Further tasks of the cell a trained model can be evaluated and captured on.
    pub variants: &'static [TaskVariant],
    /// Where the cameras of `capture`, `eval --record` and `view` look.
    pub framing: Framing,
    /// The task's spaces and solved criterion.
    pub task: fn() -> twinbots_rl::TaskSpec,
    /// A design-pattern-3 robot process (no Supervisor), connecting to a RobotServer.
    pub server_robot: Option<fn(usize, u64, twinbots_server::robot::ServerAddress) -> App>,
    /// PPO settings that train this robot well (tuned like RL Zoo's per-env hyperparameters).
    pub ppo: fn() -> twinbots_rl::PpoConfig,
    /// Default arena count for training.
    pub arenas: usize,
    /// Default training budget (env steps summed over arenas).
    pub timesteps: u64,
    /// Default periodic evaluation: every this many updates (0: never), of this many episodes
    /// (also the size of the final evaluation).
    pub eval_every: usize,
    pub eval_episodes: usize,
}

/// Every robot of this build.
pub fn robots() -> Vec<RobotEntry> {
    vec![RobotEntry {
        name: "cartpole",
        description: "cart-pole twin (deepbots replica): 4 velocity-driven wheels, passive pole; Discrete(2), 32 ms step",
        patterns: &[DesignPattern::Supervised, DesignPattern::Radio],
        task_name: "balance",
        build: cartpole::headless_app_with,
        variants: &[],
        framing: Framing::default(),
        task: cartpole::task_spec,
        server_robot: Some(cartpole::robot_app),
        ppo: cartpole::ppo_config,
        arenas: 8,
        timesteps: 1_000_000,
        eval_every: 0,
        eval_episodes: 10,
    }, RobotEntry {
        name: "pioneer3at",
        description: "Pioneer 3-AT skid-steer base, 16 sonars, inverted pendulum; Box([-6.4],[6.4]) wheel speed, 64 ms step",
        patterns: &[DesignPattern::Supervised],
        task_name: "balance",
        build: pioneer3at::headless_app_with,
        variants: &[],
        framing: Framing::default(),
        task: pioneer3at::task_spec,
        server_robot: None,
        ppo: pioneer3at::ppo_config,
        arenas: 8,
        timesteps: 1_000_000,
        eval_every: 0,
        eval_episodes: 10,
    }, RobotEntry {
        name: "ur5e",
        description: "UR5e digital twin in an assembly cell (table, 2 fixtures, part, vacuum gripper); reach: Box([-1,1]^6) joint speeds, 40 ms step",
        patterns: &[DesignPattern::Supervised],
        task_name: "reach",
        build: ur5e::headless_app_with,
        variants: &[TaskVariant {
            name: "pick-place",
            description: "the part from fixture A to fixture B: a cell program of waypoints driven by the reach policy",
            build: ur5e::pick_place_app,
        }],
        // The arm works towards −x (its zero pose): cameras face it from there.
        framing: Framing { target: Vec3::new(-0.3, -0.05, 1.0), distance: 2.0, facing: std::f32::consts::PI },
        task: ur5e::task_spec,
        server_robot: Some(ur5e::server::robot_app),
        ppo: ur5e::ppo_config,
        arenas: 8,
        timesteps: 3_000_000,
        // The stochastic policy's training episodes lag its deterministic success far behind
        // (exploration noise spoils a 1 cm rest): judge the criterion on 200 evaluation
        // episodes every 20 updates (≈ 41 k steps), as SB3's EvalCallback does.
        eval_every: 20,
        eval_episodes: 200,
    }]
}

impl RobotEntry {
    pub fn task(&self) -> twinbots_rl::TaskSpec {
        (self.task)()
    }

    /// A headless app of `arenas` arenas of the robot's task under `pattern`; an unsupported
    /// pattern is an error.
    pub fn headless_app(&self, arenas: usize, seed: u64, pattern: DesignPattern) -> anyhow::Result<App> {
        self.task_app(None, arenas, seed, pattern)
    }

    /// Names of every task the robot's models can run, its own first.
    pub fn task_names(&self) -> Vec<&'static str> {
        std::iter::once(self.task_name).chain(self.variants.iter().map(|v| v.name)).collect()
    }

    /// A headless app of the named task (`None`: the robot's own); an unknown task or an
    /// unsupported pattern is an error.
    pub fn task_app(&self, task: Option<&str>, arenas: usize, seed: u64, pattern: DesignPattern) -> anyhow::Result<App> {
        let build = match task {
            None => self.build,
            Some(name) if name == self.task_name => self.build,
            Some(name) => match self.variants.iter().find(|v| v.name == name) {
                Some(v) => v.build,
                None => anyhow::bail!("{} has no task '{name}'; its tasks: {}", self.name, self.task_names().join(", ")),
            },
        };
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
        Ok(build(arenas, seed, pattern))
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
