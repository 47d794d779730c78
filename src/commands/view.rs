//! `twinbots view <robot>`: the visual mode, playing arena 0 in real time with a trained model
//! or zero actions. `train --view` shows arena 0 of a training run (see `TrainingView`).

use std::time::Duration;

use bevy::prelude::*;
use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::RunDir;
use twinbots_render::viewer::{self, RealTime, ViewSource};
use twinbots_task::AppVecEnv;

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
}

/// `twinbots view`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    view(&args.robot, args.model.as_deref(), args.seed, args.task.as_deref(), args.calibration.as_deref())
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

pub fn view(
    robot: &str,
    model: Option<&std::path::Path>,
    seed: u64,
    task: Option<&str>,
    calibration: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    let entry = registry::find(robot)?;
    let loaded = model.map(|run| twinbots_learn::algos::load_run(&RunDir::new(run))).transpose()?;
    let task = twinbots_run::settings::TrainSettings::task_for(task, model)?;
    let mut app = entry.app(task.as_deref(), 1, seed, DesignPattern::Supervised)?;
    // As `capture`: the file's twin, read and checked before any window opens.
    twinbots_run::twin::Twin::of_files(&entry, calibration, None)?.configure(&mut app, &entry)?;
    if let Some(run) = model {
        twinbots_run::settings::TrainSettings::observe_as_run(run, &mut app, &entry, 1)?;
    }
    let model = loaded;
    let mut env = AppVecEnv::new(app);
    if let Some(m) = &model {
        m.check_spaces(env.observation_space(), env.action_space())?;
    }
    let obs = env.reset(Some(seed))?;
    let dt = env.app().world().resource::<twinbots_sim::SimSettings>().control_dt();
    let player = Player { env, model, obs, clock: RealTime::new(dt), steps: 0, episodes: 0, score: 0.0, seed };
    viewer::run(Box::new(player), &format!("twinbots — {robot}"), entry.framing)
}
