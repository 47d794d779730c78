//! A robot beside its twin in the live view (`monitor --live`, `deploy --live`): the robot as
//! a ghost of its twin posed at the joints it reports (frames `robot/<link>`, tinted), its joint
//! states as reported (`/robot/joint_states`), and what the command adds in the same frame (the
//! twin, the residuals), paced as the server is.

use std::sync::Arc;
use std::time::Duration;

use bevy::ecs::system::SystemState;
use bevy::prelude::*;
use twinbots_api::DesignPattern;
use twinbots_live::{JsonSchema, LiveFrame, LiveServer, Place};
use twinbots_run::registry::RobotEntry;
use twinbots_sim::{Arena, InArena, Joint, Supervisor};

use crate::deploy::arm::{Arm, Measured};
use crate::pacer::Pacer;
use crate::ur_sim::CYCLE;

/// What the ghost is drawn in: translucent orange, so the twin shows through.
pub const GHOST_TINT: [f32; 4] = [1.0, 0.55, 0.1, 0.45];

/// `/alarms`: an alarm as it is raised.
pub const ALARM: JsonSchema = JsonSchema {
    name: "twinbots/Alarm",
    schema: r#"{"title":"twinbots/Alarm","type":"object","properties":{"time":{"type":"number"},"kind":{"type":"string"},"message":{"type":"string"}}}"#,
};

/// A robot's reported joints, in the order of the view's joint names.
#[derive(Clone, Copy, Debug)]
pub struct RobotJoints<'a> {
    /// The robot's clock (s).
    pub time: f64,
    pub q: &'a [f64],
    pub qd: &'a [f64],
    pub effort: &'a [f64],
}

/// A robot's twin that is only posed, never stepped: the ghost of the robot in the view.
pub struct Ghost {
    app: App,
    /// The joints the ghost is posed by, in the order their positions come.
    joints: Vec<Entity>,
}

impl Ghost {
    /// `entry`'s twin (one arena, its cell), posed by `joints` (names of its joints).
    pub fn of(entry: &RobotEntry, joints: &[String]) -> anyhow::Result<Self> {
        let mut app = entry.app(None, 1, 0, DesignPattern::Supervised)?;
        // Start-up only: the world as built.
        app.update();
        let world = app.world_mut();
        let arena = world.query::<(Entity, &Arena)>().iter(world).map(|(e, _)| e).next();
        let named: Vec<(Entity, String)> = world
            .query::<(Entity, &Joint, &InArena)>()
            .iter(world)
            .filter(|(_, _, a)| Some(a.0) == arena)
            .map(|(e, j, _)| (e, j.name.clone()))
            .collect();
        let joints =
            joints
                .iter()
                .map(|name| {
                    named.iter().find(|(_, n)| n == name).map(|(e, _)| *e).ok_or_else(|| {
                        anyhow::anyhow!("{}'s twin has no joint '{name}' to pose its ghost by", entry.name)
                    })
                })
                .collect::<anyhow::Result<_>>()?;
        Ok(Self { app, joints })
    }

    /// Puts the ghost's joints at `q` (rad or m).
    pub fn place(&mut self, q: &[f64]) {
        let world = self.app.world_mut();
        let mut state: SystemState<Supervisor> = SystemState::new(world);
        let Ok(mut supervisor) = state.get_mut(world) else { return };
        for (&joint, &position) in self.joints.iter().zip(q) {
            supervisor.set_joint_position(joint, position as f32);
        }
        state.apply(world);
    }

    pub fn world_mut(&mut self) -> &mut World {
        self.app.world_mut()
    }
}

/// The live view of a robot: the server, the ghost it poses and the names of its joints.
pub struct RobotView {
    server: Arc<LiveServer>,
    ghost: Ghost,
    joints: Vec<String>,
    period: f64,
}

impl RobotView {
    /// `entry`'s ghost, posed by `joints`, paced at `entry`'s control period.
    pub fn new(server: Arc<LiveServer>, entry: &RobotEntry, joints: &[String]) -> anyhow::Result<Self> {
        let ghost = Ghost::of(entry, joints)?;
        server.advertise("/robot/joint_states", twinbots_live::JOINT_STATE)?;
        Ok(Self { server, ghost, joints: joints.to_vec(), period: entry.control_period_s() })
    }

    /// The server, for what is published unpaced (alarms, episodes) or advertised early.
    pub fn server(&self) -> &LiveServer {
        &self.server
    }

    /// When a frame is due: the robot's ghost at `robot.q` and its joint states, then what
    /// `more` adds to the frame.
    pub fn publish(&mut self, robot: RobotJoints, more: impl FnOnce(&mut LiveFrame)) {
        let Some(mut frame) = self.server.frame(robot.time, self.period) else { return };
        self.ghost.place(robot.q);
        frame.world(self.ghost.world_mut(), Place::Ghost { name: "robot", tint: GHOST_TINT });
        let joints: Vec<(String, f64, f64, f64)> = (0..self.joints.len().min(robot.q.len()))
            .map(|j| {
                let at = |v: &[f64]| v.get(j).copied().unwrap_or(f64::NAN);
                (self.joints[j].clone(), robot.q[j], at(robot.qd), at(robot.effort))
            })
            .collect();
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
