//! `twinbots train <robot>`: PPO on N arenas, headless, into a run directory.
//!
//! As DESIGN.md's data flow: the learner runs on its own thread and steps the app through the
//! crossbeam bridge; the Bevy app runs on the main thread. The run directory holds `config.toml`
//! (the resolved settings), `progress.csv` (one row per update), `evaluations.csv`,
//! `checkpoints/` (atomic, every `checkpoint_every` updates), `learning_curve.png`, `model/` (the
//! final model) and `summary.json`. Training stops at `timesteps` or when the task's solved
//! criterion holds; `--resume` continues from the last checkpoint with its counters.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use twinbots_rl::plot::{CurvePoint, EvaluationPoint};
use twinbots_rl::randomization::{Randomization, RandomizationPlugin};
use twinbots_rl::{DesignPattern, Flow, Ppo, PpoConfig, UpdateStats, bridge, env};

use crate::cli::eval;
use crate::cli::run_log::{self, RunLog};
use crate::registry::{self, RobotEntry};

/// Everything a run is made of; written to `config.toml`, read by `--config` and `--resume`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainSettings {
    pub robot: String,
    pub timesteps: u64,
    pub arenas: usize,
    pub seed: u64,
    /// Design pattern (paper §3): 1 supervised, 2 supervisor + slave over radio, 3 RobotServer.
    pub pattern: u8,
    /// Save a checkpoint (and redraw the learning curve) every this many updates.
    pub checkpoint_every: usize,
    /// Evaluate the deterministic policy every this many updates into `evaluations.csv`
    /// (0: never); an evaluation of at least the solved criterion's window of episodes that
    /// meets it ends training (SB3's EvalCallback with a stop threshold). The final model is
    /// always evaluated into `eval.json`.
    pub eval_every: usize,
    pub eval_episodes: usize,
    pub ppo: PpoConfig,
    /// Domain randomization (patterns 1 and 2): see `twinbots_rl::randomization`.
    #[serde(default)]
    pub randomization: Randomization,
}

/// What a `--config` file may set: any subset of the settings but the robot.
#[derive(Clone, Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConfigFile {
    pub timesteps: Option<u64>,
    pub arenas: Option<usize>,
    pub seed: Option<u64>,
    pub pattern: Option<u8>,
    pub checkpoint_every: Option<usize>,
    pub eval_every: Option<usize>,
    pub eval_episodes: Option<usize>,
    pub ppo: Option<PpoConfig>,
    pub randomization: Option<Randomization>,
}

impl ConfigFile {
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| anyhow::anyhow!("{}: cannot read config: {e}", path.display()))?;
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }
}

impl TrainSettings {
    /// The settings a run directory was made with (its `config.toml`).
    pub fn read(run: &Path) -> anyhow::Result<Self> {
        let config = run.join("config.toml");
        let text = std::fs::read_to_string(&config)
            .map_err(|e| anyhow::anyhow!("{}: not a run directory: {e}", config.display()))?;
        toml::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", config.display()))
    }

    pub fn design_pattern(&self) -> anyhow::Result<DesignPattern> {
        DesignPattern::from_number(self.pattern)
            .ok_or_else(|| anyhow::anyhow!("pattern must be 1, 2 or 3, got {}", self.pattern))
    }

    /// The robot's defaults, then the config file, then command-line flags.
    pub fn resolve(entry: &RobotEntry, file: ConfigFile, flags: ConfigFile) -> Self {
        let mut s = Self {
            robot: entry.name.to_string(),
            timesteps: entry.defaults.timesteps,
            arenas: entry.defaults.arenas,
            seed: 0,
            pattern: 1,
            checkpoint_every: 10,
            eval_every: entry.defaults.eval_every,
            eval_episodes: entry.defaults.eval_episodes,
            ppo: entry.defaults.ppo.clone(),
            randomization: Randomization::default(),
        };
        for layer in [file, flags] {
            s.timesteps = layer.timesteps.unwrap_or(s.timesteps);
            s.arenas = layer.arenas.unwrap_or(s.arenas);
            s.seed = layer.seed.unwrap_or(s.seed);
            s.pattern = layer.pattern.unwrap_or(s.pattern);
            s.checkpoint_every = layer.checkpoint_every.unwrap_or(s.checkpoint_every);
            s.eval_every = layer.eval_every.unwrap_or(s.eval_every);
            s.eval_episodes = layer.eval_episodes.unwrap_or(s.eval_episodes);
            s.ppo = layer.ppo.unwrap_or(s.ppo);
            s.randomization = layer.randomization.unwrap_or(s.randomization);
        }
        s
    }
}

/// Default run directory: `runs/<robot>-<unix seconds>`.
pub fn default_run_dir(robot: &str) -> PathBuf {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    PathBuf::from("runs").join(format!("{robot}-{secs}"))
}

/// The newest checkpoint of a run, if any.
pub fn latest_checkpoint(run: &Path) -> Option<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(run.join("checkpoints"))
        .ok()?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("model.json").is_file() && p.join("model.safetensors").is_file())
        .collect();
    dirs.sort();
    dirs.pop()
}

/// A trained model from a run directory: its final model, else its newest checkpoint.
pub fn load_model(run: &Path) -> anyhow::Result<Ppo> {
    let dir = if run.join("model").join("model.json").is_file() {
        run.join("model")
    } else {
        latest_checkpoint(run).ok_or_else(|| anyhow::anyhow!("{}: no model or checkpoint", run.display()))?
    };
    Ok(Ppo::load(dir)?)
}

/// Pattern 3: starts `twinbots serve` as its own process and runs the robots here.
fn train_through_server(settings: TrainSettings, out: &Path) -> anyhow::Result<()> {
    use std::io::BufRead;
    let exe = std::env::current_exe()?;
    let config = toml::to_string_pretty(&settings)?;
    std::fs::create_dir_all(out)?;
    let config_path = out.with_extension("server.toml");
    std::fs::write(&config_path, config)?;
    let mut server = std::process::Command::new(exe)
        .args(["serve", &settings.robot, "--listen", "127.0.0.1:0", "--settings"])
        .arg(&config_path)
        .arg("--out")
        .arg(out)
        .stdout(std::process::Stdio::piped())
        .spawn()?;
    let stdout = server.stdout.take().ok_or_else(|| anyhow::anyhow!("no server output"))?;
    let mut lines = std::io::BufReader::new(stdout).lines();
    let first = lines.next().transpose()?.unwrap_or_default();
    let addr: std::net::SocketAddr = first
        .strip_prefix("listening on ")
        .and_then(|a| a.parse().ok())
        .ok_or_else(|| anyhow::anyhow!("the server did not start: {first:?}"))?;
    println!("RobotServer (pid {}) listening on {addr}", server.id());
    let result = crate::cli::serve::robots(&settings.robot, addr, settings.arenas, settings.seed, std::time::Duration::from_secs(10));
    for line in lines.map_while(Result::ok) {
        println!("server: {line}");
    }
    let status = server.wait()?;
    let _ = std::fs::remove_file(&config_path);
    result?;
    anyhow::ensure!(status.success(), "the server exited with {status}");
    Ok(())
}

/// A fresh run into `out`.
pub fn train(settings: TrainSettings, out: &Path, view: bool) -> anyhow::Result<()> {
    if settings.design_pattern()? == DesignPattern::Server {
        return train_through_server(settings, out);
    }
    anyhow::ensure!(settings.arenas > 0, "arenas must be at least 1");
    anyhow::ensure!(
        !out.join("progress.csv").exists(),
        "{} already holds a run (use --resume to continue it, or another --out)",
        out.display()
    );
    std::fs::create_dir_all(out.join("checkpoints"))?;
    std::fs::write(out.join("config.toml"), toml::to_string_pretty(&settings)?)?;
    run(settings, out, None, Vec::new(), view)
}

/// Continues the run in `run_dir` from its newest checkpoint.
pub fn resume(run_dir: &Path, view: bool) -> anyhow::Result<()> {
    let settings = TrainSettings::read(run_dir)?;
    let checkpoint = latest_checkpoint(run_dir)
        .ok_or_else(|| anyhow::anyhow!("{}: no checkpoint to resume from", run_dir.display()))?;
    let model = Ppo::load(&checkpoint)?;
    // Keep the progress rows up to the checkpoint; later ones are redone.
    let csv_path = run_dir.join("progress.csv");
    let csv = std::fs::read_to_string(&csv_path).unwrap_or_default();
    let mut kept = vec![run_log::CSV_HEADER.to_string()];
    let mut curve = Vec::new();
    for line in csv.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let Some(t) = f.get(1).and_then(|t| t.parse::<u64>().ok()) else { continue };
        if t > model.timesteps {
            break;
        }
        let num = |i: usize| f.get(i).and_then(|x| x.parse::<f32>().ok()).unwrap_or(f32::NAN);
        curve.push(CurvePoint { timesteps: t, mean_reward: num(3), min_reward: num(4), max_reward: num(5), success_rate: num(14) });
        kept.push(line.to_string());
    }
    twinbots_rl::ppo::write_atomic(&csv_path, (kept.join("\n") + "\n").as_bytes())?;
    println!("resuming {} from {} ({} steps, {} episodes)", run_dir.display(), checkpoint.display(), model.timesteps, model.episodes);
    run(settings, run_dir, Some(model), curve, view)
}

fn run(settings: TrainSettings, out: &Path, model: Option<Ppo>, curve: Vec<CurvePoint>, view: bool) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let pattern = settings.design_pattern()?;
    anyhow::ensure!(
        pattern != DesignPattern::Server,
        "design pattern 3 has no in-process env: use `twinbots serve` and `twinbots robot`"
    );
    let mut app = entry.app(None, settings.arenas, settings.seed, pattern)?;
    app.add_plugins(bridge::BridgePlugin);
    settings.randomization.validate()?;
    if !settings.randomization.is_off() {
        app.add_plugins(RandomizationPlugin(settings.randomization.clone()));
    }
    let (_, spec) = env::start(&mut app)?;
    let mut channel_env = bridge::connect(app.world_mut())?;
    let model = match model {
        Some(m) => {
            m.check_spaces(&spec.observation_space, &spec.action_space)?;
            m
        }
        None => Ppo::new(settings.ppo.clone(), spec.observation_space.clone(), spec.action_space.clone(), settings.seed)?,
    };
    let run_dir = out.to_path_buf();
    let robot = settings.robot.clone();
    let settings_title = settings.robot.clone();
    let (settings_arenas, eval_episodes, seed) = (settings.arenas, settings.eval_episodes, settings.seed);
    let solved = spec.solved;
    let task_name = entry.main_task().name;
    let make_app = {
        let entry = entry.clone();
        std::sync::Arc::new(move |arenas: usize, seed: u64| entry.app(None, arenas, seed, pattern))
    };
    let learner_app = make_app.clone();

    // The learner's thread: PPO, logging, checkpoints, evaluation.
    let trainer = std::thread::spawn(move || -> anyhow::Result<(Ppo, Option<(u64, &'static str)>, f64)> {
        let make_app = learner_app;
        let mut model = model;
        let eval_path = run_dir.join("evaluations.csv");
        if !eval_path.exists() {
            std::fs::write(&eval_path, "timesteps,mean_score,std_score,mean_length,success_rate\n")?;
        }
        let mut evals = std::fs::OpenOptions::new().append(true).open(&eval_path)?;
        let title = format!("{} — PPO, pattern {}, {} arenas, seed {}", settings.robot, settings.pattern, settings.arenas, settings.seed);
        let mut log = RunLog::open(&run_dir, title, solved, settings.checkpoint_every, settings.timesteps, model.timesteps, curve)?;
        let started = Instant::now();
        let mut solved_at = None;
        let mut callback = |s: &UpdateStats, m: &Ppo| -> anyhow::Result<Flow> {
            log.on_update(s, m)?;
            let mut evaluation = None;
            if settings.eval_every > 0 && s.update % settings.eval_every == 0 {
                let r = eval::evaluate(task_name, &*make_app, m, settings.arenas, settings.eval_episodes, settings.seed + 1_000_003)?;
                let success = r.success_rate.map_or(String::new(), |x| x.to_string());
                writeln!(evals, "{},{},{},{},{success}", s.timesteps, r.mean_score, r.std_score, r.mean_length)?;
                log.evaluations.push(EvaluationPoint {
                    timesteps: s.timesteps,
                    mean_score: r.mean_score,
                    success_rate: r.success_rate.unwrap_or(f32::NAN),
                });
                evaluation = Some(r);
            }
            if let Some(c) = solved {
                let by_training = m.is_solved(&c).then_some("training episodes");
                let by_evaluation = evaluation.as_ref().filter(|r| r.meets(&c)).map(|_| "evaluation");
                if let Some(by) = by_training.or(by_evaluation) {
                    solved_at = Some((s.timesteps, by));
                    return Ok(Flow::Stop);
                }
            }
            Ok(Flow::Continue)
        };
        let remaining = settings.timesteps.saturating_sub(model.timesteps);
        model.learn(&mut channel_env, remaining, &mut callback)?;
        log.finish()?;
        Ok((model, solved_at, started.elapsed().as_secs_f64()))
    });

    // The app's thread (this one): frames until the learner hangs up.
    let sim = if view {
        // The window drives the app in time slices; closing the window stops training.
        let arena = app.world().resource::<env::ArenaOrder>().0[0];
        let source = crate::cli::view::TrainingView { app, arena, frames: 0, updates: 0, started: Instant::now(), last_slice_end: None };
        let shown = twinbots_render::viewer::run(Box::new(source), &format!("twinbots — training {}", settings_title), entry.framing);
        Ok(shown)
    } else {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| bridge::run_until_closed(&mut app)));
        drop(app); // closes the bridge, so a learner still waiting gets an error rather than a hang
        r.map(Ok)
    };
    let learned = trainer
        .join()
        .map_err(|p| anyhow::anyhow!("the trainer thread panicked: {}", panic_message(&p)))?;
    match sim {
        Err(p) => anyhow::bail!("the simulation panicked: {}", panic_message(&p)),
        Ok(Err(e)) => return Err(e),
        Ok(Ok(())) => {}
    }
    let (model, solved_at, wall) = learned?;
    model.save(out.join("model"))?;
    let evaluation = eval::evaluate(task_name, &*make_app, &model, settings_arenas, eval_episodes, seed + 2_000_003)?;
    std::fs::write(out.join("eval.json"), serde_json::to_string_pretty(&evaluation)?)?;
    let summary = serde_json::json!({
        "robot": robot,
        "timesteps": model.timesteps,
        "episodes": model.episodes,
        "wall_clock_s_this_session": wall,
        "mean_reward_last_100": model.mean_recent_score(),
        "solved": solved_at.is_some(),
        "solved_at_timesteps": solved_at.map(|(t, _)| t),
        "solved_by": solved_at.map(|(_, by)| by),
        "success_rate_last_100": model.recent_success_rate(),
        "evaluation": { "episodes": evaluation.episodes, "mean_score": evaluation.mean_score, "std_score": evaluation.std_score, "success_rate": evaluation.success_rate },
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)?)?;
    match solved_at {
        Some((t, by)) => println!("solved ({by}) after {t} steps in {wall:.1} s (mean of last 100 episodes {:.1})", model.mean_recent_score()),
        None => println!("not solved: {} steps in {wall:.1} s, mean of last 100 episodes {:.1}", model.timesteps, model.mean_recent_score()),
    }
    println!("evaluation of the final model, {}", evaluation.describe());
    println!("run directory: {}", out.display());
    Ok(())
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
