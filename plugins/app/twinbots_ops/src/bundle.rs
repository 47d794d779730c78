//! A deploy bundle (`twinbots export <run> --bundle DIR`): one directory that carries a trained
//! policy to a robot with everything its controller must agree on — the ONNX policy (its
//! observation normaliser folded in), the action's scale and clipping, the joints' names, order
//! and signs, the control period, the limits the shadow enforces, the calibration the policy
//! was trained on, and the twin's version. `deploy` and `robot --policy DIR` refuse a bundle
//! whose robot, joints or control period differ from theirs (docs/deploy.md).

use anyhow::Context;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use twinbots_onnx::OnnxPolicy;

use crate::linked_arm::LinkedArm;

/// The bundle's files.
pub const MANIFEST: &str = "bundle.json";
pub const POLICY: &str = "policy.onnx";
pub const CALIBRATION: &str = "calibration.toml";
pub const CELL: &str = "cell.toml";
/// What `bundle.json`'s `format` says.
pub const FORMAT: &str = "twinbots-bundle/1";

/// `bundle.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    pub format: String,
    /// The twinbots version that trained and exported the policy (the twin's version).
    pub twinbots_version: String,
    pub robot: String,
    pub task: String,
    /// Seconds between two actions, as trained.
    pub control_period_s: f64,
    /// The robot's joints in the order its controller reports them, with the sign that turns a
    /// reported angle into the twin's, and their limits.
    pub joints: Vec<BundleJoint>,
    pub action: ActionMapping,
    /// The observation, by the task's names; raw values in, the normaliser is inside the graph.
    pub observation_names: Vec<String>,
    pub observation_normalization: String,
    /// The limits the twin's shadow checks every command against.
    pub shadow: ShadowLimits,
    /// The calibration file the policy was trained on (`calibration.toml` in the bundle), if any.
    pub calibration: Option<String>,
    /// The cell layout the policy was trained in (`cell.toml`, docs/cells.md), if not the
    /// default: deploy's targets follow its fixtures, the shadow keeps off its obstacles.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cell: Option<String>,
    /// Environment steps of training.
    pub timesteps: u64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BundleJoint {
    pub name: String,
    pub sign: f64,
    /// ± this angle (rad).
    pub range_rad: f64,
    pub max_speed_rad_s: f64,
}

/// How an action becomes a command.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionMapping {
    /// `joint_speeds`: each action value, clipped to `clip`, times `scale` is a joint speed (rad/s).
    pub kind: String,
    /// The joints the action's values drive, in order; the others hold still.
    pub joints: Vec<String>,
    pub scale: JointValues,
    pub clip: [f64; 2],
}

/// A joint figure written once for every joint (the UR5e's action scale, π/2 rad/s) or once
/// per joint of `joints` (a robot file's arm: each joint's task speed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum JointValues {
    All(f64),
    PerJoint(Vec<f64>),
}

impl JointValues {
    /// The values as written: one for all if they are all the same.
    pub fn of(values: &[f64]) -> Self {
        match values.split_first() {
            Some((first, rest)) if rest.iter().all(|v| v == first) => Self::All(*first),
            _ => Self::PerJoint(values.to_vec()),
        }
    }

    /// Joint `k`'s value (`k` below the count [`Self::check`] was given).
    pub fn at(&self, k: usize) -> f64 {
        match self {
            Self::All(v) => *v,
            Self::PerJoint(v) => v[k],
        }
    }

    /// An error naming `key` unless the values are positive numbers, one or `joints` of them.
    fn check(&self, key: &str, joints: usize) -> anyhow::Result<()> {
        let values = match self {
            Self::All(v) => std::slice::from_ref(v),
            Self::PerJoint(v) => v.as_slice(),
        };
        anyhow::ensure!(
            matches!(self, Self::All(_)) || values.len() == joints,
            "{key}: {} values for {joints} joints",
            values.len()
        );
        anyhow::ensure!(values.iter().all(|v| v.is_finite() && *v > 0.0), "{key}: {values:?} are not all positive");
        Ok(())
    }
}

impl std::fmt::Display for JointValues {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::All(v) => write!(f, "{v}"),
            Self::PerJoint(v) => write!(f, "{v:?}"),
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShadowLimits {
    /// rad/s², for every joint or each (a robot file's `acceleration_limits`).
    pub max_acceleration_rad_s2: JointValues,
    pub lookahead_s: f64,
    pub range_margin_rad: f64,
    pub table_clearance_m: f64,
}

/// A bundle read back: its manifest and its loaded policy.
pub struct Bundle {
    pub dir: PathBuf,
    pub manifest: Manifest,
    pub policy: OnnxPolicy,
    /// The cell (`manifest.cell`), else the default one.
    pub cell: ur5e::layout::CellLayout,
    /// The robot it drives.
    pub robot: LinkedArm,
}

/// What a robot's deployment needs: the UR5e's, or a robot file's six-joint arm's (its joints,
/// their ranges and task speeds from the file and its URDF).
pub fn manifest_for(
    robot: &LinkedArm,
    metadata: &twinbots_onnx::PolicyMetadata,
    calibration: Option<String>,
    cell: Option<String>,
) -> anyhow::Result<Manifest> {
    anyhow::ensure!(
        metadata.task == "reach",
        "task '{}' has no deployment yet: a UR controller's program drives the reach's joint speeds (a learned pick-and-place moves the tool and the suction); `export --onnx` writes its policy alone",
        metadata.task
    );
    let shadow = robot.shadow(&Default::default());
    let (joints, action) = match robot {
        LinkedArm::Ur5e => {
            use ur5e::kinematics::{JOINT_RANGES, MAX_JOINT_SPEED};
            let joints = ur5e::deploy::ROBOT_JOINTS
                .iter()
                .enumerate()
                .map(|(j, name)| BundleJoint {
                    name: name.to_string(),
                    sign: ur5e::deploy::JOINT_SIGNS[j],
                    range_rad: decimal(JOINT_RANGES[j]),
                    max_speed_rad_s: decimal(MAX_JOINT_SPEED),
                })
                .collect();
            let action = ActionMapping {
                kind: "joint_speeds".into(),
                joints: ur5e::deploy::ROBOT_JOINTS[..ur5e::deploy::COMMANDED_JOINTS]
                    .iter()
                    .map(|s| s.to_string())
                    .collect(),
                scale: JointValues::All(decimal(ur5e::arm::ACTION_SPEED)),
                clip: [-1.0, 1.0],
            };
            (joints, action)
        }
        LinkedArm::File { arm, .. } => {
            let f = &arm.file;
            let joints = (f.joints.iter().zip(&f.ranges).zip(&f.speed_limits))
                .map(|((name, &(lo, hi)), &speed)| BundleJoint {
                    name: name.clone(),
                    sign: 1.0,
                    range_rad: lo.abs().max(hi.abs()),
                    max_speed_rad_s: speed,
                })
                .collect();
            let action = ActionMapping {
                kind: "joint_speeds".into(),
                joints: f.joints.clone(),
                scale: JointValues::PerJoint(f.speed_limits.clone()),
                clip: [-1.0, 1.0],
            };
            (joints, action)
        }
    };
    Ok(Manifest {
        format: FORMAT.into(),
        twinbots_version: metadata.twinbots_version.clone(),
        robot: robot.name().into(),
        task: metadata.task.clone(),
        // To the microsecond, as the twin's timing is set (0.04, not 10 × 0.004 in f32).
        control_period_s: (metadata.control_period_s as f64 * 1e6).round() / 1e6,
        joints,
        action,
        observation_names: metadata.observation_names.clone(),
        observation_normalization: if metadata.normalizes_observations { "folded" } else { "none" }.into(),
        shadow: ShadowLimits {
            max_acceleration_rad_s2: JointValues::of(&shadow.max_acceleration),
            lookahead_s: shadow.lookahead,
            range_margin_rad: shadow.range_margin,
            table_clearance_m: shadow.table_clearance,
        },
        calibration,
        cell,
        timesteps: metadata.timesteps,
    })
}

/// An f32 as the decimal it was written as (0.04, not 0.04000000283…), for the manifest.
fn decimal(v: f32) -> f64 {
    v.to_string().parse().expect("an f32 prints as a number")
}

/// Writes a bundle to `dir` (all files first into `dir.partial`, then renamed, so a bundle is
/// whole or absent). An existing bundle there is replaced; any other existing path is an error.
pub fn write(
    dir: &Path,
    manifest: &Manifest,
    policy_bytes: &[u8],
    calibration_text: Option<&str>,
    cell_text: Option<&str>,
) -> anyhow::Result<()> {
    if dir.exists() {
        anyhow::ensure!(
            dir.join(MANIFEST).is_file(),
            "{} exists and is not a bundle: choose another --bundle",
            dir.display()
        );
    }
    let partial = dir.with_extension("partial");
    let named = |p: &Path| p.display().to_string();
    if partial.exists() {
        std::fs::remove_dir_all(&partial).with_context(|| named(&partial))?;
    }
    std::fs::create_dir_all(&partial).with_context(|| named(&partial))?;
    let write = |name: &str, bytes: &[u8]| {
        std::fs::write(partial.join(name), bytes).with_context(|| named(&partial.join(name)))
    };
    write(POLICY, policy_bytes)?;
    if let Some(text) = calibration_text {
        write(CALIBRATION, text.as_bytes())?;
    }
    if let Some(text) = cell_text {
        write(CELL, text.as_bytes())?;
    }
    write(MANIFEST, (serde_json::to_string_pretty(manifest)? + "\n").as_bytes())?;
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| named(dir))?;
    }
    std::fs::rename(&partial, dir).with_context(|| named(dir))?;
    Ok(())
}

impl Bundle {
    /// Reads a bundle; a missing file, a manifest of another format or one that disagrees with
    /// its policy's own metadata is an error naming it.
    pub fn read(dir: &Path) -> anyhow::Result<Self> {
        Self::read_as(dir, None)
    }

    /// Reads a bundle for `robot`, or (none) the robot its manifest names.
    fn read_as(dir: &Path, robot: Option<LinkedArm>) -> anyhow::Result<Self> {
        let path = dir.join(MANIFEST);
        let text = std::fs::read_to_string(&path).map_err(|e| {
            anyhow::anyhow!("{}: {e} (is {} a bundle of `twinbots export --bundle`?)", path.display(), dir.display())
        })?;
        let manifest: Manifest = serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        anyhow::ensure!(
            manifest.format == FORMAT,
            "{}: format '{}', this twinbots reads '{FORMAT}'",
            path.display(),
            manifest.format
        );
        let policy = OnnxPolicy::load(&dir.join(POLICY))?;
        let m = &policy.metadata;
        anyhow::ensure!(
            m.robot == manifest.robot && m.task == manifest.task && m.observation_names == manifest.observation_names,
            "{}: the manifest (robot {}, task {}) disagrees with its policy (robot {}, task {})",
            dir.display(),
            manifest.robot,
            manifest.task,
            m.robot,
            m.task
        );
        let joints = manifest.joints.len();
        (manifest.action.scale.check("action.scale", joints))
            .and_then(|()| manifest.shadow.max_acceleration_rad_s2.check("shadow.max_acceleration_rad_s2", joints))
            .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        if let Some(file) = &manifest.calibration {
            anyhow::ensure!(
                dir.join(file).is_file(),
                "{}: the manifest names calibration '{file}', which is missing",
                dir.display()
            );
        }
        let cell = match &manifest.cell {
            Some(file) => ur5e::layout::CellLayout::read(&dir.join(file))
                .map_err(|e| anyhow::anyhow!("{}: the manifest's cell: {e}", dir.display()))?,
            None => Default::default(),
        };
        let robot = match robot {
            Some(robot) => robot,
            None => LinkedArm::of(&manifest.robot).map_err(|e| anyhow::anyhow!("{}: its robot: {e}", dir.display()))?,
        };
        Ok(Self { dir: dir.to_path_buf(), manifest, policy, cell, robot })
    }

    /// [`Self::read`] for `robot` (a command's ROBOT argument): an error unless the bundle is
    /// for it, with its joints (names and order) and control period; a robot file's bundle
    /// needs the robot file, found as the command names it, wherever the bundle was made.
    pub fn read_for(dir: &Path, robot: &str) -> anyhow::Result<Self> {
        let bundle = Self::read_as(dir, Some(LinkedArm::of(robot)?))?;
        let arm = &bundle.robot;
        anyhow::ensure!(
            arm.is(&bundle.manifest.robot),
            "the bundle {} is for the robot '{}', not '{robot}'",
            dir.display(),
            bundle.manifest.robot
        );
        let joints = arm.joints();
        let names: Vec<&str> = joints.iter().map(String::as_str).collect();
        bundle.check_joints(&names, arm.control_period())?;
        Ok(bundle)
    }

    /// An error unless this bundle fits `robot` with these joints (controller order) and
    /// control period (s).
    pub fn check(&self, robot: &str, joints: &[&str], control_period_s: f64) -> anyhow::Result<()> {
        let m = &self.manifest;
        anyhow::ensure!(
            m.robot == robot,
            "the bundle {} is for the robot '{}', not '{robot}'",
            self.dir.display(),
            m.robot
        );
        self.check_joints(joints, control_period_s)
    }

    /// An error unless this bundle's joints are these (names and order) and its policy acts
    /// every `control_period_s`.
    fn check_joints(&self, joints: &[&str], control_period_s: f64) -> anyhow::Result<()> {
        let m = &self.manifest;
        let names: Vec<&str> = m.joints.iter().map(|j| j.name.as_str()).collect();
        anyhow::ensure!(
            names == joints,
            "the bundle's joints {names:?} are not this robot's {joints:?} (names and order must match)"
        );
        anyhow::ensure!(
            (m.control_period_s - control_period_s).abs() < 1e-6,
            "the bundle's policy acts every {} s, this robot's task every {control_period_s} s",
            m.control_period_s
        );
        Ok(())
    }
}
