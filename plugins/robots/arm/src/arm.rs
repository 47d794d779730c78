//! The arm a robot file describes, as its controller knows it: the chain's kinematics in the
//! controller's joint order, the joints' ranges and speed limits, home, and where the base
//! stands in the arena.

use bevy::math::DVec3;
use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::RobotModel;
use twinbots_sim::urdf::robot_file::RobotFile;

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
/// …and at least this high above the floor (m).
pub const TARGET_CLEARANCE: f64 = 0.1;
/// Episode starts: home with every joint off by up to this much (rad or m).
pub const START_SPREAD: f64 = 0.05;

/// The arm, shared by every arena of an app.
#[derive(Resource, Clone, Debug)]
pub struct Arm {
    pub file: RobotFile,
    /// The URDF with its meshes (what the simulator spawns).
    pub model: RobotModel,
    /// The base link's pose in the arena (the root link stands at the origin, welded).
    pub base: Pose,
    /// For each of the chain's movable joints, its place in the controller's order (the robot
    /// file's mapping, computed once).
    controller_index: Vec<usize>,
}

impl Arm {
    /// The arm of a robot file, its URDF's meshes read.
    pub fn of(file: RobotFile) -> anyhow::Result<Self> {
        let model = file.model()?;
        let root_poses = model.link_poses(Pose::IDENTITY, |j| {
            file.joints.iter().position(|n| *n == j.name).map_or(0.0, |k| file.home[k] as f32)
        });
        let base_link = model
            .link_index(&file.chain.base)
            .ok_or_else(|| anyhow::anyhow!("{}: the URDF has no link '{}'", file.path.display(), file.chain.base))?;
        let base = root_poses[base_link];
        let controller_index = file.controller_index();
        Ok(Self { file, model, base, controller_index })
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

    /// The tool's position and linear velocity (J·q̇) in the base frame.
    pub fn tool_motion(&self, q: &[f32], qd: &[f32]) -> (DVec3, DVec3) {
        let (tool, columns) = self.file.chain.forward_and_jacobian(&self.chain_q(q));
        let velocity = columns
            .iter()
            .zip(&self.controller_index)
            .map(|(col, &k)| DVec3::new(col[0], col[1], col[2]) * qd[k] as f64)
            .sum();
        (tool.translation, velocity)
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
    /// above the floor (a few draws; home's own tool position if none is).
    pub fn sample_target(&self, rng: &mut impl Rng) -> Vec3 {
        for _ in 0..32 {
            let tool = self.tool(&self.sample_around_home(rng, TARGET_SPREAD));
            let height = self.base.translation.z as f64 + tool.z;
            if height >= TARGET_CLEARANCE {
                return tool.as_vec3();
            }
        }
        self.tool(&self.home()).as_vec3()
    }

    pub fn home(&self) -> Vec<f32> {
        self.file.home.iter().map(|&h| h as f32).collect()
    }

    /// How far the tool can get from the base: the chain's joint offsets laid end to end.
    pub fn reach(&self) -> f32 {
        self.file.chain.joints.iter().map(|j| j.origin.translation.length()).sum::<f64>() as f32
    }
}
