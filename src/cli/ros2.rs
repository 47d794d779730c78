//! `twinbots ros2 <robot> [--domain N] [--rate HZ] [--seconds S]`: the twin as a ROS 2 robot on
//! DDS, no ROS install needed (docs/ros2.md).

use std::sync::atomic::AtomicBool;

use twinbots::ros2::{Ros2Twin, ServeOptions, serve};
use twinbots_ros2::node::{TRAJECTORY_TOPIC, domain_from_env, parse_domain};
use twinbots_ros2::{Interface, Ros2Node};

use crate::registry;

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
    /// The node's name (default: twinbots_<robot>).
    #[arg(long)]
    pub node: Option<String>,
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
    let mut twin = Ros2Twin::new(&entry)?;
    let name = args.node.unwrap_or_else(|| format!("twinbots_{}", twin.robot()));
    let node = Ros2Node::open(domain, &name)?;
    let joints: Vec<&str> = twin.commandable().collect();
    println!("ros2: {} twin as node /{name} on DDS domain {domain}, {:.0} Hz physics, states at {} Hz", twin.robot(), 1.0 / twin.dt(), args.rate);
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
