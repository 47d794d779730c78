//! The arm a robot file describes, as its controller knows it: the chain's kinematics in the
//! controller's joint order, the joints' ranges and speed limits, home, and where the base
//! stands in the arena: on an empty floor, or on the table of its cell.

use bevy::math::DVec3;
use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::RobotModel;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_task::cell::layout::{CellLayout, Fixtures};

use crate::work_area::WorkArea;

/// A joint this close to a stop (rad or m) counts as at its limit: the protective stop.
pub use twinbots_sim::urdf::robot_file::STOP_MARGIN as LIMIT_MARGIN;
/// How far inside each end of a joint's range the soft limit is (rad or m): the reach's
/// `joint_limits` cost grows past it, before the protective stop (Isaac Lab's
/// `joint_pos_limits` with soft limits).
pub const SOFT_LIMIT_ZONE: f64 = 0.2;
/// Reach targets are the tool's position at joint positions this far (rad or m) either side
/// of home, each joint drawn on its own within its range: reachable by construction, and
/// around where the arm works.
pub const TARGET_SPREAD: f64 = 0.6;
/// …and at least this high above the floor, or the table of the arm's cell (m).
pub const TARGET_CLEARANCE: f64 = 0.1;
/// Episode starts: home with every joint off by up to this much (rad or m).
pub const START_SPREAD: f64 = 0.05;
/// A station target lies this far (m) across either fixture's plate centre…
pub const STATION_SPREAD: f32 = 0.05;
/// …and this high above its plate (m): from the part's top (7 cm) plus the cell program's 4 cm
/// align height to its 10 cm clearance and beyond, where the program's free moves end.
pub const STATION_HEIGHTS: std::ops::RangeInclusive<f32> = 0.11..=0.25;

/// A reach target over one of the cell's fixtures (either, at even odds): where the cell
/// program's free moves (approach, transfer) send the tool, which targets around home need not
/// cover (the Panda's reach model, trained on those alone, placed 1.5 % of its cell's parts).
fn station_target(fixtures: Fixtures, rng: &mut impl Rng) -> Vec3 {
    let plate = if rng.random_bool(0.5) { fixtures.pick } else { fixtures.place };
    let across = Vec3::new(
        rng.random_range(-STATION_SPREAD..=STATION_SPREAD),
        rng.random_range(-STATION_SPREAD..=STATION_SPREAD),
        0.0,
    );
    plate + across + Vec3::Z * rng.random_range(STATION_HEIGHTS)
}

/// A reach succeeds when the tool is this close to its target (m), and so does the
/// reachability check.
pub const REACH_TOLERANCE: f32 = 0.01;
/// A straight move has brought the tool down only once its axis is within this of the
/// vertical (rad). The UR5e reach's 0.1 rad let parts go tilted: 10 % of the UR10's programs
/// with its reach model left the part leaning 0.2–0.45 rad against a rail.
pub const TILT_TOLERANCE: f32 = 0.01;

/// Gain (1/s) with which a straight move turns the tool's axis down, as the UR5e's controller.
const TILT_GAIN: f64 = 3.0;
/// Damping of a straight move's least-squares solve (m), the UR5e controller's.
const STRAIGHT_DAMPING: f64 = 0.02;
/// The reachability check's straight move: gain (1/s) and top tool speed (m/s), quick enough
/// to cross a cell within its 12 s.
const REACH_CHECK_GAIN: f64 = 4.0;
const REACH_CHECK_SPEED: f64 = 1.0;

/// The arm, shared by every arena of an app.
#[derive(Resource, Clone, Debug)]
pub struct Arm {
    pub file: RobotFile,
    /// The URDF with its meshes (what the simulator spawns).
    pub model: RobotModel,
    /// The base link's pose in the arena (the root link welded at the origin, or where the
    /// cell's layout puts the robot).
    pub base: Pose,
    /// The cell's layout (the file's `cell`), if any.
    pub cell: Option<CellLayout>,
    /// The height (m) of what the arm works over in the arena: the floor, or its cell's table top.
    pub surface: f32,
    /// The learned pick-and-place's work area, for an arm with a cell and a gripper.
    pub work_area: Option<WorkArea>,
    /// For each of the chain's movable joints, its place in the controller's order (the robot
    /// file's mapping, computed once).
    controller_index: Vec<usize>,
}

impl Arm {
    /// The arm of a robot file, its URDF's meshes read.
    pub fn of(file: RobotFile) -> anyhow::Result<Self> {
        let model = file.model()?;
        let cell = match &file.cell {
            Some(path) => {
                Some(CellLayout::read(path).map_err(|e| anyhow::anyhow!("{}: key 'cell': {e}", file.path.display()))?)
            }
            None => None,
        };
        for (name, value) in &file.held_positions {
            let joint = model.joint(name).filter(|j| j.kind.is_movable() && !file.joints.contains(name));
            let Some(joint) = joint else {
                anyhow::bail!(
                    "{}: key 'held_positions': '{name}' is not a movable joint of the URDF outside `joints`",
                    file.path.display()
                );
            };
            let [lo, hi] = joint.limits.position.unwrap_or([f32::NEG_INFINITY, f32::INFINITY]);
            // In the URDF's single precision, as the simulator holds it.
            anyhow::ensure!(
                value.is_finite() && (lo..=hi).contains(&(*value as f32)),
                "{}: key 'held_positions': {value} for '{name}' is outside its range [{lo}, {hi}]",
                file.path.display()
            );
            anyhow::ensure!(
                joint.limits.effort > 0.0,
                "{}: key 'held_positions': '{name}' has no drive to hold it (its URDF effort is 0)",
                file.path.display()
            );
        }
        let controller_index = file.controller_index();
        let arm =
            Self { file, model, base: Pose::IDENTITY, cell: None, surface: 0.0, work_area: None, controller_index };
        arm.in_cell(cell)
    }

    /// The same arm standing in `cell` (its table, where the layout puts the robot), or on an
    /// empty floor: what a cell study runs in each of its layouts.
    pub fn in_cell(mut self, cell: Option<CellLayout>) -> anyhow::Result<Self> {
        let root = cell.as_ref().map_or(Pose::IDENTITY, CellLayout::base_pose);
        let file = &self.file;
        let root_poses = self.model.link_poses(root, |j| file.start_position(&j.name) as f32);
        let base_link = self
            .model
            .link_index(&file.chain.base)
            .ok_or_else(|| anyhow::anyhow!("{}: the URDF has no link '{}'", file.path.display(), file.chain.base))?;
        self.base = root_poses[base_link];
        self.surface = cell.as_ref().map_or(0.0, |c| c.table.height);
        self.work_area = match (&cell, &self.file.gripper) {
            (Some(layout), Some(_)) => {
                let home = self.tool(&self.home()).as_vec3();
                let area = WorkArea::of(layout, self.base, home)
                    .map_err(|e| anyhow::anyhow!("{}: key 'cell': {e}", self.file.path.display()))?;
                Some(area)
            }
            _ => None,
        };
        self.cell = cell;
        Ok(self)
    }

    pub fn dof(&self) -> usize {
        self.file.joints.len()
    }

    /// Chain-order positions of controller-order `q`.
    fn chain_q(&self, q: &[f32]) -> Vec<f64> {
        self.controller_index.iter().map(|&k| q[k] as f64).collect()
    }

    /// The tool link's position in the base frame at controller-order joint positions `q`.
    pub fn tool(&self, q: &[f32]) -> DVec3 {
        self.file.chain.forward(&self.chain_q(q)).translation
    }

    /// The tool's position, linear velocity (J·q̇) and z axis (its gripper's) in the base frame,
    /// from one pass along the chain.
    pub fn tool_motion(&self, q: &[f32], qd: &[f32]) -> (DVec3, DVec3, DVec3) {
        let (tool, columns) = self.file.chain.forward_and_jacobian(&self.chain_q(q));
        let velocity = columns
            .iter()
            .zip(&self.controller_index)
            .map(|(col, &k)| DVec3::new(col[0], col[1], col[2]) * qd[k] as f64)
            .sum();
        (tool.translation, velocity, tool.rotation * DVec3::Z)
    }

    /// Whether any joint is within [`LIMIT_MARGIN`] of a stop.
    pub fn at_limit(&self, q: &[f32]) -> bool {
        q.iter()
            .zip(&self.file.ranges)
            .any(|(&q, &(lo, hi))| (q as f64) <= lo + LIMIT_MARGIN || (q as f64) >= hi - LIMIT_MARGIN)
    }

    /// How far the joints are past their soft limits ([`SOFT_LIMIT_ZONE`] inside each end of their
    /// ranges), summed (rad or m).
    pub fn limit_depth(&self, q: &[f32]) -> f32 {
        q.iter()
            .zip(&self.file.ranges)
            .map(|(&q, &(lo, hi))| {
                let q = q as f64;
                ((lo + SOFT_LIMIT_ZONE - q).max(0.0) + (q - (hi - SOFT_LIMIT_ZONE)).max(0.0)) as f32
            })
            .sum()
    }

    /// Joint positions near home, inside the ranges by more than the stop's margin.
    pub fn sample_around_home(&self, rng: &mut impl Rng, spread: f64) -> Vec<f32> {
        self.file
            .home
            .iter()
            .zip(&self.file.ranges)
            .map(|(&h, &(lo, hi))| {
                let margin = 2.0 * LIMIT_MARGIN;
                (h + rng.random_range(-spread..=spread)).clamp(lo + margin, hi - margin) as f32
            })
            .collect()
    }

    /// A reach target in the base frame: the tool at joint positions around home, high enough
    /// above the floor (a few draws; home's own tool position if none is). An arm in a cell
    /// draws every other target over its fixtures instead ([`Self::station_target`]).
    pub fn sample_target(&self, rng: &mut impl Rng) -> Vec3 {
        if let Some(fixtures) = self.fixtures()
            && rng.random_bool(0.5)
        {
            return station_target(fixtures, rng);
        }
        for _ in 0..32 {
            let tool = self.tool(&self.sample_around_home(rng, TARGET_SPREAD));
            let height = (self.base.translation.z - self.surface) as f64 + tool.z;
            if height >= TARGET_CLEARANCE {
                return tool.as_vec3();
            }
        }
        self.tool(&self.home()).as_vec3()
    }

    pub fn home(&self) -> Vec<f32> {
        self.file.home.iter().map(|&h| h as f32).collect()
    }

    /// The root link's pose in the arena: where the robot is welded.
    pub fn root(&self) -> Pose {
        self.cell.as_ref().map_or(Pose::IDENTITY, CellLayout::base_pose)
    }

    /// Where the cell's fixtures' plates are centred on the table top, in the base link's frame
    /// (what the program and the controller work in), if the arm has a cell.
    pub fn fixtures(&self) -> Option<Fixtures> {
        let cell = self.cell.as_ref()?;
        let local = |f| (self.base.inverse() * cell.fixture_pose(f)).translation;
        Some(Fixtures { pick: local(&cell.pick), place: local(&cell.place) })
    }

    /// Joint speeds (controller order; rad/s or m/s) of a straight move of the tool towards
    /// `target` (base frame) that turns its z axis down (a UR's MoveL with the tool pointing
    /// down): damped least squares on the chain Jacobian's linear rows and the two angular rows
    /// that tilt the axis (its turn about the vertical is free), the whole scaled so that no
    /// joint exceeds its task speed and the tool no `max_speed` (m/s).
    pub fn straight_move(&self, q: &[f32], target: DVec3, gain: f64, max_speed: f64) -> Vec<f32> {
        self.tool_velocity(q, |tool| ((target - tool) * gain).clamp_length_max(max_speed))
    }

    /// Joint speeds (controller order) that move the tool at the velocity `velocity(tool)`
    /// (m/s, base frame; `tool` its position) while turning its z axis down: the straight
    /// move's law, and the learned pick-and-place's tool moves.
    pub fn tool_velocity(&self, q: &[f32], velocity: impl FnOnce(DVec3) -> DVec3) -> Vec<f32> {
        use twinbots_sim::rapier::na::{DMatrix, DVector};
        let (frame, columns) = self.file.chain.forward_and_jacobian(&self.chain_q(q));
        let down = self.down();
        let v = velocity(frame.translation);
        let w = (frame.rotation * DVec3::Z).cross(down) * TILT_GAIN;
        let twist = DVector::from_row_slice(&[v.x, v.y, v.z, w.x, w.y]);
        let j = DMatrix::from_fn(5, columns.len(), |r, c| columns[c][r]);
        let damped = (&j * j.transpose() + DMatrix::identity(5, 5) * STRAIGHT_DAMPING.powi(2)).cholesky();
        let Some(damped) = damped else { return vec![0.0; self.dof()] };
        let chain_speeds = j.transpose() * damped.solve(&twist);
        let mut speeds = vec![0.0; self.dof()];
        for (c, &k) in self.controller_index.iter().enumerate() {
            speeds[k] = chain_speeds[c];
        }
        let top = (speeds.iter().zip(&self.file.speed_limits)).fold(1.0f64, |m, (s, limit)| m.max(s.abs() / limit));
        speeds.iter().map(|s| (s / top) as f32).collect()
    }

    /// Whether the arm can bring its tool to `target` (base frame) pointing down, within the
    /// reach's 1 cm and [`TILT_TOLERANCE`]: the straight move's law run on the
    /// kinematics alone from home (12 s of control steps; no physics), joints inside their
    /// ranges all the way. Cell studies map reachability over the table with it and call a
    /// program sent to a waypoint it cannot reach a reach failure (the UR5e's
    /// `controller::reachable`).
    pub fn reachable(&self, target: Vec3) -> bool {
        const DT: f64 = 0.04;
        let (target, down) = (target.as_dvec3(), self.down());
        let mut q = self.home();
        for _ in 0..300 {
            if self.at_limit(&q) {
                return false;
            }
            let tool = self.file.chain.forward(&self.chain_q(&q));
            if (tool.translation - target).length() < f64::from(REACH_TOLERANCE)
                && (tool.rotation * DVec3::Z).angle_between(down) < f64::from(TILT_TOLERANCE)
            {
                return true;
            }
            let speeds = self.straight_move(&q, target, REACH_CHECK_GAIN, REACH_CHECK_SPEED);
            for (q, s) in q.iter_mut().zip(speeds) {
                *q += (f64::from(s) * DT) as f32;
            }
        }
        false
    }

    /// The arena's downward direction in the base frame: where a straight move turns the tool.
    fn down(&self) -> DVec3 {
        self.base.rotation.as_dquat().inverse() * -DVec3::Z
    }

    /// How far the tool can get from the base: the chain's joint offsets laid end to end.
    pub fn reach(&self) -> f32 {
        self.file.chain.joints.iter().map(|j| j.origin.translation.length()).sum::<f64>() as f32
    }
}
