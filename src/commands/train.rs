//! `twinbots train <robot>`: PPO (or another algorithm of `twinbots algos`) on N arenas,
//! headless, into a run directory (`twinbots_run::run::Run`: what it holds, how it resumes).
//! Training stops at `timesteps` or when the task's solved criterion holds; `--resume`
//! continues from the last checkpoint with its counters. Under design pattern 3 the learner
//! is a `twinbots serve` process of its own and the robots run here.

use anyhow::Context;
use std::path::Path;

use twinbots_api::DesignPattern;
use twinbots_learn::RunDir;
use twinbots_ops::fleet;
use twinbots_run::learner;
use twinbots_run::live::LiveArgs;
use twinbots_run::registry;
use twinbots_run::run::{Run, Watch, default_run_dir};
use twinbots_run::settings::{CalibrationSetting, ConfigFile, TrainSettings, read_cell};
use twinbots_run::twin::Twin;

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
    /// Behaviour cloning from these demonstrations: a LeRobot dataset whose observation and
    /// action features match the robot's (`twinbots demos` writes one); implies `--algo bc`.
    #[arg(long, value_name = "DIR")]
    pub demos: Option<std::path::PathBuf>,
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
    #[command(flatten)]
    pub live: LiveArgs,
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
    #[arg(long, conflicts_with_all = ["robot", "task", "arenas", "seed", "pattern", "config", "out", "algo", "demos", "calibration", "cell"])]
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
        demos,
        config,
        out,
        checkpoint_every,
        view,
        live,
        calibration,
        cell,
        resume,
        print_config,
    } = args;
    let watch = Watch { window: view, live: live.start()? };
    if let Some(run) = resume {
        if print_config {
            print!("{}", toml::to_string_pretty(&TrainSettings::of_run(&RunDir::new(run))?)?);
            return Ok(());
        }
        return match timesteps {
            Some(more) => extend(&run, more, watch),
            None => self::resume(&run, watch),
        };
    }
    let robot = robot.unwrap_or_default();
    let entry = registry::find(&robot)?;
    let file = match config {
        Some(path) => ConfigFile::read(&path)?,
        None => Default::default(),
    };
    let calibration = calibration.map(|path| CalibrationSetting::read(&entry, &path)).transpose()?;
    let cell = cell.map(|path| read_cell(&entry, &path)).transpose()?;
    let (algo, hyperparams) = match demos {
        Some(dir) => demos_flag(&dir, algo)?,
        None => (algo, Default::default()),
    };
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
        hyperparams,
        ..Default::default()
    };
    let settings = TrainSettings::resolve(&entry, file, flags)?;
    if print_config {
        print!("{}", toml::to_string_pretty(&settings)?);
        return Ok(());
    }
    let out = out.unwrap_or_else(|| default_run_dir(&robot));
    if settings.design_pattern()? == DesignPattern::Server {
        registry::find(&settings.robot)?.check_supports(settings.task.as_deref(), DesignPattern::Server)?;
        return train_through_server(settings, &out, false);
    }
    Run::create(settings, &out)?.train(watch)
}

/// `--demos DIR` as settings: `algo = "bc"` and `[bc] demos`, the dataset's absolute path (so
/// the run resumes from anywhere).
fn demos_flag(
    dir: &Path,
    algo: Option<String>,
) -> anyhow::Result<(Option<String>, std::collections::BTreeMap<String, toml::Value>)> {
    let bc = twinbots_learn::bc::NAME;
    if let Some(other) = algo.as_deref().filter(|a| *a != bc) {
        anyhow::bail!("--demos is behaviour cloning's dataset: it goes with --algo {bc}, not --algo {other}");
    }
    let dir = std::fs::canonicalize(dir).with_context(|| format!("--demos {}", dir.display()))?;
    let table = toml::Table::from_iter([("demos".to_string(), toml::Value::String(dir.display().to_string()))]);
    Ok((Some(bc.to_string()), [(bc.to_string(), toml::Value::Table(table))].into()))
}

/// Continues the run in `run_dir` from its newest checkpoint.
fn resume(run_dir: &Path, watch: Watch) -> anyhow::Result<()> {
    let settings = TrainSettings::of_run(&RunDir::new(run_dir))?;
    if settings.design_pattern()? == DesignPattern::Server {
        return train_through_server(settings, run_dir, true);
    }
    let (run, checkpoint) = Run::resume(run_dir)?;
    println!(
        "resuming {} from {} ({} steps, {} episodes)",
        run_dir.display(),
        checkpoint.display(),
        run.learner.timesteps(),
        run.learner.episodes()
    );
    run.train(watch)
}

/// Trains the run in `run_dir` for `more` steps beyond its model ([`Run::extend`]).
fn extend(run_dir: &Path, more: u64, watch: Watch) -> anyhow::Result<()> {
    let (run, source) = Run::extend(run_dir, more)?;
    println!(
        "training {} for {more} more steps from {} ({} steps, {} episodes) to {}",
        run_dir.display(),
        source.display(),
        run.learner.timesteps(),
        run.learner.episodes(),
        run.settings.timesteps
    );
    run.train(watch)
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
    let twin = Twin { calibration: settings.calibration.clone(), log: None };
    let result = fleet::against_server(
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
