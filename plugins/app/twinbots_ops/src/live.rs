//! A robot beside its twin in the live view (`monitor --live`, `deploy --live`): the robot as
//! a ghost of the UR5e posed at the joints its controller reports (frames `robot/<link>`,
//! tinted), its joint states as reported (`/robot/joint_states`), and what the command adds
//! in the same frame (the twin, the residuals), paced as the server is.

use std::sync::Arc;
use std::time::Duration;

use twinbots_live::{JsonSchema, LiveFrame, LiveServer, Place};
use twinbots_sysid::Stand;

use crate::deploy::arm::{Arm, Measured};
use crate::pacer::Pacer;
use crate::ur_sim::CYCLE;
use ur5e::kinematics::JOINTS;

/// What the ghost is drawn in: translucent orange, so the twin shows through.
pub const GHOST_TINT: [f32; 4] = [1.0, 0.55, 0.1, 0.45];

/// `/alarms`: an alarm as it is raised.
pub const ALARM: JsonSchema = JsonSchema {
    name: "twinbots/Alarm",
    schema: r#"{"title":"twinbots/Alarm","type":"object","properties":{"time":{"type":"number"},"kind":{"type":"string"},"message":{"type":"string"}}}"#,
};

/// A robot's reported joints, in the controller's order ([`JOINTS`]).
#[derive(Clone, Copy, Debug)]
pub struct RobotJoints<'a> {
    /// The controller's clock (s).
    pub time: f64,
    pub q: &'a [f64; 6],
    pub qd: &'a [f64; 6],
    pub effort: &'a [f64; 6],
}

/// The live view of a UR5e: the server and the ghost it poses.
pub struct RobotView {
    server: Arc<LiveServer>,
    ghost: Stand,
    period: f64,
}

impl RobotView {
    /// The ghost, standing at `q`.
    pub fn new(server: Arc<LiveServer>, q: &[f64; 6]) -> anyhow::Result<Self> {
        let (ghost, _) = crate::ur_sim::controller_stand(&Default::default(), q)?;
        server.advertise("/robot/joint_states", twinbots_live::JOINT_STATE)?;
        Ok(Self { server, ghost, period: ur5e::sim_settings().control_seconds() })
    }

    /// The server, for what is published unpaced (alarms, episodes) or advertised early.
    pub fn server(&self) -> &LiveServer {
        &self.server
    }

    /// When a frame is due: the robot's ghost at `robot.q` and its joint states, then what
    /// `more` adds to the frame.
    pub fn publish(&mut self, robot: RobotJoints, more: impl FnOnce(&mut LiveFrame)) {
        let Some(mut frame) = self.server.frame(robot.time, self.period) else { return };
        let at: Vec<f32> = robot.q.iter().map(|&v| v as f32).collect();
        self.ghost.place(0, &at);
        let (world, _) = self.ghost.scene(0);
        frame.world(world, Place::Ghost { name: "robot", tint: GHOST_TINT });
        let joints: Vec<(String, f64, f64, f64)> =
            (0..6).map(|j| (JOINTS[j].to_string(), robot.q[j], robot.qd[j], robot.effort[j])).collect();
        frame.joint_state("robot", &joints);
        more(&mut frame);
        frame.send();
    }
}

/// An arm whose every report also goes to the live view (`deploy --live`): the robot's ghost
/// and joint states, paced as the server is.
pub struct WatchedArm {
    arm: Box<dyn Arm>,
    view: RobotView,
    /// Holds each report back to the controller's 2 ms cycle of wall time ([`WatchedArm::real_time`]).
    pacer: Option<Pacer>,
}

impl WatchedArm {
    pub fn new(arm: Box<dyn Arm>, view: RobotView) -> Self {
        Self { arm, view, pacer: None }
    }

    /// Reads at most one report per controller cycle of wall time: a twin that stands in for
    /// the robot (`deploy --dry-run`), which would otherwise run its episodes faster than
    /// anyone can watch them.
    pub fn real_time(mut self) -> Self {
        self.pacer = Some(Pacer::new(Duration::from_secs_f64(CYCLE)));
        self
    }
}

impl Arm for WatchedArm {
    fn read(&mut self) -> anyhow::Result<Measured> {
        if let Some(pacer) = self.pacer.as_mut() {
            pacer.wait();
        }
        let m = self.arm.read()?;
        if m.q.iter().chain(&m.qd).chain(&m.effort).all(|v| v.is_finite()) {
            let robot = RobotJoints { time: m.time, q: &m.q, qd: &m.qd, effort: &m.effort };
            self.view.publish(robot, |_| {});
        }
        Ok(m)
    }
    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.arm.command(speeds)
    }
    fn stop(&mut self) -> anyhow::Result<()> {
        self.arm.stop()
    }
    fn describe(&self) -> String {
        self.arm.describe()
    }
}
