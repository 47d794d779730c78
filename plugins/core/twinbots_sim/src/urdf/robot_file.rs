//! A robot file (`*.toml`): an arm as data. It names the URDF (relative to the file), the chain
//! from a base link to a tool link, the controlled joints in the controller's order and how the
//! controller drives them. `assets/robots/ur5.toml` is one; docs/urdf.md lists the keys. Errors
//! name the file and the key.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::chain::Chain;

/// The file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Written {
    urdf: PathBuf,
    base: Option<String>,
    tool: String,
    joints: Vec<String>,
    control_period: f64,
    command: Command,
}

/// What the controller sends its joints each period.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Command {
    Position,
    Speed,
}

/// A robot file, read and checked against its URDF.
#[derive(Clone, Debug)]
pub struct RobotFile {
    pub path: PathBuf,
    /// The file's name without `.toml`.
    pub name: String,
    pub urdf: PathBuf,
    pub chain: Chain,
    /// The controlled joints, the controller's order.
    pub joints: Vec<String>,
    /// Seconds between commands.
    pub control_period: f64,
    pub command: Command,
}

impl RobotFile {
    /// Whether `robot` (a command's ROBOT argument) names a robot file rather than a built-in robot.
    pub fn is_path(robot: &str) -> bool {
        robot.ends_with(".toml")
    }

    /// Reads and checks the robot file at `path`.
    pub fn read(path: &Path) -> anyhow::Result<RobotFile> {
        let text = std::fs::read_to_string(path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
        Self::parse(&text, path)
    }

    /// Checks `text` as the robot file at `path` (its URDF is found relative to `path`).
    pub fn parse(text: &str, path: &Path) -> anyhow::Result<RobotFile> {
        let at = |e: anyhow::Error| anyhow::anyhow!("{}: {e:#}", path.display());
        let written: Written = toml::from_str(text).map_err(|e| at(anyhow::anyhow!("{}", e.to_string().trim_end())))?;
        let urdf = path.parent().unwrap_or(Path::new(".")).join(&written.urdf);
        let chain = Chain::from_file(&urdf, written.base.as_deref(), &written.tool)
            .map_err(|e| at(anyhow::anyhow!("key 'urdf' ({}), 'base', 'tool': {e:#}", written.urdf.display())))?;
        let movable: Vec<&str> = chain.movable().map(|j| j.name.as_str()).collect();
        for (k, joint) in written.joints.iter().enumerate() {
            anyhow::ensure!(
                movable.contains(&joint.as_str()),
                "{}: key 'joints': '{joint}' is not a movable joint of the chain from '{}' to '{}' ({})",
                path.display(),
                chain.base,
                chain.tool,
                movable.join(", ")
            );
            anyhow::ensure!(!written.joints[..k].contains(joint), "{}: key 'joints': '{joint}' twice", path.display());
        }
        anyhow::ensure!(
            written.joints.len() == movable.len(),
            "{}: key 'joints': {} joints, but the chain from '{}' to '{}' moves {} ({})",
            path.display(),
            written.joints.len(),
            chain.base,
            chain.tool,
            movable.len(),
            movable.join(", ")
        );
        anyhow::ensure!(
            written.control_period.is_finite() && (1e-4..=1.0).contains(&written.control_period),
            "{}: key 'control_period': {} s is not from 0.0001 to 1",
            path.display(),
            written.control_period
        );
        let name = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
        Ok(RobotFile {
            path: path.to_path_buf(),
            name,
            urdf,
            chain,
            joints: written.joints,
            control_period: written.control_period,
            command: written.command,
        })
    }

    /// Where each of the chain's movable joints is in the controller's order.
    pub fn controller_index(&self) -> Vec<usize> {
        self.chain
            .movable()
            .map(|j| self.joints.iter().position(|n| *n == j.name).expect("checked on reading"))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn the_ur5_file_reads_and_bad_files_are_named() {
        let ur5 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../assets/robots/ur5.toml");
        let robot = RobotFile::read(&ur5).unwrap();
        assert_eq!((robot.name.as_str(), robot.chain.dof(), robot.control_period), ("ur5", 6, 0.008));
        assert_eq!(robot.controller_index(), vec![0, 1, 2, 3, 4, 5]);

        let dir = std::env::temp_dir().join(format!("twinbots-robot-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let urdf = ur5.parent().unwrap().join("ur5/ur5_robot.urdf");
        let head = format!(
            "urdf = {:?}\nbase = \"base_link\"\ntool = \"tool0\"\ncontrol_period = 0.008\ncommand = \"position\"\n",
            urdf
        );
        let joints = "joints = [\"shoulder_pan_joint\", \"shoulder_lift_joint\", \"elbow_joint\", \"wrist_1_joint\", \"wrist_2_joint\", \"wrist_3_joint\"]\n";
        let cases = [
            ("unknown.toml", format!("{head}{joints}gripper = true\n"), "unknown field `gripper`"),
            (
                "joint.toml",
                format!("{head}{}", joints.replace("elbow_joint", "knee")),
                "key 'joints': 'knee' is not a movable joint",
            ),
            ("short.toml", format!("{head}joints = [\"elbow_joint\"]\n"), "key 'joints': 1 joints, but the chain"),
            ("tool.toml", format!("{}{joints}", head.replace("tool0", "world")), "not a descendant of the base link"),
            ("period.toml", format!("{}{joints}", head.replace("0.008", "0")), "key 'control_period'"),
        ];
        for (name, text, expected) in cases {
            let path = write(&dir, name, &text);
            let err = format!("{:#}", RobotFile::read(&path).unwrap_err());
            assert!(err.contains(name) && err.contains(expected), "{name}: {err}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
