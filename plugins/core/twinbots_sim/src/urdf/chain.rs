//! The kinematics of a serial chain read from a URDF, in double precision: the tool link's pose
//! in the base link's frame (forward kinematics), its geometric Jacobian, and a resolved-rate
//! step (the joint speeds that move the tool at a given twist), for any chain of revolute,
//! continuous, prismatic and fixed joints with any `origin` and `axis`. Checked against Pinocchio
//! (`python/tests/test_kinematics.py`). Rapier's bodies are single precision; this is what a
//! controller computes with.

use std::path::Path;

use bevy::math::{DMat3, DQuat, DVec3, EulerRot};

use super::UrdfError;

/// One joint of the chain, from its parent link's frame to its child's.
#[derive(Clone, Debug)]
pub struct ChainJoint {
    pub name: String,
    /// The joint frame in the parent link's frame (the URDF's `origin`).
    pub origin: Frame,
    pub motion: Motion,
    /// `lower`/`upper` (rad or m) of a limited joint; none for a continuous or fixed one.
    pub limits: Option<(f64, f64)>,
    /// The URDF's `velocity` and `effort` limits (0: not given).
    pub max_speed: f64,
    pub max_effort: f64,
    /// The child link's `<inertial>` and, joined to it, those of the links hanging from it off
    /// the chain (a gripper's fingers, the links below the tool), their joints at 0: they move
    /// with it.
    pub child_inertia: LinkInertia,
}

/// How a joint moves its child, along or about its unit axis (in the joint frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Motion {
    Fixed,
    Revolute(DVec3),
    Prismatic(DVec3),
}

/// A rigid transform: `p' = rotation · p + translation`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub rotation: DQuat,
    pub translation: DVec3,
}

impl Frame {
    pub const IDENTITY: Frame = Frame { rotation: DQuat::IDENTITY, translation: DVec3::ZERO };

    /// A URDF `origin`: `xyz`, then `rpy` (roll about X, pitch about Y, yaw about Z, fixed axes:
    /// R = Rz(yaw) · Ry(pitch) · Rx(roll)).
    pub fn from_xyz_rpy(xyz: [f64; 3], rpy: [f64; 3]) -> Self {
        Self { rotation: DQuat::from_euler(EulerRot::ZYX, rpy[2], rpy[1], rpy[0]), translation: DVec3::from_array(xyz) }
    }

    /// `self` then `child` (the child's frame expressed in this one's parent).
    pub fn then(&self, child: &Frame) -> Frame {
        Frame {
            rotation: (self.rotation * child.rotation).normalize(),
            translation: self.translation + self.rotation * child.translation,
        }
    }
}

/// A body's inertial parameters (Pinocchio's `Inertia::toDynamicParameters`): m, m·cx, m·cy,
/// m·cz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz (about the link frame's origin).
pub const PARAMS_PER_BODY: usize = 10;

/// A link's mass, centre of mass and inertia about it (the URDF's `<inertial>`), in the link's
/// frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LinkInertia {
    pub mass: f64,
    pub com: DVec3,
    /// About the centre of mass, axes of the link frame.
    pub inertia: DMat3,
}

impl LinkInertia {
    pub const ZERO: LinkInertia = LinkInertia { mass: 0.0, com: DVec3::ZERO, inertia: DMat3::ZERO };

    /// The URDF's `<inertial>`: its `origin` places the centre of mass and turns the inertia's axes.
    pub fn of_urdf(inertial: &urdf_rs::Inertial) -> Self {
        let origin = Frame::from_xyz_rpy(inertial.origin.xyz.0, inertial.origin.rpy.0);
        let i = &inertial.inertia;
        let principal = DMat3::from_cols_array(&[i.ixx, i.ixy, i.ixz, i.ixy, i.iyy, i.iyz, i.ixz, i.iyz, i.izz]);
        let r = DMat3::from_quat(origin.rotation);
        Self { mass: inertial.mass.value, com: origin.translation, inertia: r * principal * r.transpose() }
    }

    /// The ten parameters about the frame's origin (Pinocchio's order).
    pub fn parameters(&self) -> [f64; PARAMS_PER_BODY] {
        let (m, c) = (self.mass, self.com);
        let origin = self.inertia + m * (DMat3::from_diagonal(DVec3::splat(c.dot(c))) - outer(c, c));
        let h = m * c;
        [
            m,
            h.x,
            h.y,
            h.z,
            origin.x_axis.x,
            origin.y_axis.x,
            origin.y_axis.y,
            origin.z_axis.x,
            origin.z_axis.y,
            origin.z_axis.z,
        ]
    }

    /// This inertia seen from a frame in which the link's frame sits at `at`.
    pub(crate) fn moved(&self, at: &Frame) -> LinkInertia {
        let r = DMat3::from_quat(at.rotation);
        LinkInertia {
            mass: self.mass,
            com: at.translation + at.rotation * self.com,
            inertia: r * self.inertia * r.transpose(),
        }
    }

    /// Two rigidly joined links as one (the sum about their common centre of mass).
    pub(crate) fn plus(&self, other: &LinkInertia) -> LinkInertia {
        let mass = self.mass + other.mass;
        if mass <= 0.0 {
            return LinkInertia::ZERO;
        }
        let com = (self.com * self.mass + other.com * other.mass) / mass;
        let shifted = |l: &LinkInertia| {
            let d = l.com - com;
            l.inertia + l.mass * (DMat3::from_diagonal(DVec3::splat(d.dot(d))) - outer(d, d))
        };
        LinkInertia { mass, com, inertia: shifted(self) + shifted(other) }
    }
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The joints from a base link to a tool link, in order from the base.
#[derive(Clone, Debug)]
pub struct Chain {
    pub base: String,
    pub tool: String,
    pub joints: Vec<ChainJoint>,
}

impl Chain {
    /// Reads the chain from `base` to `tool` of the URDF file at `path` (`base` none: the root).
    pub fn from_file(path: &Path, base: Option<&str>, tool: &str) -> anyhow::Result<Chain> {
        let text = std::fs::read_to_string(path).map_err(|source| UrdfError::Io { file: path.into(), source })?;
        let robot = super::parse_urdf_exact(&text, path)?;
        Self::of(&robot, base, tool).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    /// The chain from `base` (none: the root link) to `tool` in a URDF: an error names a link
    /// that is not there, or a tool that is not a descendant of the base.
    pub fn of(robot: &urdf_rs::Robot, base: Option<&str>, tool: &str) -> anyhow::Result<Chain> {
        let has_link = |name: &str| robot.links.iter().any(|l| l.name == name);
        let parent_joint = |link: &str| robot.joints.iter().find(|j| j.child.link == link);
        let root = robot
            .links
            .iter()
            .find(|l| parent_joint(&l.name).is_none())
            .map(|l| l.name.clone())
            .ok_or_else(|| anyhow::anyhow!("no root link (every link is some joint's child)"))?;
        let base = base.map_or(root, str::to_string);
        for link in [&base, &tool.to_string()] {
            anyhow::ensure!(has_link(link), "no link '{link}' in robot '{}'", robot.name);
        }
        let mut joints = Vec::new();
        let mut link = tool.to_string();
        while link != base {
            let Some(joint) = parent_joint(&link) else {
                anyhow::bail!("the tool link '{tool}' is not a descendant of the base link '{base}'")
            };
            anyhow::ensure!(joints.len() <= robot.joints.len(), "the joints from '{tool}' up form a loop");
            joints.push(chain_joint(joint, LinkInertia::ZERO)?);
            link = joint.parent.link.clone();
        }
        joints.reverse();
        for k in 0..joints.len() {
            let child = &robot.joints.iter().find(|j| j.name == joints[k].name).expect("read from it").child.link;
            let next = joints.get(k + 1).map(|j| j.name.clone());
            joints[k].child_inertia = attached(robot, child, next.as_deref(), &Frame::IDENTITY, 0);
        }
        Ok(Chain { base, tool: tool.to_string(), joints })
    }

    /// The joints that move, in chain order (the controller's order unless a robot file says
    /// otherwise).
    pub fn movable(&self) -> impl Iterator<Item = &ChainJoint> {
        self.joints.iter().filter(|j| j.motion != Motion::Fixed)
    }

    /// Degrees of freedom: the joints that move.
    pub fn dof(&self) -> usize {
        self.movable().count()
    }

    /// The tool link's frame in the base link's frame at joint positions `q` (one per movable
    /// joint, in chain order; rad or m).
    pub fn forward(&self, q: &[f64]) -> Frame {
        self.frames(q).1
    }

    /// The geometric Jacobian of the tool link's origin at `q`, in the base frame: rows are
    /// (vx, vy, vz, ωx, ωy, ωz), one column per movable joint (as Pinocchio's
    /// `LOCAL_WORLD_ALIGNED` frame Jacobian).
    pub fn jacobian(&self, q: &[f64]) -> Vec<[f64; 6]> {
        self.forward_and_jacobian(q).1
    }

    /// [`Chain::forward`] and [`Chain::jacobian`] at `q` from one pass along the chain.
    pub fn forward_and_jacobian(&self, q: &[f64]) -> (Frame, Vec<[f64; 6]>) {
        let (axes, tool) = self.frames(q);
        let columns = axes
            .iter()
            .map(|(motion, at)| match *motion {
                Motion::Revolute(axis) => {
                    let linear = axis.cross(tool.translation - *at);
                    [linear.x, linear.y, linear.z, axis.x, axis.y, axis.z]
                }
                Motion::Prismatic(axis) => [axis.x, axis.y, axis.z, 0.0, 0.0, 0.0],
                Motion::Fixed => unreachable!("only movable joints have columns"),
            })
            .collect();
        (tool, columns)
    }

    /// Resolved-rate control: the joint speeds whose tool twist is closest to `twist` (vx, vy,
    /// vz, ωx, ωy, ωz in the base frame), by damped least squares (`damping` in the units of
    /// the twist; 0: the pseudo-inverse), as the UR5e's own controller solves it.
    pub fn joint_speeds(&self, q: &[f64], twist: [f64; 6], damping: f64) -> Vec<f64> {
        use crate::rapier::na::{DMatrix, DVector};
        let columns = self.jacobian(q);
        let j = DMatrix::from_fn(6, columns.len(), |r, c| columns[c][r]);
        let twist = DVector::from_row_slice(&twist);
        // q̇ = Jᵀ (J Jᵀ + λ² I)⁻¹ twist: a 6 × 6 solve whatever the joint count.
        let damped = (damping > 0.0)
            .then(|| (&j * j.transpose() + DMatrix::identity(6, 6) * (damping * damping)).cholesky())
            .flatten();
        let speeds = match damped {
            Some(c) => j.transpose() * c.solve(&twist),
            None => j.pseudo_inverse(1e-12).expect("a non-negative tolerance") * twist,
        };
        speeds.iter().copied().collect()
    }

    /// Each movable joint's origin (where its axis passes) in the base frame at `q`.
    pub fn joint_origins(&self, q: &[f64]) -> Vec<DVec3> {
        self.joint_origins_and_tool(q).0
    }

    /// [`Chain::joint_origins`] and [`Chain::forward`] at `q` from one pass along the chain.
    pub fn joint_origins_and_tool(&self, q: &[f64]) -> (Vec<DVec3>, Frame) {
        let (axes, tool) = self.frames(q);
        (axes.into_iter().map(|(_, at)| at).collect(), tool)
    }

    /// Each movable joint's axis and origin in the base frame at `q`, and the tool's frame.
    fn frames(&self, q: &[f64]) -> (Vec<(Motion, DVec3)>, Frame) {
        assert_eq!(q.len(), self.dof(), "{} joint positions for a chain of {} movable joints", q.len(), self.dof());
        let mut at = Frame::IDENTITY;
        let mut axes = Vec::with_capacity(q.len());
        let mut q = q.iter();
        for joint in &self.joints {
            at = at.then(&joint.origin);
            let motion = match joint.motion {
                Motion::Fixed => continue,
                Motion::Revolute(axis) => {
                    let angle = *q.next().expect("checked length");
                    axes.push((Motion::Revolute(at.rotation * axis), at.translation));
                    Frame { rotation: DQuat::from_axis_angle(axis, angle), translation: DVec3::ZERO }
                }
                Motion::Prismatic(axis) => {
                    let d = *q.next().expect("checked length");
                    axes.push((Motion::Prismatic(at.rotation * axis), at.translation));
                    Frame { rotation: DQuat::IDENTITY, translation: axis * d }
                }
            };
            at = at.then(&motion);
        }
        (axes, at)
    }
}

/// `link`'s inertia (its frame at `at`) with those of every link below it but through the joint
/// `except` (the chain's next), all joints at 0: in `at`'s parent frame.
fn attached(robot: &urdf_rs::Robot, link: &str, except: Option<&str>, at: &Frame, depth: usize) -> LinkInertia {
    let own =
        robot.links.iter().find(|l| l.name == link).map_or(LinkInertia::ZERO, |l| LinkInertia::of_urdf(&l.inertial));
    let mut sum = own.moved(at);
    // A tree has no more levels than joints; a loop ends here.
    if depth > robot.joints.len() {
        return sum;
    }
    for joint in robot.joints.iter().filter(|j| j.parent.link == link && Some(j.name.as_str()) != except) {
        let child = at.then(&Frame::from_xyz_rpy(joint.origin.xyz.0, joint.origin.rpy.0));
        sum = sum.plus(&attached(robot, &joint.child.link, None, &child, depth + 1));
    }
    sum
}

fn chain_joint(joint: &urdf_rs::Joint, child_inertia: LinkInertia) -> anyhow::Result<ChainJoint> {
    let axis = DVec3::from_array(joint.axis.xyz.0);
    let unit = || {
        let n = axis.length();
        anyhow::ensure!(n.is_finite() && n > 1e-12, "joint '{}': its axis {:?} has no direction", joint.name, axis);
        Ok(axis / n)
    };
    let (motion, limited) = match joint.joint_type {
        urdf_rs::JointType::Fixed => (Motion::Fixed, false),
        urdf_rs::JointType::Revolute => (Motion::Revolute(unit()?), true),
        urdf_rs::JointType::Continuous => (Motion::Revolute(unit()?), false),
        urdf_rs::JointType::Prismatic => (Motion::Prismatic(unit()?), true),
        ref other => anyhow::bail!(
            "joint '{}' is {other:?}: a serial chain has revolute, continuous, prismatic and fixed joints",
            joint.name
        ),
    };
    let l = &joint.limit;
    Ok(ChainJoint {
        name: joint.name.clone(),
        origin: Frame::from_xyz_rpy(joint.origin.xyz.0, joint.origin.rpy.0),
        motion,
        limits: limited.then_some((l.lower, l.upper)),
        max_speed: l.velocity,
        max_effort: l.effort,
        child_inertia,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const ARM: &str = r#"<robot name="arm">
      <link name="base"/><link name="a"/><link name="b"/><link name="tool"/><link name="side"/>
      <joint name="j1" type="revolute"><parent link="base"/><child link="a"/>
        <origin xyz="0 0 0.5" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="10" velocity="2"/></joint>
      <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/>
        <origin xyz="0.3 0 0" rpy="0 1.5707963267948966 0"/><axis xyz="0 0 1"/><limit lower="0" upper="0.2" effort="5" velocity="1"/></joint>
      <joint name="flange" type="fixed"><parent link="b"/><child link="tool"/><origin xyz="0 0 0.1"/></joint>
      <joint name="j3" type="continuous"><parent link="base"/><child link="side"/><axis xyz="1 0 0"/></joint>
    </robot>"#;

    fn arm() -> Chain {
        let robot = crate::urdf::parse_urdf_exact(ARM, Path::new("arm.urdf")).unwrap();
        Chain::of(&robot, None, "tool").unwrap()
    }

    #[test]
    fn forward_kinematics_of_a_chain_worked_by_hand() {
        let chain = arm();
        assert_eq!((chain.base.as_str(), chain.dof()), ("base", 2));
        // j1 turns a quarter: the arm points along +y; j2 (along a's x, pitched to point along
        // it) slides 0.1 out, the flange 0.1 further.
        let tool = chain.forward(&[std::f64::consts::FRAC_PI_2, 0.1]);
        let expected = DVec3::new(0.0, 0.5, 0.5);
        assert!((tool.translation - expected).length() < 1e-12, "{:?}", tool.translation);
    }

    #[test]
    fn the_jacobian_is_the_derivative_of_forward_kinematics() {
        let chain = arm();
        let q = [0.7, 0.05];
        let columns = chain.jacobian(&q);
        for (i, column) in columns.iter().enumerate() {
            let h = 1e-6;
            let (mut lo, mut hi) = (q, q);
            lo[i] -= h;
            hi[i] += h;
            let v = (chain.forward(&hi).translation - chain.forward(&lo).translation) / (2.0 * h);
            assert!((v - DVec3::new(column[0], column[1], column[2])).length() < 1e-8, "column {i}: {v:?}");
        }
        // The resolved-rate step reproduces a twist the chain can make.
        let twist = [columns[0][0], columns[0][1], columns[0][2], 0.0, 0.0, 1.0];
        let speeds = chain.joint_speeds(&q, twist, 0.0);
        assert!((speeds[0] - 1.0).abs() < 1e-9 && speeds[1].abs() < 1e-9, "{speeds:?}");
        // Damped, the same within the damping's pull towards zero.
        let damped = chain.joint_speeds(&q, twist, 1e-4);
        assert!((damped[0] - 1.0).abs() < 1e-6 && damped[1].abs() < 1e-6, "{damped:?}");
    }

    #[test]
    fn a_tool_off_the_base_branch_and_unknown_links_are_named() {
        let robot = crate::urdf::parse_urdf_exact(ARM, Path::new("arm.urdf")).unwrap();
        let err = Chain::of(&robot, Some("side"), "tool").unwrap_err().to_string();
        assert!(err.contains("'tool' is not a descendant of the base link 'side'"), "{err}");
        let err = Chain::of(&robot, None, "gripper").unwrap_err().to_string();
        assert!(err.contains("no link 'gripper'"), "{err}");
    }
}
