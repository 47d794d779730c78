//! The robot description a URDF is turned into: plain data in SI units, frames as [`Pose`]s.
//!
//! Coordinates are the URDF's own (Z up, X forward). The loader has already checked everything
//! [`RobotModel`] promises: one root, every joint's links exist, a tree, non-negative masses.

use std::sync::Arc;

use bevy::math::{Mat3, Vec3};

use crate::rapier::math::Pose;

/// One robot: its links and the joints between them, as a tree rooted at `root`.
#[derive(Clone, Debug)]
pub struct RobotModel {
    pub name: String,
    pub links: Vec<LinkModel>,
    pub joints: Vec<JointModel>,
    /// Index into `links` of the link no joint moves.
    pub root: usize,
}

/// A rigid link.
#[derive(Clone, Debug)]
pub struct LinkModel {
    pub name: String,
    /// `None` for a massless link (a frame, or a link with no `<inertial>`).
    pub inertial: Option<Inertial>,
    pub collisions: Vec<Geometry>,
    pub visuals: Vec<Visual>,
}

/// Mass properties of a link, in the link frame.
#[derive(Clone, Copy, Debug)]
pub struct Inertial {
    /// Centre of mass and principal frame of the inertia tensor.
    pub origin: Pose,
    pub mass: f32,
    /// Inertia tensor about the centre of mass, in `origin`'s frame.
    pub inertia: Mat3,
    /// The URDF gave the mass but no inertia: centre of mass and inertia are the collision
    /// geometry's as a uniform solid of that mass.
    pub from_geometry: bool,
}

/// A shape placed in its link's frame.
#[derive(Clone, Debug)]
pub struct Geometry {
    pub origin: Pose,
    pub shape: Shape,
}

/// A visual: geometry plus colour.
#[derive(Clone, Debug)]
pub struct Visual {
    pub geometry: Geometry,
    /// Linear RGBA in 0..=1; URDF materials without colour get a neutral grey.
    pub rgba: [f32; 4],
}

/// URDF geometry. Cylinders follow URDF: their axis is the local Z axis.
#[derive(Clone, Debug)]
pub enum Shape {
    Box { half_extents: Vec3 },
    Cylinder { radius: f32, length: f32 },
    Sphere { radius: f32 },
    Mesh(Arc<TriangleMesh>),
}

impl Shape {
    /// The shape as parry builds it, and where parry's shape sits in the URDF geometry frame
    /// (URDF cylinders run along Z, parry's along Y); a mesh as its convex hull, `None` when it
    /// has none (the loader refuses such meshes). What colliders and computed inertias share.
    pub fn parry(&self) -> Option<(crate::rapier::parry::shape::SharedShape, Pose)> {
        use crate::rapier::parry::shape::SharedShape;
        Some(match self {
            Shape::Box { half_extents: h } => (SharedShape::cuboid(h.x, h.y, h.z), Pose::IDENTITY),
            Shape::Cylinder { radius, length } => (
                SharedShape::cylinder(length / 2.0, *radius),
                Pose::from_rotation(bevy::math::Quat::from_rotation_x(std::f32::consts::FRAC_PI_2)),
            ),
            Shape::Sphere { radius } => (SharedShape::ball(*radius), Pose::IDENTITY),
            Shape::Mesh(mesh) => (SharedShape::convex_hull(&mesh.vertices)?, Pose::IDENTITY),
        })
    }
}

/// A triangle mesh read from a mesh file (STL, OBJ, glTF), already scaled.
#[derive(Clone, Debug)]
pub struct TriangleMesh {
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
}

/// The kinds of joint the simulator supports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    Revolute,
    Continuous,
    Prismatic,
    Fixed,
}

impl JointKind {
    /// Whether the joint has a degree of freedom.
    pub fn is_movable(self) -> bool {
        self != JointKind::Fixed
    }

    /// Whether the joint turns (as opposed to slides).
    pub fn is_rotational(self) -> bool {
        matches!(self, JointKind::Revolute | JointKind::Continuous)
    }
}

/// Joint limits from `<limit>`: position stops, and the motor's effort and velocity bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointLimits {
    /// Position stops; `None` for continuous joints.
    pub position: Option<[f32; 2]>,
    /// Max torque (N·m) or force (N); 0 means the joint is passive (no motor).
    pub effort: f32,
    /// Max speed (rad/s or m/s).
    pub velocity: f32,
}

/// A joint between two links.
#[derive(Clone, Debug)]
pub struct JointModel {
    pub name: String,
    pub kind: JointKind,
    pub parent: usize,
    pub child: usize,
    /// The joint frame in the parent link's frame; the child link frame coincides with it at q = 0.
    pub origin: Pose,
    /// Unit axis in the joint frame.
    pub axis: Vec3,
    pub limits: JointLimits,
    /// Viscous damping (N·m·s/rad or N·s/m) from `<dynamics damping>`.
    pub damping: f32,
    /// Coulomb friction (N·m or N) from `<dynamics friction>`.
    pub friction: f32,
}

impl JointModel {
    /// The child link frame in the parent link's at joint position `q` (rad or m): the
    /// forward kinematics of one joint, as robot_state_publisher computes a frame.
    pub fn child_pose(&self, q: f32) -> Pose {
        let motion = match self.kind {
            JointKind::Fixed => Pose::IDENTITY,
            JointKind::Prismatic => Pose::from_translation(self.axis * q),
            JointKind::Revolute | JointKind::Continuous => {
                Pose::from_rotation(bevy::math::Quat::from_axis_angle(self.axis, q))
            }
        };
        self.origin * motion
    }
}

impl RobotModel {
    /// Links ordered so that every parent comes before its children.
    pub fn tree_order(&self) -> Vec<usize> {
        let mut order = vec![self.root];
        let mut i = 0;
        while i < order.len() {
            let l = order[i];
            order.extend(self.joints.iter().filter(|j| j.parent == l).map(|j| j.child));
            i += 1;
        }
        order
    }

    /// Every link's frame (by link index) with the root at `base` and each joint at
    /// `position(joint)`: the robot's forward kinematics.
    pub fn link_poses(&self, base: Pose, position: impl Fn(&JointModel) -> f32) -> Vec<Pose> {
        let mut pose = vec![base; self.links.len()];
        for l in self.tree_order() {
            if let Some(j) = self.parent_joint(l) {
                pose[l] = pose[j.parent] * j.child_pose(position(j));
            }
        }
        pose
    }

    /// Looks a link up by name.
    pub fn link_index(&self, name: &str) -> Option<usize> {
        self.links.iter().position(|l| l.name == name)
    }

    /// Looks a joint up by name.
    pub fn joint(&self, name: &str) -> Option<&JointModel> {
        self.joints.iter().find(|j| j.name == name)
    }

    /// The joint whose child is `link`, if any (the root has none).
    pub fn parent_joint(&self, link: usize) -> Option<&JointModel> {
        self.joints.iter().find(|j| j.child == link)
    }
}
