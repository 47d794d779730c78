//! `twinbots capture <robot>`: PNG frames of the digital twin, rendered off-screen, driven by a
//! trained model or zero actions. `eval --record` uses the same recorder. Frame `i` is written
//! right after physics step `i` (frame 0: the start), so it shows that step.

use anyhow::Context;
use std::path::PathBuf;

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::RunDir;
use twinbots_render::recorder::{Recorder, camera, parse_size};
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::{Randomization, RandomizationPlugin};

use twinbots_run::registry;
use twinbots_run::settings::{CalibrationSetting, TrainSettings};

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    pub robot: String,
    /// Drive the robot with this run's trained model (default: zero actions).
    #[arg(long)]
    pub model: Option<std::path::PathBuf>,
    #[arg(long, default_value_t = 50)]
    pub frames: usize,
    /// Physics control steps between frames.
    #[arg(long, default_value_t = 1)]
    pub every: usize,
    #[arg(long, default_value = "640x480")]
    pub size: String,
    /// Camera: side, front, iso or top.
    #[arg(long, default_value = "side")]
    pub camera: String,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// The task to run (see `twinbots robots`); default: the robot's own.
    #[arg(long)]
    pub task: Option<String>,
    #[arg(long)]
    pub out: std::path::PathBuf,
    /// Render the twin calibrated by this file (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<std::path::PathBuf>,
    /// Lights cast shadows (each light renders a shadow map: slower on a CPU renderer).
    #[arg(long)]
    pub shadows: bool,
    /// Domain randomization from this run configuration's `[randomization]` table (with
    /// `[randomization.visual]`: each episode's look, recorded in looks.jsonl beside the frames).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Also write arena 0's latest episode (the running one at the last frame) as a robot log
    /// (.mcap or .csv).
    #[arg(long)]
    pub log: Option<std::path::PathBuf>,
}

/// `twinbots capture`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let Args { robot, model, frames, every, size, camera, seed, task, out, calibration, shadows, config, log } = args;
    let randomization = match config {
        Some(path) => {
            let text = std::fs::read_to_string(&path).with_context(|| format!("--config {}", path.display()))?;
            Randomization::from_config(&text).with_context(|| format!("--config {}", path.display()))?
        }
        None => Randomization::default(),
    };
    capture(CaptureArgs {
        robot,
        model,
        frames,
        every,
        size: parse_size(&size)?,
        camera,
        seed,
        task,
        out,
        calibration,
        randomization,
        shadows,
        log,
    })
}

pub struct CaptureArgs {
    pub robot: String,
    pub model: Option<PathBuf>,
    pub frames: usize,
    pub every: usize,
    pub size: (u32, u32),
    pub camera: String,
    pub seed: u64,
    pub task: Option<String>,
    pub out: PathBuf,
    pub calibration: Option<PathBuf>,
    pub randomization: Randomization,
    pub shadows: bool,
    pub log: Option<PathBuf>,
}

pub fn capture(args: CaptureArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.every > 0, "--every must be at least 1");
    let entry = registry::find(&args.robot)?;
    let view = camera(&entry.framing, &args.camera)?;
    let model = args.model.as_deref().map(|run| twinbots_learn::algos::load_run(&RunDir::new(run))).transpose()?;
    let task = TrainSettings::task_for(args.task.as_deref(), args.model.as_deref())?;
    let mut app = entry.app(task.as_deref(), 1, args.seed, DesignPattern::Supervised)?;
    let twin = twinbots_run::twin::Twin::of_files(&entry, args.calibration.as_deref(), args.log.as_deref())?;
    CalibrationSetting::check_randomization(twin.calibration.as_ref(), &args.randomization)?;
    twin.configure(&mut app, &entry)?;
    if let Some(run) = &args.model {
        TrainSettings::observe_as_run(run, &mut app, &entry, 1)?;
    }
    if !args.randomization.is_off() {
        app.add_plugins(RandomizationPlugin(args.randomization.clone()));
    }
    let mut env = AppVecEnv::new(app);
    if let Some(m) = &model {
        m.check_spaces(env.observation_space(), env.action_space())?;
    }
    let mut recorder = Recorder::new(args.size, view, &args.out)?.with_shadows(args.shadows);
    let mut obs = env.reset(Some(args.seed))?;
    recorder.frame(&mut env, 0)?;
    let zero = vec![0.0; env.action_space().dim()];
    for step in 1..=(args.frames * args.every) as u64 {
        let action = match &model {
            Some(m) => m.predict_deterministic(&obs)?,
            None => zero.clone(),
        };
        obs = env.step(&action)?.obs;
        if step % args.every as u64 == 0 {
            recorder.frame(&mut env, step)?;
        }
    }
    println!("wrote {} frames ({}x{}) to {}", recorder.written, args.size.0, args.size.1, args.out.display());
    if let (Some(path), Some((states, commands))) =
        (&args.log, twinbots_run::robot_log::finish_log(env.app_mut().world_mut())?)
    {
        println!("logged the latest episode ({states} states, {commands} commands) to {}", path.display());
    }
    Ok(())
}
