//! `twinbots capture <robot>`: PNG frames of the digital twin, rendered off-screen, driven by a
//! trained model or zero actions. `eval --record` uses the same recorder. Frame `i` is written
//! right after physics step `i` (frame 0: the start), so it shows that step.

use anyhow::Context;
use std::io::Write;
use std::path::{Path, PathBuf};

use twinbots_api::{DesignPattern, VecEnv};
use twinbots_learn::RunDir;
use twinbots_render::{Framing, Renderer, View};
use twinbots_sim::Look;
use twinbots_task::AppVecEnv;
use twinbots_task::randomization::{Randomization, RandomizationPlugin};

use crate::registry::{self, RobotEntry};
use twinbots::settings::{CalibrationSetting, TrainSettings};

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

/// A named camera of a robot's cell.
pub fn camera(entry: &RobotEntry, name: &str) -> anyhow::Result<View> {
    View::framed(&entry.framing, name)
        .ok_or_else(|| anyhow::anyhow!("unknown camera '{name}'; cameras: {}", Framing::CAMERAS.join(", ")))
}

/// `WxH` → (W, H).
pub fn parse_size(size: &str) -> anyhow::Result<(u32, u32)> {
    let (w, h) = size.split_once('x').ok_or_else(|| anyhow::anyhow!("--size must look like 640x480, got '{size}'"))?;
    let w: u32 = w.parse().map_err(|_| anyhow::anyhow!("--size: bad width '{w}'"))?;
    let h: u32 = h.parse().map_err(|_| anyhow::anyhow!("--size: bad height '{h}'"))?;
    anyhow::ensure!(w > 0 && h > 0 && w <= 4096 && h <= 4096, "--size must be between 1x1 and 4096x4096");
    Ok((w, h))
}

pub struct Recorder {
    renderer: Renderer,
    out: PathBuf,
    pub written: usize,
    /// The look of the latest frame, when the arena has one (visual randomization).
    look: Option<Look>,
}

impl Recorder {
    pub fn new(size: (u32, u32), view: View, out: &Path) -> anyhow::Result<Self> {
        std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
        let mut renderer = Renderer::new(size.0, size.1)?;
        renderer.set_view(view);
        Ok(Self { renderer, out: out.to_path_buf(), written: 0, look: None })
    }

    /// Lights cast shadows (before the first frame).
    pub fn with_shadows(mut self, shadows: bool) -> Self {
        self.renderer = self.renderer.with_shadows(shadows);
        self
    }

    /// Renders arena 0 of `env` as it is now into `frame_<step>.png`. A new look of the arena
    /// (visual randomization) is appended to `looks.jsonl` first: `{"frame": step, "look": …}`,
    /// in force from that frame on.
    pub fn frame(&mut self, env: &mut AppVecEnv, step: u64) -> anyhow::Result<PathBuf> {
        let arena = env.arenas()[0];
        let look = env.app().world().get::<Look>(arena);
        if look.is_some() && look != self.look.as_ref() {
            self.look = look.cloned();
            let line = serde_json::json!({ "frame": step, "look": self.look });
            let path = self.out.join("looks.jsonl");
            let mut file = std::fs::OpenOptions::new()
                .create(true)
                .append(true)
                .open(&path)
                .with_context(|| path.display().to_string())?;
            writeln!(file, "{line}").with_context(|| path.display().to_string())?;
        }
        self.renderer.sync(env.app_mut().world_mut(), arena);
        let rgb = self.renderer.render()?;
        let path = self.out.join(format!("frame_{step:05}.png"));
        image::save_buffer(&path, &rgb, self.renderer.width, self.renderer.height, image::ExtendedColorType::Rgb8)
            .with_context(|| path.display().to_string())?;
        self.written += 1;
        Ok(path)
    }
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
    let view = camera(&entry, &args.camera)?;
    let model = args.model.as_deref().map(|run| twinbots_learn::algos::load_run(&RunDir::new(run))).transpose()?;
    let task = TrainSettings::task_for(args.task.as_deref(), args.model.as_deref())?;
    let mut app = entry.app(task.as_deref(), 1, args.seed, DesignPattern::Supervised)?;
    let twin = twinbots::twin::Twin::of_files(&entry, args.calibration.as_deref(), args.log.as_deref())?;
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
        (&args.log, twinbots::robot_log::finish_log(env.app_mut().world_mut())?)
    {
        println!("logged the latest episode ({states} states, {commands} commands) to {}", path.display());
    }
    Ok(())
}
