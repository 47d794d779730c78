//! `twinbots train <robot>`: PPO (or `--algo sac`) on N arenas, headless, into a run directory.
//!
//! As DESIGN.md's data flow: the learner runs on its own thread and steps the app through the
//! crossbeam bridge; the Bevy app runs on the main thread. The run directory
//! (`twinbots_learn::run_dir`) holds `config.toml` (the resolved settings), `progress.csv` (one row
//! per update), `evaluations.csv`, `checkpoints/` (atomic, every `checkpoint_every` updates),
//! `learning_curve.png`, `model/` (the final model), `eval.json` and `summary.json`, written by
//! the run's callbacks (`TrainSettings::callbacks`) and, at the end, here. Training stops at
//! `timesteps` or when the task's solved criterion holds; `--resume` continues from the last
//! checkpoint with its counters.

use anyhow::Context;
use std::path::Path;
use std::time::Instant;

use twinbots_api::DesignPattern;
use twinbots_learn::run_dir::TimeBreakdown;
use twinbots_learn::{RunDir, TrainingEnd};
use twinbots_task::randomization::RandomizationPlugin;
use twinbots_task::{bridge, env};

use crate::cli::learner;
use crate::registry;
use twinbots::settings::{CalibrationSetting, ConfigFile, TrainSettings};
use twinbots_learn::Learner;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Robot to train (see `twinbots robots`); not needed with --resume.
    #[arg(required_unless_present = "resume")]
    pub robot: Option<String>,
    /// The task to learn (`twinbots robots` lists a robot's tasks); default: the robot's main
    /// task. A task with its own spaces trains with its own defaults (the UR5e's
    /// `pick-place-learned`: SAC + HER).
    #[arg(long)]
    pub task: Option<String>,
    /// Env steps (summed over arenas); default: the robot's budget.
    #[arg(long)]
    pub timesteps: Option<u64>,
    /// Parallel arenas; default: the robot's.
    #[arg(long)]
    pub arenas: Option<usize>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Design pattern (paper §3): 1 RLRobot + Supervisor, 2 SupervisorRobot + SlaveRobot over
    /// radio, 3 RobotServer + Communicator.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=3))]
    pub pattern: Option<u8>,
    /// The learner, by name (`twinbots algos` lists them); default: the robot's (ppo).
    #[arg(long, value_parser = learner::parse_algo)]
    pub algo: Option<String>,
    /// A TOML file with settings (timesteps, arenas, seed, checkpoint_every, eval_every,
    /// eval_episodes, algo, [ppo] / [sac] hyperparameters); flags override it.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Run directory; default runs/<robot>-<time>.
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Save a checkpoint every this many updates.
    #[arg(long)]
    pub checkpoint_every: Option<usize>,
    /// Show arena 0 in a window while training (the other arenas train at full speed).
    #[arg(long)]
    pub view: bool,
    /// Train on the twin calibrated by this file (`twinbots identify`'s calibration.toml);
    /// the run's config.toml records its parameters.
    #[arg(long)]
    pub calibration: Option<std::path::PathBuf>,
    /// Train in the cell laid out by this file (docs/cells.md; the UR5e's default is
    /// assets/cells/ur5e.toml); the run's config.toml records it as `[cell]`.
    #[arg(long)]
    pub cell: Option<std::path::PathBuf>,
    /// Continue the run in this directory from its newest checkpoint. With --timesteps N:
    /// train N steps more than its model has (a run that ended continues from its final model;
    /// SB3's `learn(N, reset_num_timesteps=False)`).
    #[arg(long, conflicts_with_all = ["robot", "task", "arenas", "seed", "pattern", "config", "out", "algo", "calibration", "cell"])]
    pub resume: Option<std::path::PathBuf>,
    /// Print the settings the run would use (the robot's defaults ← the config file ← the
    /// flags, key by key) as TOML, and exit without training.
    #[arg(long)]
    pub print_config: bool,
}

/// `twinbots train`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let Args {
        robot,
        task,
        timesteps,
        arenas,
        seed,
        pattern,
        algo,
        config,
        out,
        checkpoint_every,
        view,
        calibration,
        cell,
        resume,
        print_config,
    } = args;
    if let Some(run) = resume {
        if print_config {
            print!("{}", toml::to_string_pretty(&TrainSettings::of_run(&RunDir::new(run))?)?);
            return Ok(());
        }
        return match timesteps {
            Some(more) => extend(&run, more, view),
            None => self::resume(&run, view),
        };
    }
    let robot = robot.unwrap_or_default();
    let entry = registry::find(&robot)?;
    let file = match config {
        Some(path) => ConfigFile::read(&path)?,
        None => Default::default(),
    };
    let calibration = calibration.map(|path| CalibrationSetting::read(&entry, &path)).transpose()?;
    let cell = cell.map(|path| twinbots::settings::read_cell(&entry, &path)).transpose()?;
    let flags = ConfigFile {
        task,
        timesteps,
        arenas,
        seed,
        pattern,
        checkpoint_every,
        algo,
        calibration,
        cell,
        ..Default::default()
    };
    let settings = TrainSettings::resolve(&entry, file, flags)?;
    if print_config {
        print!("{}", toml::to_string_pretty(&settings)?);
        return Ok(());
    }
    let out = out.unwrap_or_else(|| twinbots::run::default_run_dir(&robot));
    train(settings, &out, view)
}

/// Pattern 3: starts `twinbots serve` as its own process and runs the robots here; `resume`:
/// the server continues the run in `out` (`serve --resume`).
fn train_through_server(settings: TrainSettings, out: &Path, resume: bool) -> anyhow::Result<()> {
    use std::io::BufRead;
    let exe = std::env::current_exe()?;
    let mut command = std::process::Command::new(exe);
    let config_path = out.with_extension("server.toml");
    if resume {
        command.arg("serve").arg("--resume").arg(out).args(["--listen", "127.0.0.1:0"]);
    } else {
        std::fs::create_dir_all(out).with_context(|| out.display().to_string())?;
        std::fs::write(&config_path, toml::to_string_pretty(&settings)?)
            .with_context(|| config_path.display().to_string())?;
        command
            .args(["serve", &settings.robot, "--listen", "127.0.0.1:0", "--settings"])
            .arg(&config_path)
            .arg("--out")
            .arg(out);
    }
    // The server exits when our end of its stdin closes: it cannot outlive this process.
    command.arg("--exit-with-stdin").stdin(std::process::Stdio::piped());
    let mut server = command.stdout(std::process::Stdio::piped()).spawn()?;
    let stdout = server.stdout.take().ok_or_else(|| anyhow::anyhow!("no server output"))?;
    let mut lines = std::io::BufReader::new(stdout).lines();
    let first = lines.next().transpose()?.unwrap_or_default();
    let Some(addr) = first.strip_prefix("listening on ").and_then(|a| a.parse::<std::net::SocketAddr>().ok()) else {
        // Its error is on stderr; nothing of a run that never started stays behind.
        let _ = server.wait();
        let _ = std::fs::remove_file(&config_path);
        if !resume {
            let _ = std::fs::remove_dir(out);
        }
        anyhow::bail!("the server did not start (its error is above)");
    };
    println!("RobotServer (pid {}) listening on {addr}", server.id());
    // The robots run the run's twin.
    let twin = twinbots::twin::Twin { calibration: settings.calibration.clone(), log: None };
    let result = crate::cli::robot::against_server(
        &settings.robot,
        addr,
        settings.arenas,
        settings.seed,
        std::time::Duration::from_secs(60),
        &twin,
    );
    if result.is_err() {
        // The robots gave up: the server would wait for robots for ever.
        drop(server.stdin.take());
    }
    for line in lines.map_while(Result::ok) {
        println!("server: {line}");
    }
    let status = server.wait()?;
    let _ = std::fs::remove_file(&config_path);
    result?;
    anyhow::ensure!(status.success(), "the server exited with {status}");
    Ok(())
}

/// A fresh run into `out`. Everything that can be checked before it runs is (the pattern the
/// robot supports, the learner for its task), so an error leaves no run directory behind.
pub fn train(settings: TrainSettings, out: &Path, view: bool) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let pattern = settings.design_pattern()?;
    entry.check_supports(settings.task.as_deref(), pattern)?;
    if pattern == DesignPattern::Server {
        return train_through_server(settings, out, false);
    }
    anyhow::ensure!(settings.arenas > 0, "arenas must be at least 1");
    let learner = learner::new(&settings, &settings.task(&entry)?)?;
    let run_dir = twinbots::run::create(&settings, out)?;
    run(settings, run_dir, learner, false, view)
}

/// Continues the run in `run_dir` from its newest checkpoint.
pub fn resume(run_dir: &Path, view: bool) -> anyhow::Result<()> {
    let run_dir = RunDir::new(run_dir);
    let settings = TrainSettings::of_run(&run_dir)?;
    if settings.design_pattern()? == DesignPattern::Server {
        return train_through_server(settings, run_dir.path(), true);
    }
    let spec = settings.task(&registry::find(&settings.robot)?)?;
    let (checkpoint, model) = learner::resume(&run_dir, &settings, &spec)?;
    run_dir.check_progress_columns(model.train_figures())?;
    println!(
        "resuming {} from {} ({} steps, {} episodes)",
        run_dir.path().display(),
        checkpoint.display(),
        model.timesteps(),
        model.episodes()
    );
    run(settings, run_dir, model, true, view)
}

/// Trains the run in `run_dir` for `more` steps beyond its model (its final one, else its
/// newest checkpoint); its `config.toml` records the new budget before anything runs. After a
/// final model the envs start fresh episodes (a checkpoint's are replayed, as `--resume`
/// does); the run's stop criteria still apply (a solved run stops at its next check).
pub fn extend(run_dir: &Path, more: u64, view: bool) -> anyhow::Result<()> {
    anyhow::ensure!(more >= 1, "--timesteps {more}: must be at least 1 more step");
    let run_dir = RunDir::new(run_dir);
    let mut settings = TrainSettings::of_run(&run_dir)?;
    anyhow::ensure!(
        settings.design_pattern()? != DesignPattern::Server,
        "{}: more training of a pattern-3 run is not supported yet; `train --resume` without --timesteps finishes one",
        run_dir.path().display()
    );
    let spec = settings.task(&registry::find(&settings.robot)?)?;
    let (source, model) = learner::trained(&run_dir, &settings, &spec)?;
    run_dir.check_progress_columns(model.train_figures())?;
    settings.timesteps = model.timesteps() + more;
    settings.validate()?;
    run_dir.write_config(&settings)?;
    println!(
        "training {} for {more} more steps from {} ({} steps, {} episodes) to {}",
        run_dir.path().display(),
        source.display(),
        model.timesteps(),
        model.episodes(),
        settings.timesteps
    );
    run(settings, run_dir, model, true, view)
}

/// Trains `learner` (made for the run, or `resumed` from it) in `run_dir`.
fn run(
    settings: TrainSettings,
    run_dir: RunDir,
    mut learner: Box<dyn Learner>,
    resumed: bool,
    view: bool,
) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let pattern = settings.design_pattern()?;
    anyhow::ensure!(
        pattern != DesignPattern::Server,
        "design pattern 3 has no in-process env: use `twinbots serve` and `twinbots robot`"
    );
    let mut app = entry.app(settings.task.as_deref(), settings.arenas, settings.seed, pattern)?;
    settings.calibrate(&mut app);
    settings.observe(&mut app, &entry, settings.arenas)?;
    app.add_plugins(bridge::BridgePlugin);
    settings.randomization.validate()?;
    if !settings.randomization.is_off() {
        app.add_plugins(RandomizationPlugin(settings.randomization.clone()));
    }
    let (_, spec) = env::start(&mut app)?;
    let mut channel_env = bridge::connect(app.world_mut())?;
    learner.check_spaces(&spec.observation_space, &spec.action_space)?;
    let title = format!(
        "{} — {}, pattern {}, {} arenas, seed {}",
        settings.robot,
        learner.algorithm(),
        settings.pattern,
        settings.arenas,
        settings.seed
    );
    let mut callbacks = twinbots::run::callbacks(&settings, &run_dir, &entry, title, spec.solved)?;
    let tally = twinbots_learn::callbacks::GradientStepTally::default();
    callbacks.push(tally.clone());
    if resumed {
        // Everything checked: the rows logged after the checkpoint are redone.
        run_dir.truncate_after(learner.timesteps())?;
    }
    let remaining = settings.timesteps.saturating_sub(learner.timesteps());

    // The learner's thread: the algorithm and its callbacks (logs, evaluations, checkpoints).
    let trainer = std::thread::spawn(move || -> anyhow::Result<(Box<dyn Learner>, TrainingEnd, f64)> {
        let started = Instant::now();
        let end = learner.learn(&mut channel_env, remaining, &mut callbacks)?;
        Ok((learner, end, started.elapsed().as_secs_f64()))
    });

    // The app's thread (this one): frames until the learner hangs up.
    let mut simulation_s = None;
    let sim = if view {
        // The window drives the app in time slices; closing the window stops training.
        let arena = app.world().resource::<env::ArenaOrder>().0[0];
        let source = crate::cli::view::TrainingView {
            app,
            arena,
            frames: 0,
            updates: 0,
            started: Instant::now(),
            last_slice_end: None,
        };
        let shown = twinbots_render::viewer::run(
            Box::new(source),
            &format!("twinbots — training {}", settings.robot),
            entry.framing,
        );
        Ok(shown)
    } else {
        let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| bridge::run_until_closed(&mut app)));
        simulation_s = app.world().get_resource::<bridge::SimulationTime>().map(|t| t.seconds);
        drop(app); // closes the bridge, so a learner still waiting gets an error rather than a hang
        r.map(Ok)
    };
    let learned = trainer.join().map_err(|p| anyhow::anyhow!("the trainer thread panicked: {}", panic_message(&p)))?;
    match sim {
        Err(p) => anyhow::bail!("the simulation panicked: {}", panic_message(&p)),
        Ok(Err(e)) => return Err(e),
        Ok(Ok(())) => {}
    }
    let (learner, end, wall) = learned?;
    tally.check()?;
    let times = learner.times();
    let model: &dyn twinbots_learn::Agent = learner.as_ref();
    let time = simulation_s.map(|sim| TimeBreakdown::new(&times, sim, wall));
    let (evaluation, summary) = twinbots::run::finish(&settings, &run_dir, &entry, model, &end, wall, time)?;
    match end {
        TrainingEnd::Solved { timesteps, by } => {
            println!(
                "solved ({by}) after {timesteps} steps in {wall:.1} s (mean of last 100 episodes {:.1})",
                model.history().mean_score()
            )
        }
        _ => println!(
            "not solved: {} steps in {wall:.1} s, mean of last 100 episodes {:.1}",
            model.timesteps(),
            model.history().mean_score()
        ),
    }
    if let Some(time) = &summary.time_breakdown {
        println!("time: {}", time.describe());
    }
    println!("evaluation of the final model, {}", evaluation.describe());
    println!("run directory: {}", run_dir.path().display());
    Ok(())
}

fn panic_message(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".into())
}
