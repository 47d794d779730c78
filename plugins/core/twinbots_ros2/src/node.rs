//! A ROS 2 node over DDS (ros2-client on RustDDS): the twin's side of a robot driver. It
//! publishes `/joint_states`, `/tf` and `/tf_static`, and takes commands where ros2_control's
//! controllers take them: the forward command controllers' `Float64MultiArray` and the joint
//! trajectory controller's `JointTrajectory`.

use ros2_client::dds::ContextOptions;
use ros2_client::qos::{Durability, History, WhenFull};
use ros2_client::{Context, MessageTypeName, Name, Node, NodeName, NodeOptions, Publisher, QosProfile, Subscription};

use crate::Ros2Error;
use crate::messages::{Float64MultiArray, JointState, JointTrajectory, Ros2Type, TFMessage};

/// The joint states a robot driver publishes (ros2_control's joint_state_broadcaster).
pub const JOINT_STATES_TOPIC: &str = "/joint_states";
/// The moving frames, each joint's child link in its parent's frame (robot_state_publisher).
pub const TF_TOPIC: &str = "/tf";
/// The frames fixed to each other, published once and kept for late joiners.
pub const TF_STATIC_TOPIC: &str = "/tf_static";
/// The joint trajectory controller's command topic.
pub const TRAJECTORY_TOPIC: &str = "/joint_trajectory_controller/joint_trajectory";

/// Which of a motor's command interfaces a forward command sets (ros2_control's names).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interface {
    /// rad or m.
    Position,
    /// rad/s or m/s.
    Velocity,
    /// N·m or N.
    Effort,
}

impl Interface {
    pub const ALL: [Interface; 3] = [Interface::Position, Interface::Velocity, Interface::Effort];

    pub fn name(self) -> &'static str {
        match self {
            Interface::Position => "position",
            Interface::Velocity => "velocity",
            Interface::Effort => "effort",
        }
    }

    /// The forward command controller's topic for this interface, as ros2_control's examples
    /// name the controllers (`forward_position_controller` and so on).
    pub fn topic(self) -> String {
        format!("/forward_{}_controller/commands", self.name())
    }
}

/// A command as it came off the wire (not yet checked against the robot).
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// One value per commanded joint, in the controller's joint order.
    Forward(Interface, Vec<f64>),
    Trajectory(JointTrajectory),
}

/// The DDS domain ROS 2 uses: `ROS_DOMAIN_ID` (0 when unset), as rcl reads it.
pub fn domain_from_env() -> Result<u16, Ros2Error> {
    match std::env::var("ROS_DOMAIN_ID") {
        Err(_) => Ok(0),
        Ok(s) if s.trim().is_empty() => Ok(0),
        Ok(s) => parse_domain(&s).map_err(|e| Ros2Error::Domain(format!("ROS_DOMAIN_ID: {e}"))),
    }
}

/// A domain id: 0 to 232, the range whose RTPS ports fit in 16 bits (ROS 2's documented limit).
pub fn parse_domain(s: &str) -> Result<u16, Ros2Error> {
    match s.trim().parse::<u16>() {
        Ok(d) if d <= 232 => Ok(d),
        _ => Err(Ros2Error::Domain(format!("'{s}' is not a DDS domain id: a whole number from 0 to 232"))),
    }
}

/// The node and its endpoints.
pub struct Ros2Node {
    joint_states: Publisher<JointState>,
    tf: Publisher<TFMessage>,
    tf_static: Publisher<TFMessage>,
    commands: CommandSubscriptions,
    // Dropped last: the endpoints belong to it.
    _node: Node,
}

/// The command topics a robot driver takes (the forward controllers' and the trajectory
/// controller's), subscribed: the driver obeys them, a monitor overhears them.
struct CommandSubscriptions {
    forward: Vec<(Interface, Subscription<Float64MultiArray>)>,
    trajectory: Subscription<JointTrajectory>,
}

impl CommandSubscriptions {
    fn open(node: &mut Node, qos: &QosProfile) -> Result<Self, Ros2Error> {
        let mut forward = Vec::new();
        for interface in Interface::ALL {
            let name = interface.topic();
            let t = topic::<Float64MultiArray>(node, &name, qos)?;
            forward.push((interface, node.create_subscription(&t, None).map_err(|e| create(&name, &e))?));
        }
        let t = topic::<JointTrajectory>(node, TRAJECTORY_TOPIC, qos)?;
        let trajectory = node.create_subscription(&t, None).map_err(|e| create(TRAJECTORY_TOPIC, &e))?;
        Ok(Self { forward, trajectory })
    }

    fn take(&self) -> Vec<Result<Command, Ros2Error>> {
        let mut out = Vec::new();
        for (interface, subscription) in &self.forward {
            drain(subscription, &interface.topic(), &mut out, |m| Command::Forward(*interface, m.data));
        }
        drain(&self.trajectory, TRAJECTORY_TOPIC, &mut out, Command::Trajectory);
        out
    }
}

fn create(what: &str, e: &dyn std::fmt::Debug) -> Ros2Error {
    Ros2Error::Create(format!("{what}: {e:?}"))
}

/// How far DDS discovery reaches: this machine only unless `ROS_AUTOMATIC_DISCOVERY_RANGE`
/// (ROS 2's own variable, Iron and later) says `SUBNET` or `SYSTEM_DEFAULT`. ROS 2 itself
/// defaults to the subnet; the twin does not, since any peer it discovers can command it.
pub fn localhost_only_from_env() -> Result<bool, Ros2Error> {
    match std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE") {
        Err(_) => Ok(true),
        Ok(s) => discovery_range(&s),
    }
}

/// A discovery range's value: whether it keeps discovery on this machine.
pub fn discovery_range(s: &str) -> Result<bool, Ros2Error> {
    match s.trim() {
        "" | "LOCALHOST" => Ok(true),
        "SUBNET" | "SYSTEM_DEFAULT" => Ok(false),
        other => Err(Ros2Error::Domain(format!(
            "ROS_AUTOMATIC_DISCOVERY_RANGE: '{other}' is not LOCALHOST (the default here), SUBNET or SYSTEM_DEFAULT"
        ))),
    }
}

/// A node on domain `domain` named `/<name>`; discovery on loopback only unless the
/// environment asks for more ([`localhost_only_from_env`]).
fn open_node(domain: u16, name: &str) -> Result<Node, Ros2Error> {
    let context = if localhost_only_from_env()? {
        use ros2_client::dds::rustdds::DomainParticipantBuilder;
        let participant = DomainParticipantBuilder::new(domain)
            .with_only_networks([std::net::IpAddr::V4(std::net::Ipv4Addr::LOCALHOST)])
            .build()
            .map_err(|e| create("the DDS participant", &e))?;
        Context::from_domain_participant(participant)
    } else {
        Context::with_options(ContextOptions::new().domain_id(domain))
    }
    .map_err(|e| create("the DDS participant", &e))?;
    let node_name = NodeName::new("/", name).map_err(|e| create(&format!("node name '{name}'"), &e))?;
    context.new_node(node_name, NodeOptions::new().enable_rosout(false)).map_err(|e| create("the node", &e))
}

/// What ROS 2 nodes use by default (rmw's "default" profile): reliable, volatile, last 10.
fn default_qos() -> QosProfile {
    QosProfile::publisher_default()
        .reliability_reliable(WhenFull::DEFAULT)
        .durability(Durability::Volatile)
        .history(History::KeepLast { depth: 10 })
}

fn topic<M: Ros2Type>(
    node: &Node,
    name: &str,
    qos: &QosProfile,
) -> Result<ros2_client::dds::rustdds::Topic, Ros2Error> {
    let name = Name::parse(name).map_err(|e| Ros2Error::Create(format!("topic {name}: {e:?}")))?;
    node.create_topic(&name, MessageTypeName::new(M::PACKAGE, M::NAME), qos)
        .map_err(|e| Ros2Error::Create(format!("topic {name:?}: {e:?}")))
}

impl Ros2Node {
    /// Joins DDS domain `domain` as node `/<name>` with the link's publishers and subscriptions.
    pub fn open(domain: u16, name: &str) -> Result<Self, Ros2Error> {
        let mut node = open_node(domain, name)?;
        let qos = default_qos();
        // As tf2's static broadcaster: kept for subscribers that join later.
        let latched = QosProfile::publisher_default()
            .reliability_reliable(WhenFull::DEFAULT)
            .durability(Durability::TransientLocal)
            .history(History::KeepLast { depth: 1 });
        let t = topic::<JointState>(&node, JOINT_STATES_TOPIC, &qos)?;
        let joint_states = node.create_publisher(&t, None).map_err(|e| create(JOINT_STATES_TOPIC, &e))?;
        let t = topic::<TFMessage>(&node, TF_TOPIC, &qos)?;
        let tf = node.create_publisher(&t, None).map_err(|e| create(TF_TOPIC, &e))?;
        let t = topic::<TFMessage>(&node, TF_STATIC_TOPIC, &latched)?;
        let tf_static = node.create_publisher(&t, None).map_err(|e| create(TF_STATIC_TOPIC, &e))?;
        let commands = CommandSubscriptions::open(&mut node, &qos)?;
        Ok(Self { joint_states, tf, tf_static, commands, _node: node })
    }

    pub fn publish_joint_states(&self, message: JointState) -> Result<(), Ros2Error> {
        self.joint_states.publish(message).map_err(|e| Ros2Error::Publish(format!("{JOINT_STATES_TOPIC}: {e:?}")))
    }

    pub fn publish_tf(&self, message: TFMessage) -> Result<(), Ros2Error> {
        self.tf.publish(message).map_err(|e| Ros2Error::Publish(format!("{TF_TOPIC}: {e:?}")))
    }

    pub fn publish_tf_static(&self, message: TFMessage) -> Result<(), Ros2Error> {
        self.tf_static.publish(message).map_err(|e| Ros2Error::Publish(format!("{TF_STATIC_TOPIC}: {e:?}")))
    }

    /// Every command that arrived since the last call, in arrival order per topic; a sample
    /// that did not decode is an error in its place (the rest are still taken).
    pub fn take_commands(&self) -> Vec<Result<Command, Ros2Error>> {
        self.commands.take()
    }
}

/// A node that only listens: to a robot driver's `/joint_states` and to the commands sent to
/// the driver (`twinbots monitor --ros2`). It publishes nothing, so it never moves the robot.
pub struct Ros2Listener {
    joint_states: Subscription<JointState>,
    commands: CommandSubscriptions,
    _node: Node,
}

impl Ros2Listener {
    pub fn open(domain: u16, name: &str) -> Result<Self, Ros2Error> {
        let mut node = open_node(domain, name)?;
        let qos = default_qos();
        let t = topic::<JointState>(&node, JOINT_STATES_TOPIC, &qos)?;
        let joint_states = node.create_subscription(&t, None).map_err(|e| create(JOINT_STATES_TOPIC, &e))?;
        let commands = CommandSubscriptions::open(&mut node, &qos)?;
        Ok(Self { joint_states, commands, _node: node })
    }

    /// Every joint state that arrived since the last call, in arrival order.
    pub fn take_joint_states(&self) -> Vec<Result<JointState, Ros2Error>> {
        let mut out = Vec::new();
        drain(&self.joint_states, JOINT_STATES_TOPIC, &mut out, |m| m);
        out
    }

    /// Every command sent to the robot since the last call (as [`Ros2Node::take_commands`]).
    pub fn take_commands(&self) -> Vec<Result<Command, Ros2Error>> {
        self.commands.take()
    }
}

/// At most this many samples per topic and call: a flood cannot stall the caller's cycle.
const MAX_TAKE: usize = 256;

fn drain<M: 'static + serde::de::DeserializeOwned, T>(
    subscription: &Subscription<M>,
    topic: &str,
    out: &mut Vec<Result<T, Ros2Error>>,
    wrap: impl Fn(M) -> T,
) {
    for _ in 0..MAX_TAKE {
        match subscription.take() {
            Ok(Some((message, _info))) => out.push(Ok(wrap(message))),
            Ok(None) => break,
            Err(e) => out.push(Err(Ros2Error::Take(format!("{topic}: {e:?}")))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn discovery_stays_on_this_machine_unless_asked() {
        assert!(discovery_range("LOCALHOST").unwrap());
        assert!(discovery_range("").unwrap());
        assert!(!discovery_range("SUBNET").unwrap());
        assert!(!discovery_range("SYSTEM_DEFAULT").unwrap());
        let e = discovery_range("everywhere").unwrap_err().to_string();
        assert!(e.contains("ROS_AUTOMATIC_DISCOVERY_RANGE") && e.contains("'everywhere'"), "{e}");
    }

    #[test]
    fn domain_ids_are_rcls() {
        assert_eq!(parse_domain("0").unwrap(), 0);
        assert_eq!(parse_domain(" 42 ").unwrap(), 42);
        assert_eq!(parse_domain("232").unwrap(), 232);
        for bad in ["233", "-1", "x", "1.5"] {
            let e = parse_domain(bad).unwrap_err().to_string();
            assert!(e.contains(bad) && e.contains("0 to 232"), "{e}");
        }
    }

    #[test]
    fn forward_topics_are_ros2_controls() {
        let topics: Vec<String> = Interface::ALL.iter().map(|i| i.topic()).collect();
        assert_eq!(
            topics,
            [
                "/forward_position_controller/commands",
                "/forward_velocity_controller/commands",
                "/forward_effort_controller/commands"
            ]
        );
    }
}
