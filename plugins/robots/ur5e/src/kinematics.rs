//! The UR5e's published kinematics (standard Denavit–Hartenberg, UR's own table) and its limits.
//! The robot controller knows these, so the tool pose computed from the joint encoders is not
//! privileged: it is what the real UR5e reports as its TCP pose.

use std::sync::OnceLock;

use bevy::math::{DAffine3, DMat3, DMat4, DVec3, Vec3};
use twinbots_sim::rapier::math::Pose;

/// One row of the DH table: T_i = Rz(θ_i) · Tz(d_i) · Tx(a_i) · Rx(α_i).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DhRow {
    pub d: f64,
    pub a: f64,
    pub alpha: f64,
}

const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;

/// UR5e, from Universal Robots' "DH parameters for calculations of kinematics and dynamics".
pub const DH: [DhRow; 6] = [
    DhRow { d: 0.1625, a: 0.0, alpha: HALF_PI },
    DhRow { d: 0.0, a: -0.425, alpha: 0.0 },
    DhRow { d: 0.0, a: -0.3922, alpha: 0.0 },
    DhRow { d: 0.1333, a: 0.0, alpha: HALF_PI },
    DhRow { d: 0.0997, a: 0.0, alpha: -HALF_PI },
    DhRow { d: 0.0996, a: 0.0, alpha: 0.0 },
];

/// Joint names in the URDF, base to wrist.
pub const JOINTS: [&str; 6] =
    ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"];

/// Distance from the flange (tool0) to the suction cup's face (the TCP), along the flange's z.
pub const TOOL_LENGTH: f64 = 0.10;

/// Home: upper arm up, forearm forward, tool pointing straight down 0.39 m above the base.
pub const HOME: [f32; 6] = [0.0, -HALF_PI as f32, HALF_PI as f32, -HALF_PI as f32, -HALF_PI as f32, 0.0];

/// Position range (rad) of every joint but the elbow: ±2π.
pub const JOINT_RANGE: f32 = std::f32::consts::TAU;
/// Position range (rad) of the elbow: ±π, its hardware range (ur_description's limit).
pub const ELBOW_RANGE: f32 = std::f32::consts::PI;
/// Position range (rad) of each joint, base to wrist: the URDF's `<limit lower upper>`.
pub const JOINT_RANGES: [f32; 6] = [JOINT_RANGE, JOINT_RANGE, ELBOW_RANGE, JOINT_RANGE, JOINT_RANGE, JOINT_RANGE];
/// Max joint speed (rad/s).
pub const MAX_JOINT_SPEED: f32 = std::f32::consts::PI;
/// Max joint torque (N·m), base to wrist.
pub const MAX_TORQUE: [f32; 6] = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0];

/// sin α and cos α of each DH row, computed once (the values `DMat4::from_rotation_x` uses).
fn alpha_sin_cos() -> &'static [(f64, f64); 6] {
    static SIN_COS: OnceLock<[(f64, f64); 6]> = OnceLock::new();
    SIN_COS.get_or_init(|| DH.map(|row| row.alpha.sin_cos()))
}

/// T_i = Rz(θ) · Tz(d) · Tx(a) · Rx(α) written out: its entries are the products the four
/// matrices' product forms (its other terms are exact zeros and ones), so the frames are the
/// same numbers at a fraction of the cost — HER relabels through the arm's kinematics about 200
/// times a gradient step.
fn dh_transform(row: &DhRow, (sin_alpha, cos_alpha): (f64, f64), theta: f64) -> DAffine3 {
    let (s, c) = theta.sin_cos();
    DAffine3 {
        matrix3: DMat3::from_cols(
            DVec3::new(c, s, 0.0),
            DVec3::new(-s * cos_alpha, c * cos_alpha, sin_alpha),
            DVec3::new(s * sin_alpha, c * -sin_alpha, cos_alpha),
        ),
        translation: DVec3::new(c * row.a, s * row.a, row.d),
    }
}

/// The DH frames 0 (base) to 6 (flange) in the base frame at joint angles `q`: joint i + 1
/// turns about the z axis of frame i.
pub fn frames(q: &[f32; 6]) -> [DMat4; 7] {
    let alphas = alpha_sin_cos();
    let mut frame = DAffine3::IDENTITY;
    let mut out = [DMat4::IDENTITY; 7];
    for i in 0..6 {
        // Affine products: a 4×4 product's bottom row only adds exact zeros.
        frame *= dh_transform(&DH[i], alphas[i], q[i] as f64);
        out[i + 1] = DMat4::from(frame);
    }
    out
}

/// The flange frame (tool0) in the base frame at joint angles `q`, in double precision.
pub fn flange(q: &[f32; 6]) -> DMat4 {
    frames(q)[6]
}

/// The tool face (the suction cup's, the TCP) from the flange frame: `TOOL_LENGTH` along the
/// flange's z axis.
pub fn tool_face(flange: DMat4) -> DMat4 {
    flange * DMat4::from_translation(DVec3::new(0.0, 0.0, TOOL_LENGTH))
}

/// The TCP's geometric Jacobian at `q`: column i is (z_i × (p − o_i), z_i), the TCP's linear and
/// angular velocity per unit speed of joint i + 1.
pub fn jacobian(q: &[f32; 6]) -> [[f64; 6]; 6] {
    let f = frames(q);
    let tcp = tool_face(f[6]).w_axis.truncate();
    std::array::from_fn(|i| {
        let z = f[i].z_axis.truncate();
        let linear = z.cross(tcp - f[i].w_axis.truncate());
        [linear.x, linear.y, linear.z, z.x, z.y, z.z]
    })
}

/// The TCP (suction cup face) in the base frame at joint angles `q`.
pub fn tcp(q: &[f32; 6]) -> Pose {
    let (_, rotation, translation) = tool_face(flange(q)).to_scale_rotation_translation();
    Pose::from_parts(translation.as_vec3(), rotation.as_quat())
}

/// Angle (rad) between the tool's axis and straight down.
pub fn tilt(tool: &Pose) -> f32 {
    // atan2 of the horizontal part against the downward part: exact near 0, where acos is not.
    let axis = tool.rotation * Vec3::Z;
    axis.truncate().length().atan2(-axis.z)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The frames as the four matrices of each DH row multiply out, 4×4 throughout.
    fn frames_by_full_products(q: &[f32; 6]) -> [DMat4; 7] {
        let mut out = [DMat4::IDENTITY; 7];
        for i in 0..6 {
            let row = &DH[i];
            let t = DMat4::from_rotation_z(q[i] as f64)
                * DMat4::from_translation(DVec3::new(row.a, 0.0, row.d))
                * DMat4::from_rotation_x(row.alpha);
            out[i + 1] = out[i] * t;
        }
        out
    }

    #[test]
    fn the_written_out_frames_are_the_full_products_number_for_number() {
        let mut poses = vec![HOME, [0.0; 6]];
        let mut x = 0.37f32;
        for _ in 0..2000 {
            poses.push(std::array::from_fn(|_| {
                x = (x * 7.31 + 0.17).fract();
                (x - 0.5) * 4.0 * std::f32::consts::PI
            }));
        }
        let tool = DMat4::from_translation(DVec3::new(0.0, 0.0, TOOL_LENGTH)); // as `tool_face`, written out
        for q in &poses {
            let (ours, theirs) = (frames(q), frames_by_full_products(q));
            // `==` on each number: bit for bit but for the sign of a zero.
            assert_eq!(ours.map(|m| m.to_cols_array()), theirs.map(|m| m.to_cols_array()), "at {q:?}");
            let (_, rotation, translation) = (theirs[6] * tool).to_scale_rotation_translation();
            let pose = tcp(q);
            assert_eq!((pose.translation, pose.rotation), (translation.as_vec3(), rotation.as_quat()), "at {q:?}");
        }
    }

    #[test]
    fn zero_pose_is_the_arm_stretched_along_minus_x() {
        let p = tcp(&[0.0; 6]).translation;
        // x: a2 + a3; y: -(d4 + d6 + tool); z: d1 - d5.
        assert!((p - Vec3::new(-0.8172, -0.3329, 0.0628)).length() < 1e-4, "{p}");
    }

    #[test]
    fn jacobian_is_the_derivative_of_the_tcp_position() {
        let q = [0.3, -1.2, 1.4, -1.8, -1.5, 0.4];
        let j = jacobian(&q);
        let h = 1e-3;
        for i in 0..6 {
            let mut plus = q;
            let mut minus = q;
            plus[i] += h;
            minus[i] -= h;
            let numeric = (tcp(&plus).translation - tcp(&minus).translation) / (2.0 * h);
            let analytic = Vec3::new(j[i][0] as f32, j[i][1] as f32, j[i][2] as f32);
            assert!((numeric - analytic).length() < 1e-3, "joint {i}: {numeric} vs {analytic}");
        }
    }

    #[test]
    fn home_points_the_tool_down() {
        let tool = tcp(&HOME);
        assert!(tilt(&tool) < 1e-4);
        assert!((tool.translation - Vec3::new(-0.4919, -0.1333, 0.3879)).length() < 1e-3, "{}", tool.translation);
    }
}
