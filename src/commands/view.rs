//! `twinbots view <robot>`: the visual mode, playing arena 0 in real time with a trained model
//! or zero actions, in a window and/or the live view (`--live`; `--no-window` for a machine
//! without a screen). `train --view` shows arena 0 of a training run (see `TrainingView`).

use std::time::Duration;

use bevy::prelude::*;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::RunDir;
use twinbots_render::viewer::{self, RealTime, ViewSource};
use twinbots_task::AppVecEnv;

use twinbots_run::live::LiveArgs;
use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    pub robot: String,
    /// Drive the robot with this run's trained model (default: zero actions).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The task to run (see `twinbots robots`); default: the robot's own.
    #[arg(long)]
    pub task: Option<String>,
    /// Show the twin calibrated by this file (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub live: LiveArgs,
    /// Play without a window (with --live: a headless machine's view), until Ctrl-C or
    /// --seconds.
    #[arg(long, requires = "live")]
    pub no_window: bool,
    /// Without a window: stop after this many seconds.
    #[arg(long, requires = "no_window")]
    pub seconds: Option<f64>,
}

/// `twinbots view`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    if let Some(s) = args.seconds {
        anyhow::ensure!(s > 0.0 && s.is_finite(), "--seconds must be positive, not {s}");
    }
    let live = args.live.start()?;
    let (entry, mut app) = view_app(&args)?;
    if let Some(server) = live {
        app.add_plugins(twinbots_live::LivePlugin(server));
    }
    let player = Player::new(app, &args)?;
    if args.no_window {
        return play(player, args.seconds);
    }
    viewer::run(Box::new(player), &format!("twinbots — {}", args.robot), entry.framing)
}

/// Plays one arena in real time.
struct Player {
    env: AppVecEnv,
    model: Option<Box<dyn twinbots_learn::Learner>>,
    obs: Vec<f32>,
    clock: RealTime,
    steps: u64,
    episodes: u64,
    score: f32,
    seed: u64,
}

impl ViewSource for Player {
    fn advance(&mut self, _budget: Duration, paused: bool, single_step: bool) -> bool {
        let n = if paused && single_step { 1 } else { self.clock.steps_due(paused, 8) };
        for _ in 0..n {
            let action = match &self.model {
                Some(m) => m.predict_deterministic(&self.obs).unwrap_or_default(),
                None => vec![0.0; self.env.action_space().dim()],
            };
            let Ok(out) = self.env.step(&action) else { return false };
            self.obs = out.obs;
            self.steps += 1;
            self.score += out.rewards[0];
            if out.episodes[0].is_some() {
                self.episodes += 1;
                self.score = 0.0;
            }
        }
        true
    }
    fn reset(&mut self) {
        self.seed += 1;
        if let Ok(obs) = self.env.reset(Some(self.seed)) {
            self.obs = obs;
            self.score = 0.0;
        }
    }
    fn sim_world(&mut self) -> &mut World {
        self.env.app_mut().world_mut()
    }
    fn arena(&self) -> Entity {
        self.env.arenas()[0]
    }
    fn status(&self) -> String {
        format!("step {} — episode {} — score {:.0}", self.steps, self.episodes + 1, self.score)
    }
}

/// The robot and its app for arena 0, with the run's observation and the file's twin, checked
/// before any window opens (as `capture`).
fn view_app(args: &Args) -> anyhow::Result<(registry::RobotEntry, App)> {
    let entry = registry::find(&args.robot)?;
    let model = args.model.as_deref();
    let task = twinbots_run::settings::TrainSettings::task_for(args.task.as_deref(), model)?;
    let mut app = entry.app(task.as_deref(), 1, args.seed, DesignPattern::Supervised)?;
    twinbots_run::twin::Twin::of_files(&entry, args.calibration.as_deref(), None)?.configure(&mut app, &entry)?;
    if let Some(run) = model {
        twinbots_run::settings::TrainSettings::observe_as_run(run, &mut app, &entry, 1)?;
    }
    Ok((entry, app))
}

impl Player {
    fn new(app: App, args: &Args) -> anyhow::Result<Self> {
        let model = args.model.as_deref().map(|run| twinbots_learn::algos::load_run(&RunDir::new(run))).transpose()?;
        let mut env = AppVecEnv::new(app);
        if let Some(m) = &model {
            m.check_spaces(env.observation_space(), env.action_space())?;
        }
        let obs = env.reset(Some(args.seed))?;
        let dt = env.app().world().resource::<twinbots_sim::SimSettings>().control_dt();
        Ok(Player { env, model, obs, clock: RealTime::new(dt), steps: 0, episodes: 0, score: 0.0, seed: args.seed })
    }
}

/// Plays in real time without a window, a line a second, until Ctrl-C, SIGTERM or `seconds`.
fn play(mut player: Player, seconds: Option<f64>) -> anyhow::Result<()> {
    twinbots_ops::stop_signal::install();
    let started = std::time::Instant::now();
    let mut next_line = 1.0;
    loop {
        if let Some(signal) = twinbots_ops::stop_signal::requested() {
            println!("view: stopped by {signal}");
            return Ok(());
        }
        let elapsed = started.elapsed().as_secs_f64();
        if seconds.is_some_and(|s| elapsed >= s) {
            return Ok(());
        }
        anyhow::ensure!(player.advance(Duration::ZERO, false, false), "the twin stopped: {}", player.status());
        if elapsed >= next_line {
            next_line += 1.0;
            println!("view: {}", player.status());
        }
        std::thread::sleep(Duration::from_millis(1));
    }
}
