//! `twinbots serve <robot>`: the RobotServer (design pattern 3) as its own process. It hosts the
//! policy and the learner, trains on whatever robots connect, and writes a run directory like
//! `train` does. Its first line of output is `listening on <address>`.
//!
//! Robots connect to it with `twinbots robot <robot> --server <address>` (`commands::robot`).

use std::io::Write;
use std::net::SocketAddr;
use std::time::Duration;

use twinbots_link::tls::ServerTls;
use twinbots_link::token;
use twinbots_run::registry;
use twinbots_run::run::{Hosting, Run, default_run_dir};
use twinbots_run::settings::{CalibrationSetting, ConfigFile, TrainSettings};
use twinbots_server::server::ServerLimits;

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
    #[arg(long, value_parser = token::non_empty)]
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
    #[arg(long, value_parser = twinbots_run::learner::parse_algo)]
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
        token: token.or_else(token::from_env),
        handshake_timeout: seconds("--handshake-timeout", handshake_timeout)?,
        read_timeout: seconds("--read-timeout", read_timeout)?,
        tls,
        ..Default::default()
    };
    anyhow::ensure!(limits.max_robots >= 1, "--max-robots must be at least 1");
    check_exposure(listen, &limits, insecure)?;
    let hosting = Hosting { listen, limits };
    if let Some(run) = resume {
        return self::resume(&run, hosting);
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
    let out = out.unwrap_or_else(|| default_run_dir(&format!("{robot}-server")));
    serve(settings, hosting, &out)
}

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

/// Hosts a fresh run of `settings` into `out` until training ends ([`Run::host`]).
fn serve(settings: TrainSettings, hosting: Hosting, out: &std::path::Path) -> anyhow::Result<()> {
    Run::create(settings, out)?.host(hosting, announce)
}

/// Continues the server run in `run` from its newest checkpoint that loads, to its budget. The
/// robots' episodes start afresh (they are other processes: their state is theirs), so unlike
/// an in-process run's this resume is not bit-identical to an uninterrupted run.
fn resume(run: &std::path::Path, hosting: Hosting) -> anyhow::Result<()> {
    let settings = TrainSettings::of_run(&twinbots_learn::RunDir::new(run))?;
    anyhow::ensure!(
        settings.design_pattern()? == twinbots_api::DesignPattern::Server,
        "{}: not a RobotServer run (resume it with `twinbots train --resume`)",
        run.display()
    );
    let (run_, checkpoint) = Run::resume(run)?;
    eprintln!(
        "resuming {} from {} ({} steps, {} episodes)",
        run.display(),
        checkpoint.display(),
        run_.learner.timesteps(),
        run_.learner.episodes()
    );
    run_.host(hosting, announce)
}

/// The server's first line of output, which `train --pattern 3` and scripts wait for.
fn announce(addr: SocketAddr) -> anyhow::Result<()> {
    println!("listening on {addr}");
    std::io::stdout().flush()?;
    Ok(())
}
