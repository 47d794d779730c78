//! `twinbots`: train, look at and benchmark robot twins.

mod cli;
use twinbots::registry;

use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(name = "twinbots", version, about = "Robot learning with digital twins")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the learning algorithms (`--algo` and the settings' `[<algo>]` tables name them).
    Algos,
    /// List the registered robots.
    Robots {
        /// Print each robot's tasks as the RobotServer's `welcome` describes them (spaces with
        /// bounds, observation names, reward range), as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Train a robot's task with PPO (or SAC), headless.
    Train {
        /// Robot to train (see `twinbots robots`); not needed with --resume.
        #[arg(required_unless_present = "resume")]
        robot: Option<String>,
        /// Env steps (summed over arenas); default: the robot's budget.
        #[arg(long)]
        timesteps: Option<u64>,
        /// Parallel arenas; default: the robot's.
        #[arg(long)]
        arenas: Option<usize>,
        #[arg(long)]
        seed: Option<u64>,
        /// Design pattern (paper §3): 1 RLRobot + Supervisor, 2 SupervisorRobot + SlaveRobot over
        /// radio, 3 RobotServer + Communicator.
        #[arg(long, value_parser = clap::value_parser!(u8).range(1..=3))]
        pattern: Option<u8>,
        /// The learner, by name (`twinbots algos` lists them); default: the robot's (ppo).
        #[arg(long, value_parser = parse_algo)]
        algo: Option<String>,
        /// A TOML file with settings (timesteps, arenas, seed, checkpoint_every, eval_every,
        /// eval_episodes, algo, [ppo] / [sac] hyperparameters); flags override it.
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// Run directory; default runs/<robot>-<time>.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Save a checkpoint every this many updates.
        #[arg(long)]
        checkpoint_every: Option<usize>,
        /// Show arena 0 in a window while training (the other arenas train at full speed).
        #[arg(long)]
        view: bool,
        /// Continue the run in this directory from its newest checkpoint.
        #[arg(long, conflicts_with_all = ["robot", "timesteps", "arenas", "seed", "pattern", "config", "out", "algo"])]
        resume: Option<std::path::PathBuf>,
        /// Print the settings the run would use (the robot's defaults ← the config file ← the
        /// flags, key by key) as TOML, and exit without training.
        #[arg(long)]
        print_config: bool,
    },
    /// Run the RobotServer (design pattern 3): hosts the policy and learner, reached over TCP.
    Serve {
        /// Robot to serve (see `twinbots robots`); not needed with --resume.
        #[arg(required_unless_present = "resume")]
        robot: Option<String>,
        /// Address to listen on (port 0: any free port; the first output line tells which).
        /// Loopback by default: robots on other machines need an explicit address such as
        /// 0.0.0.0:7878, and then a --token.
        #[arg(long, default_value = "127.0.0.1:7878")]
        listen: std::net::SocketAddr,
        /// Robots connected at once; the next one is refused (`server_full`).
        #[arg(long, default_value_t = 64)]
        max_robots: usize,
        /// A shared secret every robot's hello must carry (default: $TWINBOTS_TOKEN, else none).
        #[arg(long)]
        token: Option<String>,
        /// Seconds a new connection has to send its whole hello.
        #[arg(long, default_value_t = 10.0)]
        handshake_timeout: f64,
        /// Seconds a robot has to send each whole request after the last reply.
        #[arg(long, default_value_t = 60.0)]
        read_timeout: f64,
        /// Robots a rollout is sized for; default: the robot's arena count.
        #[arg(long)]
        robots: Option<usize>,
        #[arg(long)]
        timesteps: Option<u64>,
        #[arg(long)]
        seed: Option<u64>,
        /// A TOML file of settings, as for `train --config`.
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// A complete settings file (a run's config.toml), used as is.
        #[arg(long, conflicts_with = "config")]
        settings: Option<std::path::PathBuf>,
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Continue the server run in this directory from its newest checkpoint.
        #[arg(long, conflicts_with_all = ["robot", "robots", "timesteps", "seed", "config", "settings", "out"])]
        resume: Option<std::path::PathBuf>,
        /// Exit when standard input closes: for a server started by `train --pattern 3`, which
        /// must not outlive it.
        #[arg(long, hide = true)]
        exit_with_stdin: bool,
    },
    /// Run simulated robots (design pattern 3: no Supervisor, self-homing) against a
    /// RobotServer, or on an exported policy each robot runs itself.
    #[command(group = clap::ArgGroup::new("source").required(true).args(["server", "policy"]))]
    Robot {
        robot: String,
        /// The RobotServer's address.
        #[arg(long)]
        server: Option<std::net::SocketAddr>,
        /// An exported policy (`twinbots export`) that the robots run on board, no server.
        #[arg(long)]
        policy: Option<std::path::PathBuf>,
        #[arg(long, default_value_t = 1)]
        arenas: usize,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Seconds to keep trying to reach the server.
        #[arg(long, default_value_t = 30, conflicts_with = "policy")]
        patience: u64,
        /// The server's shared secret (default: $TWINBOTS_TOKEN, else none).
        #[arg(long, conflicts_with = "policy")]
        token: Option<String>,
        /// With --policy: episodes to run before reporting their figures.
        #[arg(long, default_value_t = 10, conflicts_with = "server")]
        episodes: usize,
    },
    /// Write a run's trained policy as an ONNX graph (observation normalisation folded in),
    /// with its robot, task, spaces and control period as metadata.
    Export {
        /// Run directory of `twinbots train` or `twinbots serve`.
        run: std::path::PathBuf,
        /// The ONNX file to write.
        #[arg(long)]
        onnx: std::path::PathBuf,
    },
    /// Replay a trained model and report its episode scores (writes eval.json).
    Eval {
        /// Run directory of `twinbots train`.
        run: std::path::PathBuf,
        #[arg(long, default_value_t = 100)]
        episodes: usize,
        /// Parallel arenas; default: the run's.
        #[arg(long)]
        arenas: Option<usize>,
        /// Also write the PNG frames of one evaluation episode into this directory.
        #[arg(long)]
        record: Option<std::path::PathBuf>,
        #[arg(long, default_value = "640x480")]
        size: String,
        #[arg(long, default_value = "side")]
        camera: String,
        /// Evaluate on another task of the robot's cell (see `twinbots robots`), e.g. the
        /// UR5e's pick-place with its reach model; default: the task it was trained on.
        #[arg(long)]
        task: Option<String>,
    },
    /// Open a window on the twin: arena 0 in real time (Space pause, N step, R reset, Esc quit,
    /// drag to orbit, scroll to zoom).
    View {
        robot: String,
        /// Drive the robot with this run's trained model (default: zero actions).
        #[arg(long)]
        model: Option<std::path::PathBuf>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// The task to run (see `twinbots robots`); default: the robot's own.
        #[arg(long)]
        task: Option<String>,
    },
    /// Render PNG frames of the digital twin off-screen (no window).
    Capture {
        robot: String,
        /// Drive the robot with this run's trained model (default: zero actions).
        #[arg(long)]
        model: Option<std::path::PathBuf>,
        #[arg(long, default_value_t = 50)]
        frames: usize,
        /// Physics control steps between frames.
        #[arg(long, default_value_t = 1)]
        every: usize,
        #[arg(long, default_value = "640x480")]
        size: String,
        /// Camera: side, front, iso or top.
        #[arg(long, default_value = "side")]
        camera: String,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// The task to run (see `twinbots robots`); default: the robot's own.
        #[arg(long)]
        task: Option<String>,
        #[arg(long)]
        out: std::path::PathBuf,
    },
    /// Measure performance.
    Bench {
        #[arg(value_enum)]
        what: BenchKind,
        /// Robot to benchmark.
        #[arg(long, default_value = "cartpole")]
        robot: String,
        /// Arena counts to measure, comma-separated.
        #[arg(long, value_delimiter = ',', default_values_t = vec![1, 16, 64])]
        arenas: Vec<usize>,
        /// Control steps per measurement.
        #[arg(long, default_value_t = 2000)]
        steps: usize,
    },
}

#[derive(Clone, Copy, ValueEnum)]
enum BenchKind {
    /// Control steps per second with N arenas, and the schedule's cost per step.
    Physics,
    /// PPO update time per 2048 samples; env steps/s through the channel bridge vs directly
    /// (with the first of --arenas).
    Rl,
    /// RobotServer step round trip, and steps/s with N robots (--arenas as robot counts).
    Server,
    /// Frames/s of off-screen capture at 640x480 and 64x64.
    Capture,
}

/// `--algo`'s value: a name of the algorithm table, or an error listing them.
fn parse_algo(name: &str) -> Result<String, String> {
    twinbots_learn::algos::find(name).map(|a| a.name.to_string()).map_err(|e| e.to_string())
}

fn main() {
    // Before any other thread starts: the pools for arenas and candle, sized for this machine.
    twinbots_learn::threads::configure();
    // Errors are for people: one clear line, no backtrace.
    if let Err(error) = run(Args::parse()) {
        eprintln!("error: {error:#}");
        std::process::exit(1);
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Algos => {
            for a in twinbots_learn::ALGOS {
                println!("{:<6} {}", a.name, a.summary);
            }
        }
        Command::Robots { json: false } => cli::robots::print(),
        Command::Robots { json: true } => cli::robots::print_json()?,
        Command::Train { resume: Some(run), print_config: true, .. } => {
            print!("{}", toml::to_string_pretty(&cli::runs::TrainSettings::of_run(&twinbots_learn::RunDir::new(run))?)?)
        }
        Command::Train { resume: Some(run), view, .. } => cli::train::resume(&run, view)?,
        Command::Train { robot, timesteps, arenas, seed, pattern, algo, config, out, checkpoint_every, view, resume: None, print_config } => {
            let robot = robot.unwrap_or_default();
            let entry = registry::find(&robot)?;
            let file = match config {
                Some(path) => cli::runs::ConfigFile::read(&path)?,
                None => Default::default(),
            };
            let flags = cli::runs::ConfigFile { timesteps, arenas, seed, pattern, checkpoint_every, algo, ..Default::default() };
            let settings = cli::runs::TrainSettings::resolve(&entry, file, flags)?;
            if print_config {
                print!("{}", toml::to_string_pretty(&settings)?);
                return Ok(());
            }
            let out = out.unwrap_or_else(|| cli::runs::default_run_dir(&robot));
            cli::train::train(settings, &out, view)?
        }
        Command::Serve { robot, listen, max_robots, token, handshake_timeout, read_timeout, robots, timesteps, seed, config, settings, out, resume, exit_with_stdin } => {
            if exit_with_stdin {
                cli::serve::exit_when_stdin_closes();
            }
            let limits = twinbots_server::server::ServerLimits {
                max_robots,
                token: token.or_else(cli::serve::token_from_env),
                handshake_timeout: cli::serve::seconds("--handshake-timeout", handshake_timeout)?,
                read_timeout: cli::serve::seconds("--read-timeout", read_timeout)?,
                ..Default::default()
            };
            if let Some(run) = resume {
                return cli::serve::resume(&run, listen, limits);
            }
            let robot = robot.unwrap_or_default();
            let entry = registry::find(&robot)?;
            let settings = match settings {
                Some(path) => cli::runs::TrainSettings::read_file(&path)?,
                None => {
                    let file = match config {
                        Some(path) => cli::runs::ConfigFile::read(&path)?,
                        None => Default::default(),
                    };
                    let flags = cli::runs::ConfigFile { timesteps, arenas: robots, seed, pattern: Some(3), ..Default::default() };
                    cli::runs::TrainSettings::resolve(&entry, file, flags)?
                }
            };
            let out = out.unwrap_or_else(|| cli::runs::default_run_dir(&format!("{robot}-server")));
            cli::serve::serve(settings, listen, limits, &out)?
        }
        Command::Robot { robot, server: Some(server), arenas, seed, patience, token, .. } => {
            let token = token.or_else(cli::serve::token_from_env);
            cli::robot::against_server_with_token(&robot, server, arenas, seed, std::time::Duration::from_secs(patience), token)?;
        }
        Command::Robot { robot, policy: Some(policy), arenas, seed, episodes, .. } => {
            cli::robot::with_policy(&robot, &policy, arenas, episodes, seed)?;
        }
        Command::Robot { .. } => unreachable!("clap requires --server or --policy"),
        Command::Export { run, onnx } => {
            cli::export::export_run(&run, &onnx)?;
        }
        Command::Eval { run, episodes, arenas, record, size, camera, task } => {
            cli::eval::eval_run(&run, episodes, arenas, task.as_deref())?;
            if let Some(dir) = record {
                cli::eval::record_episode(&run, &dir, cli::capture::parse_size(&size)?, &camera, task.as_deref())?;
            }
        }
        Command::View { robot, model, seed, task } => cli::view::view(&robot, model.as_deref(), seed, task.as_deref())?,
        Command::Capture { robot, model, frames, every, size, camera, seed, task, out } => {
            let size = cli::capture::parse_size(&size)?;
            cli::capture::capture(cli::capture::CaptureArgs { robot, model, frames, every, size, camera, seed, task, out })?
        }
        Command::Bench { what: BenchKind::Physics, robot, arenas, steps } => {
            cli::bench::print_physics(&robot, &arenas, steps)?
        }
        Command::Bench { what: BenchKind::Server, arenas, steps, .. } => cli::bench::print_server(&arenas, steps)?,
        Command::Bench { what: BenchKind::Capture, robot, .. } => {
            cli::bench::print_capture(&robot, &[(640, 480), (64, 64)], 60)?
        }
        Command::Bench { what: BenchKind::Rl, robot, arenas, steps } => {
            cli::bench::print_rl(&robot, arenas.first().copied().unwrap_or(8), steps)?
        }
    }
    Ok(())
}
