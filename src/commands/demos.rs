//! `twinbots demos ROBOT --controller classic|RUN|FILE.onnx --episodes N --out DIR`:
//! demonstrations of a controller on the twin, written as a LeRobot dataset (docs/demos.md).

use std::path::PathBuf;

use twinbots_study::demos::{DemoOptions, record_demos};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// A built-in robot or a robot file (`*.toml`).
    pub robot: String,
    /// Who drives: `classic` (the task's scripted or classical controller), a run directory of
    /// `twinbots train`, or an exported `.onnx` policy.
    #[arg(long, default_value = "classic")]
    pub controller: String,
    /// The task (see `twinbots robots`); default: the robot's main task, or a run's own.
    #[arg(long)]
    pub task: Option<String>,
    #[arg(long, default_value_t = 100)]
    pub episodes: usize,
    /// Where the dataset goes (a new directory).
    #[arg(long)]
    pub out: PathBuf,
    /// Episode j starts from seed + j.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Episodes run side by side (the dataset does not depend on it).
    #[arg(long, default_value_t = 8)]
    pub arenas: usize,
    /// Keep only the episodes that met the task's goal, running further seeds until there are
    /// `--episodes` of them.
    #[arg(long)]
    pub successes_only: bool,
    /// Also record each frame as these cameras of the robot's framing see it (side, front,
    /// iso, top; comma-separated): image features `observation.images.<camera>`, rendered
    /// off-screen (a Vulkan adapter; lavapipe will do).
    #[arg(long, value_delimiter = ',')]
    pub cameras: Vec<String>,
    /// The camera images' size (WxH).
    #[arg(long, default_value = "96x96", requires = "cameras")]
    pub size: String,
}

/// `twinbots demos`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let entry = registry::find(&args.robot)?;
    let options = DemoOptions {
        controller: args.controller,
        task: args.task,
        episodes: args.episodes,
        arenas: args.arenas,
        seed: args.seed,
        successes_only: args.successes_only,
        cameras: args.cameras,
        image_size: twinbots_render::recorder::parse_size(&args.size)?,
    };
    let mut report = |kept: usize, run: usize, rate: f64| {
        eprintln!("{kept}/{} episodes ({run} run), {rate:.0} frames/s", options.episodes);
    };
    let summary = record_demos(&entry, &options, &args.out, &mut report)?;
    println!(
        "{}: {} episodes, {} frames ({} of {} episodes run met the goal), {:.0} frames/s; a LeRobot dataset at {}",
        entry.name,
        summary.episodes,
        summary.frames,
        summary.successes,
        summary.episodes_run,
        summary.frames_per_second,
        args.out.display()
    );
    Ok(())
}
