//! `twinbots`: train, look at and benchmark robot twins. Each command is a file of `cli/` with
//! its own arguments (cargo's `commands/`).

mod cli;

use clap::{Parser, Subcommand};
// The commands find robots as `crate::registry`.
use twinbots::registry;

#[derive(Parser)]
#[command(name = "twinbots", version, about = "Robot learning with digital twins")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the learning algorithms (`--algo` and the settings' `[<algo>]` tables name them).
    Algos(cli::algos::Args),
    /// List the registered robots.
    Robots(cli::robots::Args),
    /// Train a robot's task headless, with PPO or another algorithm of `twinbots algos`.
    Train(cli::train::Args),
    /// Run the RobotServer (design pattern 3): hosts the policy and learner, reached over TCP.
    Serve(cli::serve::Args),
    /// Run simulated robots (design pattern 3: no Supervisor, self-homing) against a
    /// RobotServer, or on an exported policy each robot runs itself.
    Robot(cli::robot::Args),
    /// Write a run's trained policy as an ONNX graph (observation normalisation folded in),
    /// with its robot, task, spaces and control period as metadata.
    Export(cli::export::Args),
    /// Replay a trained model and report its episode scores (writes eval.json).
    Eval(cli::eval::Args),
    /// Teach a pixel run's policy by a teacher that sees the state (DAgger): the robot's
    /// classical controller, a state run or an ONNX policy.
    Distill(cli::distill::Args),
    /// Open a window on the twin: arena 0 in real time (Space pause, N step, R reset, Esc quit,
    /// drag to orbit, scroll to zoom).
    View(cli::view::Args),
    /// Render PNG frames of the digital twin off-screen (no window).
    Capture(cli::capture::Args),
    /// Measure performance.
    Bench(cli::bench::Args),
    /// Figures over seeds: runs' steps to solve, wall clock and final evaluation as median,
    /// quartiles and interquartile mean, and their learning curves as a band (PNG).
    Compare(cli::compare::Args),
    /// Check a robot description: its link/joint tree with masses, limits and motors, what
    /// will not simulate well, a stand in the physics, and a picture (`--png`).
    Urdf(cli::urdf::Args),
    /// Run a policy test suite on a robot's twin: step-response kicks, impulse disturbances and
    /// payloads for each controller (classical, trained run, ONNX); per-run time series, figures
    /// (survival, settling time, overshoot, steady-state error), summary, plots and report.
    Study(cli::study::Args),
    /// Record a stand-in robot: the twin with hidden true physics (a truth file), driven
    /// through an excitation program, logging what a controller measures (MCAP or CSV).
    Record(cli::record::Args),
    /// Replay a robot log on the twin and report how far it strays, per joint.
    Replay(cli::replay::Args),
    /// Calibrate the twin to robot logs (system identification with CMA-ES).
    Identify(cli::identify::Args),
    /// Run a deploy bundle's policy on a robot (RTDE), the twin checking every command first;
    /// `--dry-run` drives only the twin.
    Deploy(cli::deploy::Args),
    /// Follow a robot live with its twin (RTDE): divergence per joint, alarms, robot and twin
    /// logged side by side.
    Monitor(cli::monitor::Args),
    /// A UR controller stand-in: serves RTDE on 127.0.0.1:30004, backed by the UR5e twin
    /// (optionally a truth twin) running the shipped control program every 2 ms.
    #[command(name = "ur-sim")]
    UrSim(cli::ur_sim::Args),
    /// The twin as a ROS 2 robot on DDS (no ROS install): publishes /joint_states and /tf,
    /// obeys ros2_control's forward command and joint trajectory topics.
    #[cfg(feature = "ros2")]
    Ros2(cli::ros2::Args),
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
        Command::Algos(args) => cli::algos::exec(args),
        Command::Robots(args) => cli::robots::exec(args),
        Command::Train(args) => cli::train::exec(args),
        Command::Serve(args) => cli::serve::exec(args),
        Command::Robot(args) => cli::robot::exec(args),
        Command::Export(args) => cli::export::exec(args),
        Command::Eval(args) => cli::eval::exec(args),
        Command::View(args) => cli::view::exec(args),
        Command::Capture(args) => cli::capture::exec(args),
        Command::Bench(args) => cli::bench::exec(args),
        Command::Compare(args) => cli::compare::exec(args),
        Command::Urdf(args) => cli::urdf::exec(args),
        Command::Study(args) => cli::study::exec(args),
        Command::Distill(args) => cli::distill::exec(args),
        Command::Record(args) => cli::record::exec(args),
        Command::Replay(args) => cli::replay::exec(args),
        Command::Identify(args) => cli::identify::exec(args),
        Command::UrSim(args) => cli::ur_sim::exec(args),
        Command::Deploy(args) => cli::deploy::exec(args),
        Command::Monitor(args) => cli::monitor::exec(args),
        #[cfg(feature = "ros2")]
        Command::Ros2(args) => cli::ros2::exec(args),
    }
}
