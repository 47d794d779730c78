//! `twinbots`: train, look at and benchmark robot twins. Each command is a file of `commands/`
//! with its own arguments and `exec` (cargo's `commands/`); what commands share lives in the
//! application crates (`plugins/app`), never in another command.

mod commands;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "twinbots", version, about = "Robot learning with digital twins")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the learning algorithms (`--algo` and the settings' `[<algo>]` tables name them).
    Algos(commands::algos::Args),
    /// List the registered robots.
    Robots(commands::robots::Args),
    /// Train a robot's task headless, with PPO or another algorithm of `twinbots algos`.
    Train(commands::train::Args),
    /// Run the RobotServer (design pattern 3): hosts the policy and learner, reached over TCP.
    Serve(commands::serve::Args),
    /// Run simulated robots (design pattern 3: no Supervisor, self-homing) against a
    /// RobotServer, or on an exported policy each robot runs itself.
    Robot(commands::robot::Args),
    /// Write a run's trained policy as an ONNX graph (observation normalisation folded in),
    /// with its robot, task, spaces and control period as metadata.
    Export(commands::export::Args),
    /// Replay a trained model and report its episode scores (writes eval.json).
    Eval(commands::eval::Args),
    /// Write demonstrations as a LeRobot dataset (v3.0): a scripted or classical controller, a
    /// trained run or an ONNX policy driving the twin for N episodes.
    Demos(commands::demos::Args),
    /// Teach a pixel run's policy by a teacher that sees the state (DAgger): the robot's
    /// classical controller, a state run or an ONNX policy.
    Distill(commands::distill::Args),
    /// Open a window on the twin: arena 0 in real time (Space pause, N step, R reset, Esc quit,
    /// drag to orbit, scroll to zoom).
    View(commands::view::Args),
    /// Render PNG frames of the digital twin off-screen (no window).
    Capture(commands::capture::Args),
    /// Measure performance.
    Bench(commands::bench::Args),
    /// Figures over seeds: runs' steps to solve, wall clock and final evaluation as median,
    /// quartiles and interquartile mean, and their learning curves as a band (PNG).
    Compare(commands::compare::Args),
    /// Check a robot description: its link/joint tree with masses, limits and motors, what
    /// will not simulate well, a stand in the physics, and a picture (`--png`).
    Urdf(commands::urdf::Args),
    /// Run a policy test suite on a robot's twin: step-response kicks, impulse disturbances and
    /// payloads for each controller (classical, trained run, ONNX); per-run time series, figures
    /// (survival, settling time, overshoot, steady-state error), summary, plots and report.
    Study(commands::study::Args),
    /// Record a stand-in robot: the twin with hidden true physics (a truth file), driven
    /// through an excitation program, logging what a controller measures (MCAP or CSV).
    Record(commands::record::Args),
    /// Replay a robot log on the twin and report how far it strays, per joint.
    Replay(commands::replay::Args),
    /// Calibrate the twin to robot logs (system identification with CMA-ES).
    Identify(commands::identify::Args),
    /// Run a deploy bundle's policy on a robot (RTDE), the twin checking every command first;
    /// `--dry-run` drives only the twin.
    Deploy(commands::deploy::Args),
    /// Follow a robot live with its twin (RTDE): divergence per joint, alarms, robot and twin
    /// logged side by side.
    Monitor(commands::monitor::Args),
    /// A UR controller stand-in: serves RTDE on 127.0.0.1:30004, backed by the UR5e's twin or
    /// a robot file's six-joint arm's (optionally a truth twin) running the shipped control
    /// program every 2 ms.
    #[command(name = "ur-sim")]
    UrSim(commands::ur_sim::Args),
    /// The twin as a ROS 2 robot on DDS (no ROS install): publishes /joint_states and /tf,
    /// obeys ros2_control's forward command and joint trajectory topics.
    #[cfg(feature = "ros2")]
    Ros2(commands::ros2::Args),
}

/// A report piped into `head` ends as Unix tools end when the reader leaves: killed by SIGPIPE,
/// silently. Rust ignores SIGPIPE, so the next `println!` would panic on the closed pipe. Only
/// for the commands that print reports: the servers keep it ignored (their sockets are written
/// with `MSG_NOSIGNAL` anyway), so a run is never killed by a pipe.
fn end_quietly_when_the_reader_leaves() {
    // SAFETY: restores the default disposition of one signal before any other thread writes.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
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
    // `robots` writes its listing in one piece and ends with status 0 on a closed pipe itself.
    if matches!(
        args.command,
        Command::Algos(_)
            | Command::Bench(_)
            | Command::Compare(_)
            | Command::Urdf(_)
            | Command::Record(_)
            | Command::Replay(_)
            | Command::Identify(_)
    ) {
        end_quietly_when_the_reader_leaves();
    }
    match args.command {
        Command::Algos(args) => commands::algos::exec(args),
        Command::Robots(args) => commands::robots::exec(args),
        Command::Train(args) => commands::train::exec(args),
        Command::Serve(args) => commands::serve::exec(args),
        Command::Robot(args) => commands::robot::exec(args),
        Command::Export(args) => commands::export::exec(args),
        Command::Eval(args) => commands::eval::exec(args),
        Command::View(args) => commands::view::exec(args),
        Command::Capture(args) => commands::capture::exec(args),
        Command::Bench(args) => commands::bench::exec(args),
        Command::Compare(args) => commands::compare::exec(args),
        Command::Urdf(args) => commands::urdf::exec(args),
        Command::Study(args) => commands::study::exec(args),
        Command::Distill(args) => commands::distill::exec(args),
        Command::Demos(args) => commands::demos::exec(args),
        Command::Record(args) => commands::record::exec(args),
        Command::Replay(args) => commands::replay::exec(args),
        Command::Identify(args) => commands::identify::exec(args),
        Command::UrSim(args) => commands::ur_sim::exec(args),
        Command::Deploy(args) => commands::deploy::exec(args),
        Command::Monitor(args) => commands::monitor::exec(args),
        #[cfg(feature = "ros2")]
        Command::Ros2(args) => commands::ros2::exec(args),
    }
}
