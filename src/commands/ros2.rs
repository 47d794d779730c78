//! `twinbots ros2 <robot> [--domain N] [--rate HZ] [--seconds S] [--truth FILE] [--payload KG]`:
//! the twin as a ROS 2 robot on DDS, no ROS install needed (docs/ros2.md).

use std::sync::atomic::AtomicBool;

use std::path::PathBuf;

use twinbots_ops::ros2::{Payload, Ros2Twin, ServeOptions, TwinOptions, serve};
use twinbots_ros2::node::{TRAJECTORY_TOPIC, domain_from_env, parse_domain};
use twinbots_ros2::{Interface, Ros2Node};
use twinbots_run::settings::CalibrationSetting;

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// The robot (`twinbots robots` lists them).
    pub robot: String,
    /// The DDS domain (default: ROS_DOMAIN_ID, else 0).
    #[arg(long)]
    pub domain: Option<String>,
    /// How often joint states and frames are published (Hz).
    #[arg(long, default_value_t = 100.0)]
    pub rate: f64,
    /// Stop after this many seconds (default: until killed).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// The node's name (default: twinbots_<robot>; a robot file: its file name's stem).
    #[arg(long)]
    pub node: Option<String>,
    /// The physics step (ms); default: the robot's, the UR5e's controller cycle (2 ms, as ur-sim).
    #[arg(long)]
    pub step_ms: Option<f64>,
    /// Run the robot on these parameters (a calibration file, as `ur-sim --truth`): a stand-in
    /// for a robot that differs from its twin.
    #[arg(long)]
    pub truth: Option<PathBuf>,
    /// A payload (kg) the twin does not know, on `--payload-link` 5 cm out along its z axis.
    #[arg(long)]
    pub payload: Option<f32>,
    /// The link that carries `--payload` (default: the flange, a UR's tool0).
    #[arg(long, requires = "payload")]
    pub payload_link: Option<String>,
}

/// `twinbots ros2`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let entry = registry::find(&args.robot)?;
    if let Some(s) = args.seconds {
        anyhow::ensure!(s > 0.0 && s.is_finite(), "--seconds must be positive, not {s}");
    }
    let domain = match &args.domain {
        Some(d) => parse_domain(d)?,
        None => domain_from_env()?,
    };
    let truth =
        CalibrationSetting::read_optional(&entry, args.truth.as_deref())?.map(|c| c.parameters()).unwrap_or_default();
    let step = match args.step_ms {
        Some(ms) => Some(ms / 1e3),
        None => (entry.name == "ur5e").then_some(twinbots_ops::ur_sim::CYCLE),
    };
    let payload = args.payload.map(|mass| Payload {
        mass,
        link: args.payload_link.clone(),
        at: bevy::math::Vec3::new(0.0, 0.0, 0.05),
    });
    let mut twin = Ros2Twin::new(&entry, &TwinOptions { step, truth, payload })?;
    // A robot file's name is its path: the node takes the file's stem, in a ROS name's characters.
    let robot = std::path::Path::new(twin.robot()).file_stem().map_or(twin.robot().into(), |s| s.to_string_lossy());
    let robot: String = robot.chars().map(|c| if c.is_ascii_alphanumeric() { c } else { '_' }).collect();
    let name = args.node.unwrap_or_else(|| format!("twinbots_{robot}"));
    let node = Ros2Node::open(domain, &name)?;
    let joints: Vec<&str> = twin.commandable().collect();
    println!(
        "ros2: {} twin as node /{name} on DDS domain {domain}, {:.0} Hz physics, states at {} Hz",
        twin.robot(),
        1.0 / twin.dt(),
        args.rate
    );
    println!("ros2: publishing /joint_states, /tf, /tf_static; commands for [{}] on", joints.join(", "));
    for interface in Interface::ALL {
        println!("ros2:   {} (std_msgs/msg/Float64MultiArray, {})", interface.topic(), interface.name());
    }
    println!("ros2:   {TRAJECTORY_TOPIC} (trajectory_msgs/msg/JointTrajectory)");
    let options = ServeOptions { seconds: args.seconds, rate: args.rate, report: 5.0 };
    let s = serve(&mut twin, &node, &options, &AtomicBool::new(false))?;
    println!(
        "ros2: {:.1} s, {} states published, {} commands ({} refused, {} values clipped), {} missed cycle(s)",
        s.seconds, s.published, s.commands, s.rejected, s.clipped, s.missed_cycles
    );
    Ok(())
}
