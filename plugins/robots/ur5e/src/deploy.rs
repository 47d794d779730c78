//! The reach policy on a real UR5e (or its stand-in): the controller's side of an episode
//! without the twin's app — the task's own observation terms over the arm as RTDE reports it,
//! targets from the task's own sampler, actions as joint speeds — and the arm's geometry for
//! the **shadow**, the twin's check of every command before it reaches the robot.

use std::sync::Arc;

use bevy::math::{DVec3, Vec3};
use rand::RngCore;
use twinbots_task::TaskTerms;
use twinbots_task::on_robot::ReachOnRobot;
use twinbots_task::shadow::{ArmGeometry, Keepout, Shadow};

use crate::arm::{self, ACTION_DIM, ActionHistory, ArmState};
use crate::kinematics::{self, JOINT_RANGES, JOINTS, MAX_JOINT_SPEED};
use crate::layout::CellLayout;
use crate::state::CellState;
use twinbots_sim::rapier::math::Pose;

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

impl ReachOnRobot for ReachController {
    fn new_reach(&mut self, mut rng: &mut dyn RngCore) {
        self.state.target = crate::reach::sample_target(&mut rng, self.state.fixtures.pick);
        self.state.actions = ActionHistory::default();
    }

    /// The arm as measured (robot order and signs).
    fn read(&mut self, q: &[f64], qd: &[f64]) {
        let twin = |v: &[f64]| std::array::from_fn(|j| (v[j] * JOINT_SIGNS[j]) as f32);
        self.state.arm = ArmState::from_joints(twin(q), twin(qd));
        self.state.read = true;
    }

    fn observation(&mut self) -> &[f32] {
        self.terms.observe(&self.state, &mut self.observation);
        &self.observation
    }

    /// Joint speeds (rad/s, robot order and signs): the first five joints at the task's speed.
    fn act(&mut self, action: &[f32]) -> Vec<f64> {
        self.state.actions.push(action);
        let speeds = arm::joint_speeds(action);
        (0..6).map(|j| speeds[j] as f64 * JOINT_SIGNS[j]).collect()
    }

    /// The controller's homing move.
    fn homing(&self) -> Vec<f64> {
        arm::homing_speeds(&self.state.arm.q).iter().map(|&v| v as f64).collect()
    }

    fn arrived(&self) -> bool {
        self.state.arm.has_reached(self.state.target)
    }

    fn is_home(&self) -> bool {
        self.state.arm.is_home()
    }

    fn target(&self) -> Vec3 {
        self.state.target
    }

    fn error(&self) -> f32 {
        self.state.arm.distance_to(self.state.target)
    }
}

/// The UR5e's geometry for the shadow ([`twinbots_task::shadow`]): its DH frames, its stops.
#[derive(Clone, Copy, Debug, Default)]
pub struct Ur5eGeometry;

impl ArmGeometry for Ur5eGeometry {
    fn range(&self, joint: usize) -> (f64, f64) {
        let r = JOINT_RANGES[joint] as f64;
        (-r, r)
    }

    fn skeleton(&self, q: &[f64; 6]) -> Vec<(&str, DVec3)> {
        skeleton(q)
    }

    fn lowest_point(&self, q: &[f64; 6]) -> (&str, f64) {
        lowest_point(q)
    }
}

/// The UR5e's shadow: its joints' π rad/s, its stops, its DH frames.
pub fn shadow() -> Shadow {
    Shadow::new(Arc::new(Ur5eGeometry), [MAX_JOINT_SPEED as f64; 6])
}

/// A cell's obstacles in its robot's base frame.
pub fn keepouts(layout: &CellLayout) -> Vec<Keepout> {
    let base = layout.base_pose().inverse();
    let yaw = -(layout.robot.yaw as f64).to_radians();
    layout
        .obstacles
        .iter()
        .map(|o| Keepout {
            centre: (base * Pose::from_translation(Vec3::from_array(o.centre))).translation.as_dvec3(),
            half: Vec3::from_array(o.size).as_dvec3() / 2.0,
            yaw,
        })
        .collect()
}

const SKELETON_NAMES: [&str; 7] = ["shoulder", "elbow", "wrist 1", "wrist 2", "wrist 3", "flange", "tool"];

/// The arm at `q` (base frame): the DH frames' origins from the shoulder to the flange, and
/// the tool face.
pub fn skeleton(q: &[f64; 6]) -> Vec<(&'static str, DVec3)> {
    let f = kinematics::frames(&q.map(|v| v as f32));
    let tool = kinematics::tool_face(f[6]).w_axis.truncate();
    f[1..].iter().map(|m| m.w_axis.truncate()).chain([tool]).zip(SKELETON_NAMES).map(|(p, name)| (name, p)).collect()
}

/// The lowest of the elbow, wrists, flange and tool face at `q`: its name and height (m, base
/// frame, the table's surface at 0).
pub fn lowest_point(q: &[f64; 6]) -> (&'static str, f64) {
    let f = kinematics::frames(&q.map(|v| v as f32));
    let tool = kinematics::tool_face(f[6]).w_axis.z;
    let points = [
        ("elbow", f[2].w_axis.z),
        ("wrist 1", f[3].w_axis.z),
        ("wrist 2", f[4].w_axis.z),
        ("wrist 3", f[5].w_axis.z),
        ("flange", f[6].w_axis.z),
        ("tool", tool),
    ];
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
        let shadow = shadow();
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
    fn the_shadow_keeps_the_arm_off_a_cells_obstacles() {
        // A column beside the arm, where the pan turning +z brings the tool.
        let home = HOME.map(|v| v as f64);
        let mut turned = home;
        let column_at = |q: &[f64; 6]| skeleton(q).last().unwrap().1;
        turned[0] += 0.6;
        let tool = column_at(&turned);
        let text = crate::layout::DEFAULT.replacen(
            "# [[obstacle]]\n# centre = [-0.1, 0.45, 0.95]   # m, cell frame\n# size = [0.1, 0.1, 0.4]",
            &format!("[[obstacle]]\ncentre = [{}, {}, {}]\nsize = [0.1, 0.1, 0.4]", tool.x, tool.y, tool.z + 0.75),
            1,
        );
        let layout = CellLayout::parse(&text, "column.toml").unwrap();
        let keepouts = keepouts(&layout);
        assert_eq!(keepouts.len(), 1);
        assert!(
            keepouts[0].distance(tool) < 1e-6,
            "the tool at the turned pose is inside the column: {:?}",
            keepouts[0]
        );
        let shadow = Shadow { keepouts, ..shadow() };
        // At home the arm is clear; a turn towards the column, from just outside the clearance,
        // is refused; a turn away from it is not.
        let mut near = home;
        while shadow.closest_keepout(&near).unwrap().2 > shadow.keepout_clearance + 0.02 {
            near[0] += 0.005;
        }
        let towards = shadow.check(&near, &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], &[1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.04);
        assert!(towards.refused && towards.notes[0].contains("obstacle[0]"), "{towards:?}");
        let away = shadow.check(&near, &[-1.0, 0.0, 0.0, 0.0, 0.0, 0.0], &[-1.0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.04);
        assert!(!away.refused, "{away:?}");
        assert!(!shadow.check(&home, &[0.1, 0.0, 0.0, 0.0, 0.0, 0.0], &[0.0; 6], 0.04).refused);
        // A turned robot sees its obstacles turned back: the same column, the base turned 90°,
        // keeps the same distance from the same joint angles when the pan turns with it.
        let turned_layout = CellLayout::parse(
            &text
                .replace("yaw = 0.0", "yaw = 90.0")
                .replace(&format!("centre = [{}, {}", tool.x, tool.y), &format!("centre = [{}, {}", -tool.y, tool.x)),
            "turned.toml",
        )
        .unwrap();
        let k = super::keepouts(&turned_layout)[0];
        assert!(k.distance(tool) < 1e-5, "{k:?}");
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
