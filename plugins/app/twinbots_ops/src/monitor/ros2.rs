//! The monitor's ROS 2 source (`twinbots monitor --ros2`): a robot driver's `/joint_states`
//! and the velocity commands sent to its forward velocity controller, overheard on DDS. The
//! node only listens: it never commands the robot. The arm's joints are found by name (the
//! UR5e's, or those a robot file lists), in any order among others.

use std::time::{Duration, Instant};

use twinbots_ros2::node::TRAJECTORY_TOPIC;
use twinbots_ros2::{Command, Interface, JointState, Ros2Listener};

use super::Report;

/// How long the first joint state may take: DDS discovery takes a few seconds.
pub const FIRST_STATE_WAIT: Duration = Duration::from_secs(20);

/// The robot on ROS 2, as reports.
pub struct Ros2Source {
    listener: Ros2Listener,
    /// The arm's joints in the controller's order, as its joint states name them.
    joints: [String; 6],
    /// The joint speeds last commanded (rad/s, `joints`' order): zero until a command comes.
    command: [f64; 6],
    patience: Duration,
    /// States taken but not yet handed out.
    pending: std::collections::VecDeque<Report>,
    /// Notes taken but not yet handed out (handed out before the states).
    notes: std::collections::VecDeque<String>,
    /// Command kinds already reported as not followed (printed once each).
    unfollowed: Vec<String>,
    started: bool,
}

/// What the source says next.
pub enum Next {
    Report(Report),
    /// Nothing for the patience: the robot went.
    Silent(Duration),
    /// Something to print (a command the twin does not follow, one that did not decode).
    Note(String),
}

impl Ros2Source {
    /// Joins `domain` as node `/<name>`, to follow the six `joints` (controller order).
    pub fn open(domain: u16, name: &str, joints: &[String], patience: Duration) -> anyhow::Result<Self> {
        let joints: [String; 6] = joints.to_vec().try_into().map_err(|j: Vec<String>| {
            anyhow::anyhow!("the monitor follows six-joint arms; this one has {} ({})", j.len(), j.join(", "))
        })?;
        let listener = Ros2Listener::open(domain, name)?;
        Ok(Self {
            listener,
            joints,
            command: [0.0; 6],
            patience,
            pending: Default::default(),
            notes: Default::default(),
            unfollowed: Vec::new(),
            started: false,
        })
    }

    /// The next joint state with the command in force when it arrived, a note, or silence.
    /// (Not an iterator: it waits, and it fails.)
    #[allow(clippy::should_implement_trait)]
    pub fn next(&mut self) -> anyhow::Result<Next> {
        let wait = if self.started { self.patience } else { FIRST_STATE_WAIT };
        let since = Instant::now();
        loop {
            if let Some(note) = self.notes.pop_front() {
                return Ok(Next::Note(note));
            }
            if let Some(r) = self.pending.pop_front() {
                self.started = true;
                return Ok(Next::Report(r));
            }
            // Commands first, every one of them: a state taken in the same poll already felt
            // them (within a poll).
            for command in self.listener.take_commands() {
                if let Some(note) = self.take_command(command) {
                    self.notes.push_back(note);
                }
            }
            for state in self.listener.take_joint_states() {
                let r = report(&state?, &self.joints, self.command)?;
                self.pending.push_back(r);
            }
            if self.pending.is_empty() && self.notes.is_empty() {
                if since.elapsed() > wait {
                    return Ok(Next::Silent(wait));
                }
                std::thread::sleep(Duration::from_micros(250));
            }
        }
    }

    /// Keeps a velocity command; says once per kind that another is not followed.
    fn take_command(&mut self, command: Result<Command, twinbots_ros2::Ros2Error>) -> Option<String> {
        let (kind, topic) = match command {
            Err(e) => return Some(format!("{e}")),
            Ok(Command::Forward(Interface::Velocity, v)) if v.len() == 6 && v.iter().all(|x| x.is_finite()) => {
                self.command = std::array::from_fn(|j| v[j]);
                return None;
            }
            Ok(Command::Forward(Interface::Velocity, v)) => {
                return Some(format!(
                    "a velocity command of {v:?} is not 6 finite speeds ({}): the robot's driver refuses it, the twin keeps the last",
                    self.joints.join(", ")
                ));
            }
            Ok(Command::Forward(interface, _)) => (interface.name().to_string(), interface.topic()),
            Ok(Command::Trajectory(_)) => ("trajectory".to_string(), TRAJECTORY_TOPIC.to_string()),
        };
        if self.unfollowed.contains(&kind) {
            return None;
        }
        self.unfollowed.push(kind.clone());
        Some(format!(
            "a {kind} command was sent on {topic}: the twin follows velocity commands ({}) only, so it parts from the robot while those move it",
            Interface::Velocity.topic()
        ))
    }
}

/// A joint state as a report: the arm's `joints` by name (any order, others ignored), its
/// stamp as the time (the robot's clock).
pub fn report(state: &JointState, joints: &[String; 6], command: [f64; 6]) -> anyhow::Result<Report> {
    let n = state.name.len();
    anyhow::ensure!(
        state.position.len() == n && state.velocity.len() == n && state.effort.len() == n,
        "a joint state with {n} names, {} positions, {} velocities and {} efforts: the monitor needs all three for every joint",
        state.position.len(),
        state.velocity.len(),
        state.effort.len()
    );
    anyhow::ensure!(
        state.header.stamp.seconds() > 0.0,
        "an unstamped joint state: the monitor steps the twin by the robot's stamps"
    );
    let mut out = Report { time: state.header.stamp.seconds(), q: [0.0; 6], qd: [0.0; 6], command, effort: [0.0; 6] };
    for (j, joint) in joints.iter().enumerate() {
        let i = state
            .name
            .iter()
            .position(|n| n == joint)
            .ok_or_else(|| anyhow::anyhow!("a joint state without {joint} (it names {:?})", state.name))?;
        out.q[j] = state.position[i];
        out.qd[j] = state.velocity[i];
        out.effort[j] = state.effort[i];
    }
    anyhow::ensure!(
        out.q.iter().chain(&out.qd).chain(&out.effort).all(|v| v.is_finite()) && out.time.is_finite(),
        "a joint state that is not finite: {state:?}"
    );
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use twinbots_ros2::messages::{Header, Time};
    use ur5e::kinematics::JOINTS;

    fn ur5e() -> [String; 6] {
        JOINTS.map(String::from)
    }

    fn state(names: &[&str]) -> JointState {
        let n = names.len();
        JointState {
            header: Header { stamp: Time::from_seconds(12.5), frame_id: String::new() },
            name: names.iter().map(|s| s.to_string()).collect(),
            position: (0..n).map(|i| i as f64).collect(),
            velocity: vec![0.5; n],
            effort: vec![2.0; n],
        }
    }

    #[test]
    fn joint_states_become_reports_by_name_and_bad_ones_say_why() {
        // Any order, extra joints ignored.
        let mut names: Vec<&str> = JOINTS.iter().rev().copied().collect();
        names.push("gripper_joint");
        let r = report(&state(&names), &ur5e(), [0.1; 6]).unwrap();
        assert_eq!(r.time, 12.5);
        assert_eq!(r.q, [5.0, 4.0, 3.0, 2.0, 1.0, 0.0]);
        assert_eq!((r.qd[0], r.effort[0], r.command[0]), (0.5, 2.0, 0.1));

        let mut no_effort = state(&JOINTS);
        no_effort.effort.clear();
        assert!(
            report(&no_effort, &ur5e(), [0.0; 6])
                .unwrap_err()
                .to_string()
                .contains("6 names, 6 positions, 6 velocities and 0 efforts")
        );
        let err = report(&state(&JOINTS[..5]), &ur5e(), [0.0; 6]).unwrap_err().to_string();
        assert!(err.contains("without wrist_3_joint"), "{err}");
        let mut unstamped = state(&JOINTS);
        unstamped.header.stamp = Time::default();
        assert!(report(&unstamped, &ur5e(), [0.0; 6]).unwrap_err().to_string().contains("unstamped"));
        let mut nan = state(&JOINTS);
        nan.position[2] = f64::NAN;
        assert!(report(&nan, &ur5e(), [0.0; 6]).unwrap_err().to_string().contains("not finite"));
    }
}
