//! `twinbots serve <robot>`: the RobotServer (design pattern 3) as its own process. It hosts the
//! policy and the learner, trains on whatever robots connect, and writes a run directory like
//! `train` does. Its first line of output is `listening on <address>`.
//!
//! Robots connect to it with `twinbots robot <robot> --server <address>` (`cli::robot`).

use std::io::Write;
use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use twinbots_api::DesignPattern;
use twinbots_learn::{Learner, RunDir};
use twinbots_link::tls::ServerTls;
use twinbots_server::server::{RobotServer, ServerLimits, ServerSettings};

use crate::registry;
use twinbots::settings::{CalibrationSetting, ConfigFile, TrainSettings};

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Robot to serve (see `twinbots robots`); not needed with --resume.
    #[arg(required_unless_present = "resume")]
    pub robot: Option<String>,
    /// Address to listen on (port 0: any free port; the first output line tells which).
    /// Loopback by default: robots on other machines need an explicit address such as
    /// 0.0.0.0:7878, and then TLS and a --token (or --insecure).
    #[arg(long, default_value = "127.0.0.1:7878")]
    pub listen: std::net::SocketAddr,
    /// Robots connected at once; the next one is refused (`server_full`).
    #[arg(long, default_value_t = 64)]
    pub max_robots: usize,
    /// A shared secret every robot's hello must carry (default: $TWINBOTS_TOKEN, else none).
    /// An empty one is refused: it is an unset variable, not a choice of no authentication.
    #[arg(long, value_parser = non_empty_token)]
    pub token: Option<String>,
    /// Seconds a new connection has to send its whole hello.
    #[arg(long, default_value_t = 10.0)]
    pub handshake_timeout: f64,
    /// Seconds a robot has to send each whole request after the last reply.
    #[arg(long, default_value_t = 60.0)]
    pub read_timeout: f64,
    /// Robots the learner's batches are sized for (PPO's rollout is n_steps × robots; SAC's
    /// and TD3's iteration is one step of each); default: the robot's arena count.
    #[arg(long)]
    pub robots: Option<usize>,
    /// The algorithm it trains (see `twinbots algos`); default: the robot's.
    #[arg(long, value_parser = super::learner::parse_algo)]
    pub algo: Option<String>,
    #[arg(long)]
    pub timesteps: Option<u64>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// A TOML file of settings, as for `train --config`.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// A complete settings file (a run's config.toml), used as is.
    #[arg(long, conflicts_with = "config")]
    pub settings: Option<std::path::PathBuf>,
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// The twin the robots stand for is calibrated by this file (`twinbots identify`'s): the
    /// run's config.toml records it and its evaluations run that twin (start the robots with
    /// the same `--calibration`).
    #[arg(long, conflicts_with = "settings")]
    pub calibration: Option<std::path::PathBuf>,
    /// Continue the server run in this directory from its newest checkpoint.
    #[arg(long, conflicts_with_all = ["robot", "robots", "algo", "timesteps", "seed", "config", "settings", "out", "calibration"])]
    pub resume: Option<std::path::PathBuf>,
    /// TLS: this server's certificate chain (PEM); with --tls-key. Robots then need --tls-ca.
    #[arg(long, requires = "tls_key")]
    pub tls_cert: Option<std::path::PathBuf>,
    /// TLS: the certificate's private key (PEM).
    #[arg(long, requires = "tls_cert")]
    pub tls_key: Option<std::path::PathBuf>,
    /// Listen beyond loopback without TLS or without a token (a trusted network only): the
    /// token and every observation then travel in clear. Prints a warning.
    #[arg(long)]
    pub insecure: bool,
    /// Exit when standard input closes: for a server started by `train --pattern 3`, which
    /// must not outlive it.
    #[arg(long, hide = true)]
    pub exit_with_stdin: bool,
}

/// `twinbots serve`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let Args {
        robot,
        listen,
        max_robots,
        token,
        handshake_timeout,
        read_timeout,
        robots,
        algo,
        timesteps,
        seed,
        config,
        settings,
        out,
        calibration,
        resume,
        tls_cert,
        tls_key,
        insecure,
        exit_with_stdin,
    } = args;
    if exit_with_stdin {
        exit_when_stdin_closes();
    }
    let tls = match (tls_cert, tls_key) {
        (Some(cert), Some(key)) => Some(ServerTls::from_pem_files(&cert, &key)?),
        _ => None,
    };
    let limits = ServerLimits {
        max_robots,
        token: token.or_else(token_from_env),
        handshake_timeout: seconds("--handshake-timeout", handshake_timeout)?,
        read_timeout: seconds("--read-timeout", read_timeout)?,
        tls,
        ..Default::default()
    };
    check_exposure(listen, &limits, insecure)?;
    if let Some(run) = resume {
        return self::resume(&run, listen, limits);
    }
    let robot = robot.unwrap_or_default();
    let entry = registry::find(&robot)?;
    let settings = match settings {
        Some(path) => TrainSettings::read_file(&path)?,
        None => {
            let file = match config {
                Some(path) => ConfigFile::read(&path)?,
                None => Default::default(),
            };
            let calibration = CalibrationSetting::read_optional(&entry, calibration.as_deref())?;
            let flags = ConfigFile {
                algo,
                timesteps,
                arenas: robots,
                seed,
                pattern: Some(3),
                calibration,
                ..Default::default()
            };
            TrainSettings::resolve(&entry, file, flags)?
        }
    };
    let out = out.unwrap_or_else(|| twinbots::run::default_run_dir(&format!("{robot}-server")));
    serve(settings, listen, limits, &out)
}

/// Test-only: set to make the learner panic in its first update, so tests can show that a
/// failing learner ends `serve` with an error instead of leaving it hanging (no settings that
/// pass validation make an update fail).
pub const PANIC_IN_UPDATE_ENV: &str = "TWINBOTS_TEST_PANIC_IN_UPDATE";

/// The shared secret from the environment, for `serve` and `robot` when no --token is given
/// (keeps it out of the process list).
pub const TOKEN_ENV: &str = "TWINBOTS_TOKEN";

/// Beyond loopback a server needs TLS and a token, unless `--insecure` says the network is
/// trusted (then a warning names what travels in clear).
fn check_exposure(listen: SocketAddr, limits: &ServerLimits, insecure: bool) -> anyhow::Result<()> {
    if listen.ip().is_loopback() {
        return Ok(());
    }
    let mut missing = Vec::new();
    if limits.tls.is_none() {
        missing.push("TLS (--tls-cert and --tls-key)");
    }
    if limits.token.is_none() {
        missing.push("a token (--token or $TWINBOTS_TOKEN)");
    }
    if missing.is_empty() {
        return Ok(());
    }
    anyhow::ensure!(
        insecure,
        "--listen {listen} reaches beyond this machine: it needs {}, or --insecure on a trusted network",
        missing.join(" and ")
    );
    eprintln!(
        "warning: --insecure: listening on {listen} without {}; the token and every observation travel in clear, and anyone who reaches the port can train this model",
        missing.join(" or ")
    );
    Ok(())
}

/// `--token`'s value: refused when empty (`--token "$UNSET"` would otherwise switch the
/// authentication off, silently).
pub fn non_empty_token(value: &str) -> Result<String, String> {
    if value.is_empty() {
        return Err("an empty token is refused (an unset variable?); leave --token out for no token".into());
    }
    Ok(value.to_string())
}

/// An empty $TWINBOTS_TOKEN counts as unset.
pub fn token_from_env() -> Option<String> {
    std::env::var(TOKEN_ENV).ok().filter(|t| !t.is_empty())
}

/// Ends the process (exit 1) once standard input closes, i.e. when the process that started
/// this server and holds the other end dies, however it dies (even SIGKILL).
pub fn exit_when_stdin_closes() {
    std::thread::spawn(|| {
        use std::io::Read;
        let mut sink = [0u8; 256];
        let mut stdin = std::io::stdin();
        while matches!(stdin.read(&mut sink), Ok(n) if n > 0) {}
        eprintln!("error: the process that started this server has ended");
        std::process::exit(1);
    });
}

/// A timeout flag's seconds as a duration: finite and positive, or a clear error.
pub fn seconds(flag: &str, value: f64) -> anyhow::Result<Duration> {
    anyhow::ensure!(value.is_finite() && value > 0.0 && value < 1e9, "{flag} {value}: must be a number of seconds > 0");
    Ok(Duration::from_secs_f64(value))
}

/// Runs a server until training ends. `settings.arenas` is the number of robots the learner's
/// batches are sized for (PPO's rollout is n_steps × robots). The server trains with the same callbacks as
/// `train` (periodic evaluation runs the policy in-process, under pattern 1), and evaluates the
/// final model in-process into `eval.json` as `train` does. A failure anywhere in the server
/// (learner error, panic in a server thread) returns the error: `main` exits 1 with it.
pub fn serve(settings: TrainSettings, listen: SocketAddr, limits: ServerLimits, out: &Path) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let spec = entry.task();
    anyhow::ensure!(entry.supports(None, DesignPattern::Server)?, "{} has no design-pattern-3 robot", entry.name);
    anyhow::ensure!(limits.max_robots >= 1, "--max-robots must be at least 1");
    // Any algorithm whose `serves` is true (`settings.validate` refuses the others).
    let model = super::learner::new(&settings, &spec)?;
    let run_dir = twinbots::run::create(&settings, out)?;
    host(settings, run_dir, model, listen, limits)
}

/// Continues the server run in `run` from its newest checkpoint that loads, to its budget. The
/// robots' episodes start afresh (they are other processes: their state is theirs), so unlike
/// an in-process run's this resume is not bit-identical to an uninterrupted run.
pub fn resume(run: &Path, listen: SocketAddr, limits: ServerLimits) -> anyhow::Result<()> {
    let run_dir = RunDir::new(run);
    let settings = TrainSettings::of_run(&run_dir)?;
    anyhow::ensure!(
        settings.design_pattern()? == DesignPattern::Server,
        "{}: not a RobotServer run (resume it with `twinbots train --resume`)",
        run.display()
    );
    anyhow::ensure!(limits.max_robots >= 1, "--max-robots must be at least 1");
    let spec = registry::find(&settings.robot)?.task();
    let (checkpoint, model) = super::learner::resume(&run_dir, &settings, &spec)?;
    run_dir.check_progress_columns(model.train_figures())?;
    model.check_spaces(&spec.observation_space, &spec.action_space)?;
    eprintln!(
        "resuming {} from {} ({} steps, {} episodes)",
        run.display(),
        checkpoint.display(),
        model.timesteps(),
        model.episodes()
    );
    run_dir.truncate_after(model.timesteps())?;
    host(settings, run_dir, model, listen, limits)
}

/// Hosts `model` and its learner until training ends, into `run_dir`.
fn host(
    settings: TrainSettings,
    run_dir: RunDir,
    model: Box<dyn Learner>,
    listen: SocketAddr,
    limits: ServerLimits,
) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let spec = entry.task();
    let out = run_dir.path().to_path_buf();
    let title = format!(
        "{} — {} through the RobotServer (pattern 3), seed {}",
        settings.robot,
        model.algorithm(),
        settings.seed
    );
    let mut callbacks = twinbots::run::callbacks(&settings, &run_dir, &entry, title, spec.solved)?;
    let tally = twinbots_learn::callbacks::GradientStepTally::default();
    callbacks.push(tally.clone());
    if std::env::var_os(PANIC_IN_UPDATE_ENV).is_some() {
        callbacks = callbacks.with(
            |_: &twinbots_learn::UpdateStats, _: &dyn twinbots_learn::Agent| -> anyhow::Result<twinbots_learn::Flow> {
                panic!("{PANIC_IN_UPDATE_ENV} is set: the learner panics in its update")
            },
        );
    }
    let mut server_settings = ServerSettings::new(&settings.robot, &spec, settings.arenas.max(1), settings.timesteps);
    server_settings.limits = limits;
    server_settings.task = server_settings.task.with_control_period(entry.control_period_s());
    let started = Instant::now();
    let server = RobotServer::start(listen, model, server_settings, Box::new(callbacks))?;
    println!("listening on {}", server.addr);
    std::io::stdout().flush()?;
    let (model, end) = server.wait()?;
    tally.check()?;
    let wall = started.elapsed().as_secs_f64();
    // The final model, evaluated in-process (pattern 1 runs the same policy) as `train` does.
    twinbots::run::finish(&settings, &run_dir, &entry, model.as_ref(), &end, wall, None)?;
    println!("{end} in {wall:.1} s, mean of last 100 episodes {:.1}", model.history().mean_score());
    println!("run directory: {}", out.display());
    // Give connected robots a moment to read their `done` before the process exits.
    std::thread::sleep(Duration::from_millis(200));
    Ok(())
}
