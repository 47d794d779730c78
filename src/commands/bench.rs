//! `twinbots bench <what>`: throughput and latency figures (docs/benchmarks.md), measured by
//! `twinbots_bench`.

use twinbots_bench::{print_cameras, print_capture, print_live, print_physics, print_rl, print_rtde, print_server};

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    #[arg(value_enum)]
    pub what: BenchKind,
    /// Robot to benchmark.
    #[arg(long, default_value = "cartpole")]
    pub robot: String,
    /// Arena counts to measure, comma-separated.
    #[arg(long, value_delimiter = ',', default_values_t = vec![1, 16, 64])]
    pub arenas: Vec<usize>,
    /// Control steps per measurement (2000; `bench cameras`: 40; `bench live`: the training
    /// run's timesteps, its default if not given).
    #[arg(long)]
    pub steps: Option<usize>,
    /// `bench rtde`: the deploy bundle whose policy answers every report.
    #[arg(long)]
    pub bundle: Option<std::path::PathBuf>,
    /// `bench rtde`: run the client on SCHED_FIFO at this priority (the stand-in at one less).
    #[arg(long)]
    pub rt_priority: Option<i32>,
    /// `bench rtde`: seconds of controller time to measure.
    #[arg(long, default_value_t = 10.0)]
    pub seconds: f64,
    /// `bench live`: runs of each kind (without and with a viewer, taking turns).
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// `bench live`: the live view sends every control step (`--live-every-step`).
    #[arg(long)]
    pub every_step: bool,
}

/// `twinbots bench`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let steps = args.steps.unwrap_or(2000);
    match args.what {
        BenchKind::Physics => print_physics(&args.robot, &args.arenas, steps),
        BenchKind::Server => print_server(&args.arenas, steps),
        BenchKind::Capture => print_capture(&args.robot, &[(640, 480), (64, 64)], 60),
        BenchKind::Cameras => {
            print_cameras(&args.robot, args.arenas.iter().copied().max().unwrap_or(16), args.steps.unwrap_or(40))
        }
        BenchKind::Rl => print_rl(&args.robot, args.arenas.first().copied().unwrap_or(8), steps),
        BenchKind::Rtde => print_rtde(args.bundle.as_deref(), args.seconds, args.rt_priority),
        BenchKind::Live => print_live(&args.robot, args.rounds, args.every_step, args.steps),
    }
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum BenchKind {
    /// Control steps per second with N arenas, and the schedule's cost per step.
    Physics,
    /// PPO update time per 2048 samples; env steps/s through the channel bridge vs directly
    /// (with the first of --arenas).
    Rl,
    /// RobotServer step round trip, and steps/s with N robots (--arenas as robot counts).
    Server,
    /// Frames/s of off-screen capture at 640x480 and 64x64.
    Capture,
    /// Camera-sensor frames/s, all arenas (the largest of --arenas, 16 by default when given as
    /// `--arenas 16`) with a 64x64 camera each, rendered together; plain and with visual
    /// randomization.
    Cameras,
    /// RTDE at 500 Hz on loopback: report in → command out, p50, p99, p99.9 and max, the
    /// longest time between commands (an error if 20 ms or more: a UR stops then), missed
    /// cycles (--bundle DIR answers every report; --seconds S).
    Rtde,
    /// What a connected live viewer costs training: `train ROBOT` with and without a viewer
    /// written from Foxglove's protocol (--rounds each, medians).
    Live,
}
