//! `twinbots`: train, look at and benchmark robot twins.

mod cli;
mod registry;

use clap::{Parser, Subcommand, ValueEnum};

#[derive(Parser)]
#[command(name = "twinbots", version, about = "Robot learning with digital twins")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// List the registered robots.
    Robots,
    /// Train a robot's task with PPO, headless.
    Train {
        /// Robot to train (see `twinbots robots`).
        robot: String,
        /// Env steps (summed over arenas); default: the robot's budget.
        #[arg(long)]
        timesteps: Option<u64>,
        /// Parallel arenas; default: the robot's.
        #[arg(long)]
        arenas: Option<usize>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Run directory; default runs/<robot>-<time>.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Save a checkpoint every this many updates.
        #[arg(long, default_value_t = 10)]
        checkpoint_every: usize,
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
}

fn main() {
    // Errors are for people: one clear line, no backtrace.
    if let Err(error) = run(Args::parse()) {
        eprintln!("error: {error:#}");
        std::process::exit(1);
    }
}

fn run(args: Args) -> anyhow::Result<()> {
    match args.command {
        Command::Robots => cli::robots::print(),
        Command::Train { robot, timesteps, arenas, seed, out, checkpoint_every } => {
            let entry = registry::find(&robot)?;
            let out = out.unwrap_or_else(|| cli::train::default_run_dir(&robot));
            let settings = cli::train::TrainSettings {
                robot,
                timesteps: timesteps.unwrap_or(entry.timesteps),
                arenas: arenas.unwrap_or(entry.arenas),
                seed,
                checkpoint_every,
                ppo: (entry.ppo)(),
            };
            cli::train::train(settings, &out)?
        }
        Command::Bench { what: BenchKind::Physics, robot, arenas, steps } => {
            cli::bench::print_physics(&robot, &arenas, steps)?
        }
    }
    Ok(())
}
