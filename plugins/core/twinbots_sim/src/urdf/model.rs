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
            Shape::Mesh(mesh) => (mesh.hull.clone(), Pose::IDENTITY),
        })
    }
}

/// A triangle mesh read from a mesh file (STL, OBJ, glTF), already scaled.
#[derive(Clone, Debug)]
pub struct TriangleMesh {
    pub vertices: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Its collision shape: the convex hull, of at most [`MAX_HULL_VERTICES`] vertices or a
    /// robot file's `hull_vertices` ([`collision_hull`]), made once when the mesh is read; the
    /// inertia a link takes from its collision geometry is this hull's too.
    pub hull: crate::rapier::parry::shape::SharedShape,
}

/// The most vertices a mesh's collision hull keeps unless a robot file says `hull_vertices`. A
/// CAD export's hull can have thousands (the SO-101's links 441–4,843), and a contact test walks
/// every vertex of a hull: a hull of more is replaced by the hull of its extreme points in this
/// many directions. PhysX (and so Isaac Lab) caps a hull at 255 vertices, Isaac Lab's importer
/// at 64 by default; the collision meshes vendors ship for simulation (the Panda's 18–152, the
/// UR10's 122–243) stay whole.
pub const MAX_HULL_VERTICES: usize = 256;

/// The convex hull of `points` as a collision shape, `None` for a flat or empty set. A hull of
/// more than `max_vertices` vertices is replaced by the hull of its vertices that are farthest
/// along `max_vertices` directions spread evenly over the sphere (a Fibonacci lattice), about
/// the vertices' mean: inscribed in the full hull, every vertex one of its. Besides the contact
/// cost, it keeps parry's polyhedron sound: for hulls of tens of thousands of faces, parry's
/// merge of coplanar faces loses faces (a finely tessellated sphere's hull came out with no
/// volume), which a hull of a few hundred vertices does not meet.
pub fn collision_hull(points: &[Vec3], max_vertices: usize) -> Option<crate::rapier::parry::shape::SharedShape> {
    use crate::rapier::parry::shape::SharedShape;
    let (vertices, _) = crate::rapier::parry::transformation::try_convex_hull(points).ok()?;
    if vertices.len() <= max_vertices {
        return SharedShape::convex_hull(&vertices);
    }
    let centre = vertices.iter().copied().sum::<Vec3>() / vertices.len() as f32;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let mut kept: Vec<usize> = (0..max_vertices)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f32 + 0.5) / max_vertices as f32;
            let (r, angle) = ((1.0 - z * z).sqrt(), golden * i as f32);
            let direction = Vec3::new(r * angle.cos(), r * angle.sin(), z);
            let reach = |k: usize| (vertices[k] - centre).dot(direction);
            // The first of equals, so the choice does not depend on the float order of a tie.
            (0..vertices.len()).fold(0, |best, k| if reach(k) > reach(best) { k } else { best })
        })
        .collect();
    kept.sort_unstable();
    kept.dedup();
    SharedShape::convex_hull(&kept.iter().map(|&k| vertices[k]).collect::<Vec<_>>())
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
