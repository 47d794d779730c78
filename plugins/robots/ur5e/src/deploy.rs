//! The reach policy on a real UR5e (or its stand-in): the controller's side of an episode
//! without the twin's app — the task's own observation terms over the arm as RTDE reports it,
//! targets from the task's own sampler, actions as joint speeds — and the **shadow**, the
//! twin's check of every command before it reaches the robot.

use bevy::math::{DMat4, DVec3, Vec3};
use rand::Rng;
use twinbots_task::TaskTerms;

use crate::arm::{self, ACTION_DIM, ActionHistory, ArmState};
use crate::kinematics::{self, JOINT_RANGES, JOINTS, MAX_JOINT_SPEED, TOOL_LENGTH};
use crate::state::CellState;

/// The robot's joints as a controller reports them, base to wrist 3, with the sign that turns
/// a reported angle into the twin's: the twin is built on UR's own DH table, so every sign is +1.
pub const JOINT_SIGNS: [f64; 6] = [1.0; 6];

/// The joints' order and names on the robot (RTDE's `actual_q`).
pub const ROBOT_JOINTS: [&str; 6] = JOINTS;

/// The reach task on a robot: its state as the controller knows it, the task's observation.
pub struct ReachController {
    terms: TaskTerms<CellState>,
    pub state: CellState,
    observation: Vec<f32>,
}

impl Default for ReachController {
    fn default() -> Self {
        Self { terms: crate::goal::reach_with_goal().terms, state: CellState::default(), observation: Vec::new() }
    }
}

impl ReachController {
    /// A new reach: a target from the task's sampler, no action yet.
    pub fn new_reach(&mut self, rng: &mut impl Rng) {
        self.state.target = crate::reach::sample_target(rng, self.state.fixtures.pick);
        self.state.actions = ActionHistory::default();
    }

    /// The arm as measured (robot order and signs).
    pub fn read(&mut self, q: &[f64; 6], qd: &[f64; 6]) {
        let twin = |v: &[f64; 6]| std::array::from_fn(|j| (v[j] * JOINT_SIGNS[j]) as f32);
        self.state.arm = ArmState::from_joints(twin(q), twin(qd));
        self.state.read = true;
    }

    /// The task's observation of the arm as last read.
    pub fn observation(&mut self) -> &[f32] {
        self.terms.observe(&self.state, &mut self.observation);
        &self.observation
    }

    /// Joint speeds (rad/s, robot order and signs) for the policy's action, which the next
    /// observation will show as the last action.
    pub fn act(&mut self, action: &[f32]) -> [f64; 6] {
        self.state.actions.push(action);
        let speeds = arm::joint_speeds(action);
        std::array::from_fn(|j| speeds[j] as f64 * JOINT_SIGNS[j])
    }

    /// Joint speeds that take the arm home (the controller's homing move).
    pub fn homing(&self) -> [f64; 6] {
        arm::homing_speeds(&self.state.arm.q).map(|v| v as f64)
    }

    pub fn arrived(&self) -> bool {
        self.state.arm.has_reached(self.state.target)
    }

    pub fn is_home(&self) -> bool {
        self.state.arm.is_home()
    }

    pub fn target(&self) -> Vec3 {
        self.state.target
    }

    /// The tool's distance to the target (m).
    pub fn error(&self) -> f32 {
        self.state.arm.distance_to(self.state.target)
    }
}

/// What the shadow does with a command.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    /// The command that may go to the robot (joint speeds, rad/s).
    pub command: [f64; 6],
    /// Whether any joint's command was changed.
    pub clipped: bool,
    /// Whether the command was refused: the robot is told to stop instead.
    pub refused: bool,
    /// Why, for the log.
    pub notes: Vec<String>,
}

/// The twin's check of a joint-speed command before it goes to the robot: the joints' speed
/// and acceleration limits, their ranges and the workspace (no link or the tool near or under
/// the table) over the next `lookahead` seconds of the command. Speeds and accelerations past a
/// limit are clipped to it; a command that would take a joint out of its range or a point of
/// the arm into the table is refused.
#[derive(Clone, Debug)]
pub struct Shadow {
    /// Fastest joint speed (rad/s).
    pub max_speed: f64,
    /// Largest change of commanded speed (rad/s²).
    pub max_acceleration: f64,
    /// How far ahead a command is followed (s).
    pub lookahead: f64,
    /// The closest a joint may come to its stop (rad).
    pub range_margin: f64,
    /// The lowest the elbow, wrists, flange and tool may go, above the table (m, base frame).
    pub table_clearance: f64,
}

impl Default for Shadow {
    fn default() -> Self {
        Self { max_speed: MAX_JOINT_SPEED as f64, max_acceleration: 40.0, lookahead: 0.08, range_margin: 0.05, table_clearance: 0.005 }
    }
}

impl Shadow {
    /// Checks `command` from measured joints `q` given the previous command, `period` seconds
    /// before.
    pub fn check(&self, q: &[f64; 6], command: &[f64; 6], previous: &[f64; 6], period: f64) -> Verdict {
        let mut notes = Vec::new();
        let mut out = *command;
        let mut clipped = false;
        for j in 0..6 {
            if !out[j].is_finite() {
                notes.push(format!("joint {}: command {} is not a number", j + 1, out[j]));
                return Verdict { command: [0.0; 6], clipped: true, refused: true, notes };
            }
            let limited = out[j].clamp(-self.max_speed, self.max_speed);
            let step = self.max_acceleration * period;
            let limited = limited.clamp(previous[j] - step, previous[j] + step);
            if limited != out[j] {
                notes.push(format!("joint {}: {:.3} rad/s clipped to {:.3} (speed ≤ {:.3}, acceleration ≤ {:.0} rad/s²)", j + 1, out[j], limited, self.max_speed, self.max_acceleration));
                out[j] = limited;
                clipped = true;
            }
        }
        let ahead: [f64; 6] = std::array::from_fn(|j| q[j] + out[j] * self.lookahead);
        for j in 0..6 {
            let range = JOINT_RANGES[j] as f64 - self.range_margin;
            if ahead[j].abs() > range && ahead[j].abs() > q[j].abs() {
                notes.push(format!("joint {}: {:.3} rad in {:.2} s is past its range ±{range:.3}", j + 1, ahead[j], self.lookahead));
                return Verdict { command: [0.0; 6], clipped, refused: true, notes };
            }
        }
        let lowest = lowest_point(&ahead);
        if lowest.1 < self.table_clearance && lowest.1 < lowest_point(q).1 {
            notes.push(format!("{} at z = {:.3} m in {:.2} s: into the table", lowest.0, lowest.1, self.lookahead));
            return Verdict { command: [0.0; 6], clipped, refused: true, notes };
        }
        Verdict { command: out, clipped, refused: false, notes }
    }
}

/// The lowest of the elbow, wrists, flange and tool face at `q`: its name and height (m, base
/// frame, the table's surface at 0).
pub fn lowest_point(q: &[f64; 6]) -> (&'static str, f64) {
    let f = kinematics::frames(&q.map(|v| v as f32));
    let tool = (f[6] * DMat4::from_translation(DVec3::new(0.0, 0.0, TOOL_LENGTH))).w_axis.z;
    let points = [("elbow", f[2].w_axis.z), ("wrist 1", f[3].w_axis.z), ("wrist 2", f[4].w_axis.z), ("wrist 3", f[5].w_axis.z), ("flange", f[6].w_axis.z), ("tool", tool)];
    points.into_iter().fold(("", f64::INFINITY), |low, p| if p.1 < low.1 { p } else { low })
}

/// Joints the policy commands (wrist 3 holds).
pub const COMMANDED_JOINTS: usize = ACTION_DIM;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kinematics::HOME;

    #[test]
    fn the_shadow_clips_speed_and_acceleration_and_refuses_the_table_and_the_stops() {
        let shadow = Shadow::default();
        let home = HOME.map(|v| v as f64);
        let ok = shadow.check(&home, &[0.1, 0.0, 0.0, 0.0, 0.0, 0.0], &[0.0; 6], 0.04);
        assert!(!ok.clipped && !ok.refused, "{ok:?}");
        let fast = shadow.check(&home, &[10.0, 0.0, 0.0, 0.0, 0.0, 0.0], &[3.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.04);
        assert!(fast.clipped && !fast.refused && (fast.command[0] - std::f64::consts::PI).abs() < 1e-6, "{fast:?}");
        let jerk = shadow.check(&home, &[1.5, 0.0, 0.0, 0.0, 0.0, 0.0], &[0.0; 6], 0.01);
        assert!((jerk.command[0] - 0.4).abs() < 1e-9, "40 rad/s² over 10 ms: {jerk:?}");
        // The shoulder lifting down drives the tool into the table.
        let mut low = home;
        low[1] = -0.4;
        assert!(lowest_point(&low).1 < lowest_point(&home).1);
        let mut down = low;
        while lowest_point(&down).1 > 0.01 {
            down[1] += 0.01;
        }
        let dive = shadow.check(&down, &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0], &[0.0, 1.0, 0.0, 0.0, 0.0, 0.0], 0.04);
        assert!(dive.refused && dive.command == [0.0; 6], "{dive:?}");
        // Past the elbow's stop.
        let mut bent = home;
        bent[2] = 3.1;
        let past = shadow.check(&bent, &[0.0, 0.0, 1.0, 0.0, 0.0, 0.0], &[0.0, 0.0, 1.0, 0.0, 0.0, 0.0], 0.04);
        assert!(past.refused, "{past:?}");
        // Away from the stop is allowed.
        let back = shadow.check(&bent, &[0.0, 0.0, -1.0, 0.0, 0.0, 0.0], &[0.0, 0.0, -1.0, 0.0, 0.0, 0.0], 0.04);
        assert!(!back.refused, "{back:?}");
        assert!(shadow.check(&home, &[f64::NAN, 0.0, 0.0, 0.0, 0.0, 0.0], &[0.0; 6], 0.04).refused);
    }

    #[test]
    fn the_controller_observes_as_the_task_does() {
        let mut c = ReachController::default();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        c.new_reach(&mut rng);
        c.read(&HOME.map(|v| v as f64), &[0.0; 6]);
        let obs = c.observation().to_vec();
        assert_eq!(obs.len(), crate::task_spec().observation_space.dim());
        assert!(c.is_home() && !c.arrived());
        let speeds = c.act(&[1.0, -1.0, 0.5, 0.0, 0.0]);
        assert!((speeds[0] - arm::ACTION_SPEED as f64).abs() < 1e-6 && speeds[5] == 0.0);
        assert_eq!(&c.observation()[obs.len() - COMMANDED_JOINTS..], &[1.0, -1.0, 0.5, 0.0, 0.0]);
    }

    use rand::SeedableRng;
}
