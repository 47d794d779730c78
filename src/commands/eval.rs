//! `twinbots eval <run-dir>`: replays a trained model on its robot and reports episode scores.

use std::path::Path;
use std::sync::Arc;

use twinbots_api::VecEnv;
use twinbots_learn::{EvalResult, RunDir, evaluate_policy};
use twinbots_task::AppVecEnv;

use twinbots_live::LiveServer;
use twinbots_run::live::LiveArgs;
use twinbots_run::registry;
use twinbots_run::robot_log::finish_log;
use twinbots_run::run::evaluation_app;
use twinbots_run::settings::{CalibrationSetting, TrainSettings};
use twinbots_run::twin::Twin;
use twinbots_task::randomization::Randomization;
use twinbots_task::randomization::visual::VisualRandomizationPlugin;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Run directory of `twinbots train`.
    pub run: std::path::PathBuf,
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Parallel arenas; default: the run's.
    #[arg(long)]
    pub arenas: Option<usize>,
    /// Also write the PNG frames of one evaluation episode into this directory.
    #[arg(long)]
    pub record: Option<std::path::PathBuf>,
    #[arg(long, default_value = "640x480")]
    pub size: String,
    #[arg(long, default_value = "side")]
    pub camera: String,
    /// Evaluate on another task of the robot's cell (see `twinbots robots`), e.g. the
    /// UR5e's pick-place with its reach model; default: the task it was trained on.
    #[arg(long)]
    pub task: Option<String>,
    /// Also write one deterministic episode of arena 0 as a robot log (`.mcap` or `.csv`, see
    /// docs/logs.md): what its controller measured and commanded, every control step.
    #[arg(long)]
    pub log: Option<std::path::PathBuf>,
    /// Evaluate on the twin calibrated by this file instead of the run's own (e.g. a truth
    /// file: how a policy does on the robot a log came from).
    #[arg(long)]
    pub calibration: Option<std::path::PathBuf>,
    /// Evaluate under visual randomization: every episode of every arena a look drawn from the
    /// `[randomization.visual]` table of this TOML file (looks the run never saw: textures and
    /// lights held out from training, docs/pixels.md). Written to `eval-<task>-in-<file stem>.json`.
    #[arg(long)]
    pub looks: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub live: LiveArgs,
}

/// `twinbots eval`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let live = args.live.start()?;
    let on = Evaluated {
        task: args.task.as_deref(),
        calibration: args.calibration.as_deref(),
        looks: args.looks.as_deref(),
        live: live.as_ref(),
    };
    eval_run(&args.run, args.episodes, args.arenas, on)?;
    if let Some(path) = &args.log {
        log_episode(&args.run, path, args.task.as_deref(), args.calibration.as_deref())?;
    }
    if let Some(dir) = &args.record {
        record_episode(
            &args.run,
            dir,
            twinbots_render::recorder::parse_size(&args.size)?,
            &args.camera,
            args.task.as_deref(),
        )?;
    }
    Ok(())
}

/// What a run is evaluated on besides its own: another task of its cell, another twin (a
/// calibration file), looks drawn from a file's `[randomization.visual]`; and who watches.
#[derive(Clone, Copy, Default)]
pub struct Evaluated<'a> {
    pub task: Option<&'a str>,
    pub calibration: Option<&'a Path>,
    pub looks: Option<&'a Path>,
    /// The live view every arena is published to.
    pub live: Option<&'a Arc<LiveServer>>,
}

/// Loads the run's final model (or its newest checkpoint), evaluates it on the run's task or
/// on another `task` of the robot's cell, prints the figures and writes `eval.json` (or
/// `eval-<task>.json`, `eval-<task>-on-<twin>.json`, `eval-<task>-in-<looks>.json`) into the
/// run directory.
pub fn eval_run(run: &Path, episodes: usize, arenas: Option<usize>, on: Evaluated) -> anyhow::Result<EvalResult> {
    let Evaluated { task, calibration, looks, live } = on;
    anyhow::ensure!(episodes > 0, "--episodes must be at least 1");
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let entry = registry::find(&settings.robot)?;
    let model = twinbots_learn::algos::load_run(&run_dir)?;
    let own = settings.task_name(&entry)?;
    let name = task.unwrap_or(own);
    let seed = settings.final_eval_seed();
    let arenas = arenas.unwrap_or(settings.arenas);
    let other_twin = calibration.map(|p| p.file_stem().unwrap_or_default().to_string_lossy().to_string());
    let calibration = evaluated_calibration(&entry, &settings, calibration)?;
    let params = calibration.as_ref().map(CalibrationSetting::parameters).unwrap_or_default();
    let mut app = evaluation_app(&entry, Some(name), arenas.clamp(1, episodes), seed, &settings, &params)?;
    if let Some(file) = looks {
        app.add_plugins(VisualRandomizationPlugin(
            Randomization::looks_of(file).map_err(|e| anyhow::anyhow!("--looks {e}"))?,
        ));
    }
    if let Some(server) = live {
        app.add_plugins(twinbots_live::LivePlugin(server.clone()));
    }
    let mut env = AppVecEnv::new(app);
    let result = evaluate_policy(name, model.as_ref(), &mut env, episodes, seed)?;
    println!("{}: {}", settings.robot, result.describe());
    let stem = |p: &Path| p.file_stem().unwrap_or_default().to_string_lossy().to_string();
    // On another twin or under other looks than the run's: beside its own evaluation, not over
    // it, named after both where both are given.
    let on_twin = other_twin.map(|twin| format!("-on-{twin}")).unwrap_or_default();
    let in_looks = looks.map(|l| format!("-in-{}", stem(l))).unwrap_or_default();
    let file = match (name == own, on_twin.is_empty() && in_looks.is_empty()) {
        (true, true) => twinbots_learn::run_dir::EVAL.to_string(),
        _ => format!("eval-{name}{on_twin}{in_looks}.json"),
    };
    run_dir.write_json(&file, &result)?;
    Ok(result)
}

/// The calibration a run is evaluated with: the file's if given, else the run's own.
fn evaluated_calibration(
    entry: &registry::RobotEntry,
    settings: &TrainSettings,
    file: Option<&Path>,
) -> anyhow::Result<Option<CalibrationSetting>> {
    Ok(CalibrationSetting::read_optional(entry, file)?.or_else(|| settings.calibration.clone()))
}

/// Runs one deterministic evaluation episode of the run's model on one arena of its robot's
/// `task`, on the twin of `calibration` (a file; default: the run's own), logged to `log` if
/// given (`robot_log`). `visit` sees the env after the reset (step 0) and after every step but the one
/// that ends the episode (the arena has auto-reset by then: the episode's last state is gone).
fn one_episode(
    run: &Path,
    task: Option<&str>,
    calibration: Option<&Path>,
    log: Option<&Path>,
    mut visit: impl FnMut(&mut AppVecEnv, &TrainSettings, u64) -> anyhow::Result<()>,
) -> anyhow::Result<AppVecEnv> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    let entry = registry::find(&settings.robot)?;
    let model = twinbots_learn::algos::load_run(&run_dir)?;
    let seed = settings.final_eval_seed();
    let twin =
        Twin { calibration: evaluated_calibration(&entry, &settings, calibration)?, log: log.map(Path::to_path_buf) };
    let mut app = entry.app(task.or(settings.task.as_deref()), 1, seed, settings.in_process_pattern()?)?;
    twin.configure(&mut app, &entry)?;
    settings.observe(&mut app, &entry, 1)?;
    let mut env = AppVecEnv::new(app);
    model.check_spaces(env.observation_space(), env.action_space())?;
    let mut obs = env.reset(Some(seed))?;
    visit(&mut env, &settings, 0)?;
    for step in 1.. {
        let out = env.step(&model.predict_deterministic(&obs)?)?;
        obs = out.obs;
        if out.episodes[0].is_some() {
            break;
        }
        visit(&mut env, &settings, step)?;
    }
    Ok(env)
}

/// Writes one deterministic evaluation episode of the run's model as a robot log.
pub fn log_episode(run: &Path, path: &Path, task: Option<&str>, calibration: Option<&Path>) -> anyhow::Result<()> {
    let mut env = one_episode(run, task, calibration, Some(path), |_, _, _| Ok(()))?;
    let (states, commands) = finish_log(env.app_mut().world_mut())?.expect("the episode ended, so it was written");
    println!("logged {states} states and {commands} commands of one episode to {}", path.display());
    Ok(())
}

/// Writes the frames of one deterministic evaluation episode of the run's model (on the run's
/// own twin, as `eval` evaluates it).
pub fn record_episode(
    run: &Path,
    dir: &Path,
    size: (u32, u32),
    camera: &str,
    task: Option<&str>,
) -> anyhow::Result<()> {
    let mut recorder: Option<twinbots_render::recorder::Recorder> = None;
    one_episode(run, task, None, None, |env, settings, step| {
        if recorder.is_none() {
            let entry = registry::find(&settings.robot)?;
            recorder = Some(twinbots_render::recorder::Recorder::new(
                size,
                twinbots_render::recorder::camera(&entry.framing, camera)?,
                dir,
            )?);
        }
        recorder.as_mut().expect("made above").frame(env, step).map(|_| ())
    })?;
    let written = recorder.map_or(0, |r| r.written);
    println!("recorded {written} frames of one episode to {}", dir.display());
    Ok(())
}
