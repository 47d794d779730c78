//! `twinbots ros2 <robot>`: the twin as a ROS 2 robot. The robot stands on its test rig
//! (sysid's [`Stand`]) and runs in real time; it publishes what a ros2_control driver does
//! (`/joint_states`, `/tf`, `/tf_static`) and obeys the forward command controllers'
//! `Float64MultiArray` and the joint trajectory controller's `JointTrajectory` (docs/ros2.md).

pub mod trajectory;

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use twinbots_ros2::messages::{Header, Quaternion, Time, Transform, TransformStamped, Vector3};
use twinbots_ros2::{Command, Interface, JointState, Ros2Node, TFMessage};
use twinbots_sim::MotorCommand;
use twinbots_sim::rapier::prelude::Pose;
use twinbots_sysid::{Rig, Stand};

use self::trajectory::Following;
use twinbots_run::registry::RobotEntry;

/// The frame the robot's root link stands in.
pub const WORLD_FRAME: &str = "world";

/// The twin on its stand, and what it is told to do.
pub struct Ros2Twin {
    rig: Rig,
    stand: Stand,
    /// Twin time (s) since it started.
    time: f64,
    /// The joints that take commands (have a motor): name and index into the rig's joints, in
    /// the rig's order, the order of a forward command's values.
    commandable: Vec<(String, usize)>,
    following: Option<Following>,
}

/// What the robot on the stand is, beyond its registered twin: what a stand-in robot for a
/// monitor or a bridge test differs by.
#[derive(Clone, Debug, Default)]
pub struct TwinOptions {
    /// The physics step (s); default: the rig's.
    pub step: Option<f64>,
    /// Parameters over the nominal ones (a calibration file's, as `ur-sim --truth`).
    pub truth: twinbots_sim::Parameters,
    /// A load the registered twin does not know.
    pub payload: Option<Payload>,
}

/// A point mass on a link.
#[derive(Clone, Debug)]
pub struct Payload {
    pub mass: f32,
    /// The link (default: the robot's flange, [`flange_link`]).
    pub link: Option<String>,
    /// Where on the link, in its frame (m).
    pub at: bevy::math::Vec3,
}

/// The robot's flange: the first link fixed to its last moving link (a UR's `tool0`, where
/// `ur-sim --payload` hangs its load), else that moving link itself.
pub fn flange_link(rig: &Rig) -> anyhow::Result<String> {
    let model = &rig.model;
    let last = model
        .joints
        .iter()
        .rev()
        .find(|j| j.kind.is_movable())
        .ok_or_else(|| anyhow::anyhow!("robot '{}' has no moving link to carry a payload", rig.robot))?;
    let flange =
        model.joints.iter().find(|j| j.parent == last.child && !j.kind.is_movable()).map_or(last.child, |j| j.child);
    Ok(model.links[flange].name.clone())
}

/// A command the twin took: how many of its values were clipped into the joints' limits.
pub type Clipped = usize;

impl Ros2Twin {
    /// The robot on its rig (its parameters the nominal ones with `options.truth` over them),
    /// where the rig starts it, its drives holding there (a robot at rest with its brakes
    /// released).
    pub fn new(robot: &RobotEntry, options: &TwinOptions) -> anyhow::Result<Self> {
        let mut rig = Rig::of(robot)?;
        if let Some(step) = options.step {
            anyhow::ensure!(step > 0.0 && step <= 0.1, "a physics step of {step} s is not one (0 to 0.1 s)");
            rig.settings.dt = step as f32;
        }
        let params = rig.parameters(&options.truth)?;
        let mut stand = Stand::new(&rig, &[], std::slice::from_ref(&params));
        if let Some(payload) = &options.payload {
            anyhow::ensure!(
                payload.mass.is_finite() && payload.mass > 0.0,
                "a payload of {} kg is not one",
                payload.mass
            );
            let link = match &payload.link {
                Some(l) => l.clone(),
                None => flange_link(&rig)?,
            };
            stand.add_payload(0, &link, payload.mass, payload.at)?;
        }
        let commandable =
            rig.joints.iter().enumerate().filter(|&(i, _)| rig.actuated[i]).map(|(i, n)| (n.clone(), i)).collect();
        let mut twin = Self { rig, stand, time: 0.0, commandable, following: None };
        let now = twin.positions();
        let hold: Vec<f64> = twin.commandable.iter().map(|&(_, i)| now[i]).collect();
        twin.apply(Command::Forward(Interface::Position, hold), 0.0).map_err(anyhow::Error::msg)?;
        Ok(twin)
    }

    pub fn robot(&self) -> &'static str {
        self.rig.robot
    }

    /// The physics step (s): the twin's cycle.
    pub fn dt(&self) -> f64 {
        self.rig.dt()
    }

    pub fn time(&self) -> f64 {
        self.time
    }

    /// The joints a forward command sets, in its values' order.
    pub fn commandable(&self) -> impl Iterator<Item = &str> {
        self.commandable.iter().map(|(n, _)| n.as_str())
    }

    /// Every joint's position now, in the rig's order.
    fn positions(&self) -> Vec<f64> {
        self.stand.reading(0).position.into_iter().map(f64::from).collect()
    }

    /// Joint `joint`'s (index into the rig's joints) limits: position range (none for a
    /// continuous joint), speed and effort.
    fn limits(&self, joint: usize) -> &twinbots_sim::urdf::JointLimits {
        &self.rig.model.joint(&self.rig.joints[joint]).expect("the rig's joints are the model's").limits
    }

    /// Takes a command; `wall_now` is the wall clock (s since the epoch), against which a
    /// trajectory's stamp is read. An error says what is wrong with it and changes nothing.
    pub fn apply(&mut self, command: Command, wall_now: f64) -> Result<Clipped, String> {
        match command {
            Command::Forward(interface, values) => self.forward(interface, &values),
            Command::Trajectory(message) => {
                let stamp = message.header.stamp;
                let delay = if stamp == Time::default() { 0.0 } else { stamp.seconds() - wall_now };
                let current = self.positions();
                let range = |j| self.limits(j).position.map(|r| r.map(f64::from));
                let (following, clipped) =
                    Following::new(&message, &self.commandable, &current, range, self.time, delay)?;
                self.following = Some(following);
                Ok(clipped)
            }
        }
    }

    /// A forward command: one value per commandable joint, clipped into its limits (as
    /// ros2_control's joint limiters saturate), set as each motor's command until replaced.
    fn forward(&mut self, interface: Interface, values: &[f64]) -> Result<Clipped, String> {
        if values.len() != self.commandable.len() {
            let names: Vec<&str> = self.commandable().collect();
            return Err(format!("{} values for {} joints ({})", values.len(), names.len(), names.join(", ")));
        }
        if let Some(v) = values.iter().find(|v| !v.is_finite()) {
            return Err(format!("{} command {v} is not a number", interface.name()));
        }
        // Checked: from here on the command is taken whole.
        self.following = None;
        let mut clipped = 0;
        for (&(_, joint), &v) in self.commandable.iter().zip(values) {
            let limits = self.limits(joint);
            let bound = |b: f32| if b > 0.0 { v.clamp(-b as f64, b as f64) } else { v };
            let inside = match interface {
                Interface::Position => limits.position.map_or(v, |[lo, hi]| v.clamp(lo as f64, hi as f64)),
                Interface::Velocity => bound(limits.velocity),
                Interface::Effort => bound(limits.effort),
            };
            clipped += usize::from(inside != v);
            let value = inside as f32;
            let command = match interface {
                Interface::Position => MotorCommand::Position(value),
                Interface::Velocity => MotorCommand::Velocity(value),
                Interface::Effort => MotorCommand::Torque(value),
            };
            self.stand.command(0, joint, command);
        }
        Ok(clipped)
    }

    /// One physics step, the trajectory being followed setting its targets first.
    pub fn step(&mut self) {
        if let Some(f) = &self.following {
            for (&joint, q) in f.joints.iter().zip(f.target(self.time)) {
                self.stand.command(0, joint, MotorCommand::Position(q as f32));
            }
        }
        self.stand.step();
        self.time += self.dt();
    }

    /// Every movable joint's state, as ros2_control's joint_state_broadcaster publishes it.
    pub fn joint_state(&self, stamp: Time) -> JointState {
        let r = self.stand.reading(0);
        let wide = |v: Vec<f32>| v.into_iter().map(f64::from).collect();
        JointState {
            header: Header { stamp, frame_id: String::new() },
            name: self.rig.joints.clone(),
            position: wide(r.position),
            velocity: wide(r.velocity),
            effort: wide(r.effort),
        }
    }

    /// The moving frames: each movable joint's child link in its parent's at the joint's
    /// position (robot_state_publisher's forward kinematics), and the root link in
    /// [`WORLD_FRAME`] where the physics has it.
    pub fn frames(&self, stamp: Time) -> TFMessage {
        let positions = self.stand.reading(0).position;
        let model = &self.rig.model;
        let mut transforms: Vec<TransformStamped> = self
            .rig
            .joints
            .iter()
            .zip(positions)
            .filter_map(|(name, q)| {
                model
                    .joint(name)
                    .map(|j| frame(stamp, &model.links[j.parent].name, &model.links[j.child].name, &j.child_pose(q)))
            })
            .collect();
        let root = &model.links[model.root].name;
        if root != WORLD_FRAME
            && let Some(pose) = self.stand.link_pose(0, root)
        {
            transforms.push(frame(stamp, WORLD_FRAME, root, &pose));
        }
        TFMessage { transforms }
    }

    /// The frames fixed to each other: each fixed joint's child link in its parent's.
    pub fn fixed_frames(&self, stamp: Time) -> TFMessage {
        let model = &self.rig.model;
        let fixed = model.joints.iter().filter(|j| !j.kind.is_movable());
        TFMessage {
            transforms: fixed
                .map(|j| frame(stamp, &model.links[j.parent].name, &model.links[j.child].name, &j.child_pose(0.0)))
                .collect(),
        }
    }
}

fn frame(stamp: Time, parent: &str, child: &str, pose: &Pose) -> TransformStamped {
    let (t, r) = (pose.translation, pose.rotation);
    TransformStamped {
        header: Header { stamp, frame_id: parent.to_string() },
        child_frame_id: child.to_string(),
        transform: Transform {
            translation: Vector3 { x: t.x as f64, y: t.y as f64, z: t.z as f64 },
            rotation: Quaternion { x: r.x as f64, y: r.y as f64, z: r.z as f64, w: r.w as f64 },
        },
    }
}

/// How `serve` runs.
#[derive(Clone, Debug)]
pub struct ServeOptions {
    /// Stop after this many seconds of twin time (default: until stopped).
    pub seconds: Option<f64>,
    /// How often joint states and frames go out (Hz).
    pub rate: f64,
    /// Seconds between progress lines.
    pub report: f64,
}

/// What a run did.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ServeSummary {
    pub seconds: f64,
    pub published: u64,
    pub commands: u64,
    pub rejected: u64,
    pub clipped: u64,
    pub missed_cycles: u64,
}

/// Runs `twin` in real time on `node` until `stop` is set or the time is up: commands taken
/// every physics step, states published at `options.rate`, a line of progress every
/// `options.report` seconds and one per refused command.
pub fn serve(
    twin: &mut Ros2Twin,
    node: &Ros2Node,
    options: &ServeOptions,
    stop: &AtomicBool,
) -> anyhow::Result<ServeSummary> {
    let dt = twin.dt();
    anyhow::ensure!(options.rate > 0.0 && options.rate.is_finite(), "--rate must be positive, not {}", options.rate);
    let period = 1.0 / options.rate;
    let mut next_publish = 0.0;
    node.publish_tf_static(twin.fixed_frames(Time::now()))?;
    let mut pacer = crate::pacer::Pacer::new(Duration::from_secs_f64(dt));
    // Stamps are the robot's clock, as a driver stamps its controller's states: the wall clock
    // when the twin started plus the twin's time, so states are exactly one step apart for
    // whoever steps a twin beside it (`monitor --ros2`), and keep to the wall clock as the
    // twin keeps to real time.
    let epoch = Time::now().seconds() - twin.time();
    let mut out = ServeSummary::default();
    let mut last_report = 0.0;
    while !stop.load(Ordering::SeqCst) && options.seconds.is_none_or(|s| twin.time() < s) {
        for command in node.take_commands() {
            out.commands += 1;
            match command.map_err(|e| e.to_string()).and_then(|c| twin.apply(c, Time::now().seconds())) {
                Ok(clipped) => out.clipped += clipped as u64,
                Err(e) => {
                    out.rejected += 1;
                    eprintln!("[{:8.3} s] command refused: {e}", twin.time());
                }
            }
        }
        // At the rate on average, to the physics step: a step publishes when its time has come.
        if twin.time() + 1e-9 >= next_publish {
            next_publish += period;
            let stamp = Time::from_seconds(epoch + twin.time());
            node.publish_joint_states(twin.joint_state(stamp))?;
            node.publish_tf(twin.frames(stamp))?;
            out.published += 1;
        }
        twin.step();
        if twin.time() - last_report >= options.report {
            last_report = twin.time();
            println!(
                "[{:8.3} s] {} states published, {} commands ({} refused, {} values clipped), {} missed cycle(s)",
                twin.time(),
                out.published,
                out.commands,
                out.rejected,
                out.clipped,
                pacer.missed
            );
        }
        pacer.wait();
    }
    out.seconds = twin.time();
    out.missed_cycles = pacer.missed;
    Ok(out)
}
