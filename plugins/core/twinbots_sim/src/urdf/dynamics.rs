//! The rigid-body dynamics of a serial chain read from a URDF, in double precision: the joint
//! efforts that move it at given positions, speeds and accelerations under gravity (inverse
//! dynamics, by the recursive Newton–Euler algorithm), and the same efforts as a linear function
//! of the links' inertial parameters (the regressor, what a real arm's calibration fits). Checked
//! against Pinocchio's `rnea` and `computeJointTorqueRegressor` (`python/tests/test_kinematics.py`).
//!
//! A link's ten inertial parameters are Pinocchio's (`Inertia::toDynamicParameters`): mass `m`,
//! first moment `m·c` (x, y, z) and the inertia about the link frame's origin (xx, xy, yy, xz,
//! yz, zz), in the link's frame. Links joined by fixed joints move as one body, their parameters
//! summed in the frame of the movable joint's child; links hanging off the chain (a gripper's
//! fingers, the links below the tool) join the body they hang from, their joints at 0.

use bevy::math::{DMat3, DQuat, DVec3};

use super::chain::{Chain, Frame, Motion};
pub use super::chain::{LinkInertia, PARAMS_PER_BODY};

/// Gravity as Pinocchio and a URDF's world take it: 9.81 m/s² down the base frame's z axis.
pub const GRAVITY: DVec3 = DVec3::new(0.0, 0.0, -9.81);

/// One moving body: the frame of its joint in the previous body's frame, the joint's motion,
/// and the body's inertial parameters in its own (the joint's child) frame.
#[derive(Clone, Debug)]
struct Body {
    origin: Frame,
    motion: Motion,
    parameters: [f64; PARAMS_PER_BODY],
}

/// The chain's moving bodies, base to tool: what inverse dynamics needs.
#[derive(Clone, Debug)]
pub struct Dynamics {
    bodies: Vec<Body>,
}

/// One body's parameters as the Newton–Euler step uses them.
struct Inertial {
    m: f64,
    h: DVec3,
    i: DMat3,
}

impl Inertial {
    fn of(p: &[f64]) -> Self {
        Self {
            m: p[0],
            h: DVec3::new(p[1], p[2], p[3]),
            i: DMat3::from_cols_array(&[p[4], p[5], p[7], p[5], p[6], p[8], p[7], p[8], p[9]]),
        }
    }
}

impl Dynamics {
    /// The bodies of `chain`: each movable joint's child with the links fixed to it.
    pub fn of(chain: &Chain) -> Self {
        let mut bodies: Vec<Body> = Vec::new();
        // Fixed joints before the next movable one: their frames lead to its origin, their
        // links' inertia joins the body before them.
        let mut pending = Frame::IDENTITY;
        let mut inertia = LinkInertia::ZERO;
        let close = |bodies: &mut Vec<Body>, inertia: &LinkInertia| {
            if let Some(last) = bodies.last_mut() {
                last.parameters = inertia.parameters();
            }
        };
        for joint in &chain.joints {
            let child = joint.child_inertia;
            match joint.motion {
                Motion::Fixed => {
                    pending = pending.then(&joint.origin);
                    if !bodies.is_empty() {
                        inertia = inertia.plus(&child.moved(&pending));
                    }
                }
                motion => {
                    close(&mut bodies, &inertia);
                    bodies.push(Body {
                        origin: pending.then(&joint.origin),
                        motion,
                        parameters: [0.0; PARAMS_PER_BODY],
                    });
                    pending = Frame::IDENTITY;
                    inertia = child;
                }
            }
        }
        close(&mut bodies, &inertia);
        Self { bodies }
    }

    /// Degrees of freedom.
    pub fn dof(&self) -> usize {
        self.bodies.len()
    }

    /// Every body's ten parameters, base to tool, as the URDF gives them.
    pub fn parameters(&self) -> Vec<f64> {
        self.bodies.iter().flat_map(|b| b.parameters).collect()
    }

    /// The joint efforts (N·m or N, on each joint's child) that move the chain at `q`, `qd`,
    /// `qdd` under `gravity` (in the base frame), with the URDF's inertial parameters.
    pub fn inverse(&self, q: &[f64], qd: &[f64], qdd: &[f64], gravity: DVec3) -> Vec<f64> {
        self.inverse_with(&self.parameters(), q, qd, qdd, gravity)
    }

    /// [`Dynamics::inverse`] with other inertial parameters (`PARAMS_PER_BODY` a body).
    pub fn inverse_with(&self, parameters: &[f64], q: &[f64], qd: &[f64], qdd: &[f64], gravity: DVec3) -> Vec<f64> {
        assert_eq!(parameters.len(), self.dof() * PARAMS_PER_BODY, "{PARAMS_PER_BODY} parameters a body");
        self.backward(parameters, &self.forward(q, qd, qdd, gravity))
    }

    /// The regressor at `q`, `qd`, `qdd`: efforts = regressor · parameters, row-major
    /// (`dof` rows of `dof · PARAMS_PER_BODY`). Inverse dynamics is linear in the parameters,
    /// so each column is the efforts with that one parameter at 1 and the rest at 0; the
    /// bodies' motion, which the parameters do not change, is found once for all of them.
    pub fn regressor(&self, q: &[f64], qd: &[f64], qdd: &[f64], gravity: DVec3) -> Vec<f64> {
        let (n, cols) = (self.dof(), self.dof() * PARAMS_PER_BODY);
        let motion = self.forward(q, qd, qdd, gravity);
        let mut out = vec![0.0; n * cols];
        let mut unit = vec![0.0; cols];
        for c in 0..cols {
            unit[c] = 1.0;
            for (row, t) in self.backward(&unit, &motion).into_iter().enumerate() {
                out[row * cols + c] = t;
            }
            unit[c] = 0.0;
        }
        out
    }

    /// The forward pass: each body's rotation from its parent's frame, its origin there, and
    /// its angular velocity, angular acceleration and origin's linear acceleration in its own
    /// frame (gravity as the base accelerating upwards).
    fn forward(&self, q: &[f64], qd: &[f64], qdd: &[f64], gravity: DVec3) -> Vec<BodyMotion> {
        let n = self.dof();
        assert!(q.len() == n && qd.len() == n && qdd.len() == n, "{n} joints: q, qd, qdd of that length");
        let mut out = Vec::with_capacity(n);
        let (mut w, mut dw, mut a) = (DVec3::ZERO, DVec3::ZERO, -gravity);
        for (k, body) in self.bodies.iter().enumerate() {
            let (turn, slide, axis) = match body.motion {
                Motion::Revolute(axis) => (DQuat::from_axis_angle(axis, q[k]), DVec3::ZERO, axis),
                Motion::Prismatic(axis) => (DQuat::IDENTITY, axis * q[k], axis),
                Motion::Fixed => unreachable!("bodies move"),
            };
            let rotation = DMat3::from_quat(body.origin.rotation * turn);
            let offset = body.origin.translation + body.origin.rotation * slide;
            let back = rotation.transpose();
            // The parent's frame's motion at this body's origin, in this body's frame.
            let a_here = back * (a + dw.cross(offset) + w.cross(w.cross(offset)));
            let (w_in, dw_in) = (back * w, back * dw);
            match body.motion {
                Motion::Revolute(_) => {
                    w = w_in + axis * qd[k];
                    dw = dw_in + axis * qdd[k] + w_in.cross(axis * qd[k]);
                    a = a_here;
                }
                _ => {
                    w = w_in;
                    dw = dw_in;
                    a = a_here + axis * qdd[k] + 2.0 * w_in.cross(axis * qd[k]);
                }
            }
            out.push(BodyMotion { rotation, offset, w, dw, a });
        }
        out
    }

    /// The backward pass with `parameters`: the force and moment each body's joint transmits,
    /// in the body's frame, projected on its axis.
    fn backward(&self, parameters: &[f64], motion: &[BodyMotion]) -> Vec<f64> {
        let n = self.dof();
        let mut tau = vec![0.0; n];
        let (mut f, mut m) = (DVec3::ZERO, DVec3::ZERO);
        for k in (0..n).rev() {
            let body = Inertial::of(&parameters[k * PARAMS_PER_BODY..(k + 1) * PARAMS_PER_BODY]);
            let BodyMotion { w, dw, a, .. } = motion[k];
            let own_f = body.m * a + dw.cross(body.h) + w.cross(w.cross(body.h));
            let own_m = body.i * dw + w.cross(body.i * w) + body.h.cross(a);
            if k + 1 < n {
                let (r, p) = (motion[k + 1].rotation, motion[k + 1].offset);
                let child_f = r * f;
                m = own_m + r * m + p.cross(child_f);
                f = own_f + child_f;
            } else {
                f = own_f;
                m = own_m;
            }
            tau[k] = match self.bodies[k].motion {
                Motion::Revolute(axis) => axis.dot(m),
                Motion::Prismatic(axis) => axis.dot(f),
                Motion::Fixed => unreachable!("bodies move"),
            };
        }
        tau
    }
}

/// One body's place and motion at a state, from the forward pass.
#[derive(Clone, Copy)]
struct BodyMotion {
    /// From its parent body's frame.
    rotation: DMat3,
    /// Its origin in its parent body's frame.
    offset: DVec3,
    w: DVec3,
    dw: DVec3,
    a: DVec3,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// A pendulum of point mass m at length l on a horizontal axis, under a fixed flange.
    const PENDULUM: &str = r#"<robot name="pendulum">
      <link name="base"/>
      <link name="arm"><inertial><origin xyz="0.5 0 0"/><mass value="2"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>
      <link name="tip"><inertial><origin xyz="0 0 0"/><mass value="1"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>
      <joint name="hinge" type="revolute"><parent link="base"/><child link="arm"/>
        <origin xyz="0 0 1" rpy="0 0 0"/><axis xyz="0 1 0"/><limit lower="-3" upper="3" effort="100" velocity="2"/></joint>
      <joint name="flange" type="fixed"><parent link="arm"/><child link="tip"/><origin xyz="1 0 0"/></joint>
    </robot>"#;

    fn pendulum() -> Dynamics {
        let robot = crate::urdf::parse_urdf_exact(PENDULUM, Path::new("pendulum.urdf")).unwrap();
        Dynamics::of(&Chain::of(&robot, None, "tip").unwrap())
    }

    #[test]
    fn a_pendulum_worked_by_hand() {
        let d = pendulum();
        assert_eq!(d.dof(), 1);
        // Horizontal (q = 0, the arm along +x): a weight at +x turns it positively about +y (x
        // towards -z) with a moment of (2 · 0.5 + 1 · 1) · 9.81; holding it takes the opposite.
        let hold = d.inverse(&[0.0], &[0.0], &[0.0], GRAVITY)[0];
        assert!((hold + 19.62).abs() < 1e-12, "{hold}");
        // Angular acceleration about the hinge: moment of inertia 2 · 0.25 + 1 · 1 = 1.5.
        let spin = d.inverse(&[std::f64::consts::FRAC_PI_2], &[3.0], &[2.0], DVec3::ZERO)[0];
        assert!((spin - 3.0).abs() < 1e-12, "{spin}");
    }

    #[test]
    fn the_regressor_times_the_parameters_is_the_effort() {
        let d = pendulum();
        let (q, qd, qdd) = ([0.3], [-1.2], [0.7]);
        let y = d.regressor(&q, &qd, &qdd, GRAVITY);
        let p = d.parameters();
        let from_y: f64 = y.iter().zip(&p).map(|(a, b)| a * b).sum();
        let direct = d.inverse(&q, &qd, &qdd, GRAVITY)[0];
        assert!((from_y - direct).abs() < 1e-12, "{from_y} vs {direct}");
    }
}
