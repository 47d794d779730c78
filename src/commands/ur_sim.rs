//! `twinbots ur-sim [--robot ur5e|FILE] [--listen ADDR] [--truth FILE]`: a UR controller
//! stand-in serving RTDE, backed by the UR5e's twin or a robot file's six-joint arm's
//! (docs/rtde.md).

use std::path::PathBuf;
use std::sync::atomic::AtomicBool;

use twinbots_ops::linked_arm::LinkedArm;
use twinbots_ops::ur_sim::{UrSim, UrSimOptions, controller_info};
use twinbots_rtde::server::RtdeServer;
use twinbots_sysid::{Rig, SensorNoise};

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The arm it serves: the built-in `ur5e`, or a robot file (`*.toml`) of a six-joint arm
    /// (a UR10 from its description, say).
    #[arg(long, default_value = "ur5e")]
    pub robot: String,
    /// Where to serve RTDE.
    #[arg(long, default_value = "127.0.0.1:30004")]
    pub listen: String,
    /// The robot's true parameters (a calibration file's format, as `record --truth`); its
    /// `command_delay` is the stand-in's latency. With it, the encoders read with noise.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// Stop after this many seconds (default: until killed).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// The control program's watchdog (s): the arm stops when the client's counter stands
    /// still this long while moving.
    #[arg(long, default_value_t = 0.1)]
    pub watchdog: f64,
    /// Encoder noise (rad, standard deviation); default: none, or a UR's with --truth.
    #[arg(long)]
    pub position_noise: Option<f64>,
    /// Speed noise (rad/s); default as --position-noise.
    #[arg(long)]
    pub velocity_noise: Option<f64>,
    /// Seeds the sensor noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// A payload on the flange (kg, 5 cm out along the tool axis) that the twin's model does
    /// not know: what `monitor` should notice.
    #[arg(long)]
    pub payload: Option<f32>,
    /// Run the controller's loop on SCHED_FIFO at this priority (1-99; root or CAP_SYS_NICE).
    #[arg(long)]
    pub rt_priority: Option<i32>,
    /// Listen beyond loopback: RTDE has no authentication, and whoever reaches the port moves
    /// the (simulated) arm through the program's registers. Prints a warning.
    #[arg(long)]
    pub insecure: bool,
}

/// `twinbots ur-sim`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    // The built-in UR5e or a robot file's six-joint arm; any other, an error saying so.
    let arm = LinkedArm::of(&args.robot)?.served_arm()?;
    let rig = Rig::of(&arm.robot)?;
    let truth = rig.read_calibration(args.truth.as_deref())?;
    let ur = SensorNoise::default();
    let default = |v: f64| if args.truth.is_some() { v } else { 0.0 };
    let noise = SensorNoise {
        position: args.position_noise.unwrap_or(default(ur.position)),
        velocity: args.velocity_noise.unwrap_or(default(ur.velocity)),
        effort: default(ur.effort),
    };
    anyhow::ensure!(
        [noise.position, noise.velocity].iter().all(|n| n.is_finite() && *n >= 0.0),
        "noise levels must be finite and not negative"
    );
    if let Some(s) = args.seconds {
        anyhow::ensure!(s > 0.0 && s.is_finite(), "--seconds must be positive, not {s}");
    }
    check_exposure(&args.listen, args.insecure)?;
    let name = arm.robot.name;
    let options = UrSimOptions { arm, truth, noise, seed: args.seed, watchdog: args.watchdog, payload: args.payload };
    let mut sim = UrSim::new(&options)?;
    let server = RtdeServer::bind(&args.listen, controller_info())?;
    println!(
        "ur-sim: {name} twin ({}) serving RTDE on {} at 500 Hz",
        args.truth.as_ref().map_or("nominal".to_string(), |p| format!("truth {}", p.display())),
        server.local_addr()
    );
    if let Some(p) = args.rt_priority {
        twinbots_ops::realtime::set_rt_priority(p)?;
    }
    let stop = AtomicBool::new(false);
    let missed = sim.serve(&server, args.seconds, &stop, 5.0);
    println!("ur-sim: {:.1} s served, {missed} missed cycle(s)", sim.time());
    Ok(())
}

/// Beyond loopback only with `--insecure`: RTDE takes `speedj` through registers from anyone.
fn check_exposure(listen: &str, insecure: bool) -> anyhow::Result<()> {
    use std::net::ToSocketAddrs;
    let addresses: Vec<std::net::SocketAddr> =
        listen.to_socket_addrs().map_err(|e| anyhow::anyhow!("--listen {listen}: {e}"))?.collect();
    if addresses.iter().all(|a| a.ip().is_loopback()) {
        return Ok(());
    }
    anyhow::ensure!(
        insecure,
        "--listen {listen} reaches beyond this machine, and RTDE has no authentication: whoever reaches the port commands the arm; give --insecure on a trusted network"
    );
    eprintln!("warning: --insecure: serving RTDE on {listen}; anyone who reaches it can move the arm");
    Ok(())
}
