//! `twinbots record <robot> --truth TRUTH.toml --out LOG`: a stand-in for a real robot. The
//! twin runs with the hidden physics of a truth file (a calibration's format), through an
//! excitation program, with sensor noise, and logs only what a controller measures.

use std::path::PathBuf;

use twinbots_sysid::excitation::Excitation;
use twinbots_sysid::{Recording, Rig, SensorNoise, record};

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them).
    pub robot: String,
    /// The stand-in's true parameters (TOML, `[parameters]` of `name = value`; `twinbots
    /// identify <robot> --list-params` lists the names). Without it: the nominal twin.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// The excitation program: multisine or chirp.
    #[arg(long, default_value = "multisine")]
    pub excitation: String,
    #[arg(long, default_value_t = 20.0)]
    pub seconds: f64,
    /// Seeds the excitation and the sensor noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Encoder noise (rad or m, standard deviation).
    #[arg(long, default_value_t = SensorNoise::default().position)]
    pub position_noise: f64,
    /// Speed noise (rad/s or m/s).
    #[arg(long, default_value_t = SensorNoise::default().velocity)]
    pub velocity_noise: f64,
    /// Effort noise (N*m or N).
    #[arg(long, default_value_t = SensorNoise::default().effort)]
    pub effort_noise: f64,
    /// The log to write: `.mcap` or `.csv`.
    #[arg(long)]
    pub out: PathBuf,
}

/// `twinbots record`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let rig = Rig::of(&registry::find(&args.robot)?)?;
    // Before recording: a path no log can be written to.
    twinbots_log::Format::of(&args.out)?;
    let truth = rig.read_calibration(args.truth.as_deref())?;
    let noise = SensorNoise { position: args.position_noise, velocity: args.velocity_noise, effort: args.effort_noise };
    anyhow::ensure!(
        [noise.position, noise.velocity, noise.effort].iter().all(|n| n.is_finite() && *n >= 0.0),
        "noise levels must be finite and not negative"
    );
    let recording =
        Recording { excitation: Excitation::parse(&args.excitation)?, seconds: args.seconds, seed: args.seed, noise };
    let log = record(&rig, &truth, &recording)?;
    twinbots_log::write(&log, &args.out)?;
    println!(
        "{}: {:.1} s of {} excitation, {} joint states, {} commands -> {}",
        rig.robot,
        log.duration(),
        recording.excitation.name(),
        log.states.len(),
        log.commands.len(),
        args.out.display()
    );
    Ok(())
}
