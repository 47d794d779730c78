//! A robot file (`*.toml`): an arm as data. It names the URDF (relative to the file, or
//! `package://` through its `[packages]`), the chain from a base link to a tool link, the
//! controlled joints in the controller's order, how the controller drives them, the home pose
//! and the speed limits the twin's tasks keep to. `assets/robots/ur5.toml` is one; docs/urdf.md
//! lists the keys. Errors name the file and the key.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::chain::Chain;
use super::mesh::{package_path_from_env, resolve_in};
use super::{RobotModel, load_urdf_in};

/// The file as written.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Written {
    urdf: String,
    base: Option<String>,
    tool: String,
    joints: Vec<String>,
    control_period: f64,
    command: Command,
    home: Option<Vec<f64>>,
    speed_limits: Option<Vec<f64>>,
    acceleration_limits: Option<Vec<f64>>,
    safety_factor: Option<f64>,
    policy_period: Option<f64>,
    hull_vertices: Option<usize>,
    solver_iterations: Option<u32>,
    #[serde(default)]
    held_positions: BTreeMap<String, f64>,
    cell: Option<PathBuf>,
    gripper: Option<Gripper>,
    #[serde(default)]
    packages: BTreeMap<String, PathBuf>,
}

/// A vacuum gripper at the tool link, sucking along the tool link's +z (a UR's `tool0`, a
/// Franka's `panda_hand_tcp`: the approach axis): its cup's radius and its bellows' stroke (m).
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gripper {
    pub radius: f64,
    pub stroke: f64,
}

/// The fraction of the vendor's speed limits a task drives the joints at, unless the file says
/// `safety_factor`: half, as the UR5e's tasks drive its joints at half their rated 180°/s.
pub const DEFAULT_SAFETY_FACTOR: f64 = 0.5;
/// How often a trained policy acts unless the file says `policy_period` (s): the UR5e's 40 ms.
pub const DEFAULT_POLICY_PERIOD: f64 = 0.04;
/// A joint this close to either end of its range (rad or m) is at its stop: the twin's
/// protective stop trips there, so a home pose keeps clear of it.
pub const STOP_MARGIN: f64 = 0.01;
/// Where home is when the file does not say: 0, unless that is within this much (rad or m) of
/// a stop; then the middle of the range.
const DEFAULT_HOME_CLEARANCE: f64 = 0.1;
/// The largest `acceleration_limits` entry (rad/s² or m/s²): well past any arm's drives.
pub const MAX_ACCELERATION: f64 = 1000.0;
/// The range of `hull_vertices`: fewer than 8 is hardly a hull, more than 4,096 no robot needs.
pub const HULL_VERTICES: std::ops::RangeInclusive<usize> = 8..=4096;
/// The twin's physics step (s) for a robot file's arm: the UR5e's, whose accuracy is tested.
pub const PHYSICS_STEP: f64 = 0.004;
/// Solver iterations of a physics step unless the file says `solver_iterations`: the UR5e's.
pub const DEFAULT_SOLVER_ITERATIONS: u32 = 8;
/// The range of `solver_iterations`.
pub const SOLVER_ITERATIONS: std::ops::RangeInclusive<u32> = 1..=64;

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
    /// Where the arm rests between tasks (rad or m), the controller's order.
    pub home: Vec<f64>,
    /// Each controlled joint's top speed in the twin's tasks (rad/s or m/s), the controller's
    /// order: the file's `speed_limits` or the URDF's `velocity`, times the safety factor.
    pub speed_limits: Vec<f64>,
    /// Each controlled joint's top acceleration in the twin (rad/s² or m/s²), the controller's
    /// order: the file's `acceleration_limits` times the safety factor. `None`: a URDF has no
    /// acceleration limit, so the drives change speed as fast as their `effort` allows.
    pub acceleration_limits: Option<Vec<f64>>,
    /// Each controlled joint's range (rad or m), the controller's order; ±2π for a continuous joint.
    pub ranges: Vec<(f64, f64)>,
    /// Seconds between a trained policy's actions: a multiple of [`PHYSICS_STEP`].
    pub policy_period: f64,
    /// The file's `[packages]`: a package's name and its folder (relative paths made the file's).
    pub packages: Vec<(String, PathBuf)>,
    /// The most vertices a link's collision hull keeps (`hull_vertices`; see
    /// [`super::MAX_HULL_VERTICES`], the default).
    pub hull_vertices: usize,
    /// How many iterations the physics solves each step in (`solver_iterations`).
    pub solver_iterations: u32,
    /// Movable joints of the URDF outside `joints` (a gripper's fingers) whose drives hold
    /// them at these positions (`[held_positions]`, rad or m; checked against the URDF by the
    /// arm that spawns them). The others outside `joints` move freely.
    pub held_positions: Vec<(String, f64)>,
    /// The cell the arm works in (`cell`: a layout file, docs/cells.md, the path made the
    /// file's), if any: without one it stands on an empty floor.
    pub cell: Option<PathBuf>,
    /// Its vacuum gripper (`[gripper]`), if any.
    pub gripper: Option<Gripper>,
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
        let folder = path.parent().unwrap_or(Path::new("."));
        let packages: Vec<(String, PathBuf)> =
            written.packages.iter().map(|(name, dir)| (name.clone(), folder.join(dir))).collect();
        for (name, dir) in &packages {
            anyhow::ensure!(
                dir.is_dir(),
                "{}: key 'packages.{name}': {} is not a folder",
                path.display(),
                dir.display()
            );
        }
        let urdf = if written.urdf.starts_with("package://") {
            resolve_in(&written.urdf, folder, &packages, &package_path_from_env())
                .map_err(|e| at(anyhow::anyhow!("key 'urdf': {e}")))?
        } else {
            folder.join(&written.urdf)
        };
        let chain = Chain::from_file(&urdf, written.base.as_deref(), &written.tool)
            .map_err(|e| at(anyhow::anyhow!("key 'urdf' ({}), 'base', 'tool': {e:#}", written.urdf)))?;
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
        let joint = |name: &str| chain.movable().find(|j| j.name == name).expect("checked above");
        let ranges: Vec<(f64, f64)> = written
            .joints
            .iter()
            .map(|name| joint(name).limits.unwrap_or((-std::f64::consts::TAU, std::f64::consts::TAU)))
            .collect();
        let n = written.joints.len();
        let home = match written.home {
            Some(home) => {
                anyhow::ensure!(
                    home.len() == n,
                    "{}: key 'home': {} positions for {n} joints",
                    path.display(),
                    home.len()
                );
                for ((value, (lo, hi)), joint) in home.iter().zip(&ranges).zip(&written.joints) {
                    anyhow::ensure!(
                        value.is_finite() && (lo + STOP_MARGIN..=hi - STOP_MARGIN).contains(value),
                        "{}: key 'home': {value} for '{joint}' is outside its range [{lo}, {hi}] less the stops' {STOP_MARGIN}",
                        path.display()
                    );
                }
                home
            }
            // The zero pose, or the middle of a joint's range where zero is at or near a stop.
            None => ranges
                .iter()
                .map(|&(lo, hi)| {
                    let clear = (lo + DEFAULT_HOME_CLEARANCE..=hi - DEFAULT_HOME_CLEARANCE).contains(&0.0);
                    if clear { 0.0 } else { (lo + hi) / 2.0 }
                })
                .collect(),
        };
        let safety = written.safety_factor.unwrap_or(DEFAULT_SAFETY_FACTOR);
        anyhow::ensure!(
            safety.is_finite() && safety > 0.0 && safety <= 1.0,
            "{}: key 'safety_factor': {safety} is not in (0, 1]",
            path.display()
        );
        let vendor: Vec<f64> = match written.speed_limits {
            Some(limits) => {
                anyhow::ensure!(
                    limits.len() == n,
                    "{}: key 'speed_limits': {} limits for {n} joints",
                    path.display(),
                    limits.len()
                );
                limits
            }
            None => written.joints.iter().map(|name| joint(name).max_speed).collect(),
        };
        for (limit, joint) in vendor.iter().zip(&written.joints) {
            anyhow::ensure!(
                limit.is_finite() && *limit > 0.0 && *limit <= 100.0,
                "{}: key 'speed_limits': '{joint}' has no speed limit in (0, 100] in the file or the URDF's <limit velocity> ({limit})",
                path.display()
            );
        }
        if let Some(limits) = &written.acceleration_limits {
            anyhow::ensure!(
                limits.len() == n,
                "{}: key 'acceleration_limits': {} limits for {n} joints",
                path.display(),
                limits.len()
            );
            for (limit, joint) in limits.iter().zip(&written.joints) {
                anyhow::ensure!(
                    limit.is_finite() && *limit > 0.0 && *limit <= MAX_ACCELERATION,
                    "{}: key 'acceleration_limits': {limit} for '{joint}' is not in (0, {MAX_ACCELERATION}]",
                    path.display()
                );
            }
        }
        let policy_period = written.policy_period.unwrap_or(DEFAULT_POLICY_PERIOD);
        let steps = policy_period / PHYSICS_STEP;
        anyhow::ensure!(
            policy_period.is_finite()
                && (PHYSICS_STEP..=1.0).contains(&policy_period)
                && (steps - steps.round()).abs() < 1e-6,
            "{}: key 'policy_period': {policy_period} s is not a multiple of the physics step ({PHYSICS_STEP} s) up to 1 s",
            path.display()
        );
        let hull_vertices = written.hull_vertices.unwrap_or(super::MAX_HULL_VERTICES);
        anyhow::ensure!(
            HULL_VERTICES.contains(&hull_vertices),
            "{}: key 'hull_vertices': {hull_vertices} is not from {} to {}",
            path.display(),
            HULL_VERTICES.start(),
            HULL_VERTICES.end()
        );
        let solver_iterations = written.solver_iterations.unwrap_or(DEFAULT_SOLVER_ITERATIONS);
        anyhow::ensure!(
            SOLVER_ITERATIONS.contains(&solver_iterations),
            "{}: key 'solver_iterations': {solver_iterations} is not from {} to {}",
            path.display(),
            SOLVER_ITERATIONS.start(),
            SOLVER_ITERATIONS.end()
        );
        let cell = written.cell.map(|cell| folder.join(cell));
        if let Some(cell) = &cell {
            anyhow::ensure!(cell.is_file(), "{}: key 'cell': no file {}", path.display(), cell.display());
        }
        if let Some(g) = &written.gripper {
            for (key, value, most) in [("radius", g.radius, 0.5), ("stroke", g.stroke, 0.2)] {
                anyhow::ensure!(
                    value.is_finite() && value > 0.0 && value <= most,
                    "{}: key 'gripper.{key}': {value} m is not in (0, {most}]",
                    path.display()
                );
            }
        }
        Ok(RobotFile {
            path: path.to_path_buf(),
            name,
            urdf,
            chain,
            joints: written.joints,
            control_period: written.control_period,
            command: written.command,
            home,
            speed_limits: vendor.iter().map(|v| v * safety).collect(),
            acceleration_limits: written.acceleration_limits.map(|limits| limits.iter().map(|a| a * safety).collect()),
            ranges,
            policy_period,
            packages,
            hull_vertices,
            solver_iterations,
            held_positions: written.held_positions.into_iter().collect(),
            cell,
            gripper: written.gripper,
        })
    }

    /// The URDF with its meshes, for the simulator: `package://` through the file's
    /// `[packages]`, then `TWINBOTS_PACKAGE_PATH` and `ROS_PACKAGE_PATH`; collision hulls of at
    /// most `hull_vertices` vertices.
    pub fn model(&self) -> anyhow::Result<RobotModel> {
        load_urdf_in(&self.urdf, &self.packages, self.hull_vertices)
            .map_err(|e| anyhow::anyhow!("{}: key 'urdf': {e}", self.path.display()))
    }

    /// Where joint `name` of the URDF starts: its `home` if it is one of `joints`, its
    /// `held_positions` entry, else 0.
    pub fn start_position(&self, name: &str) -> f64 {
        match self.joints.iter().position(|n| n == name) {
            Some(k) => self.home[k],
            None => self.held_positions.iter().find(|(n, _)| n == name).map_or(0.0, |(_, q)| *q),
        }
    }

    /// The chain's joint positions (chain order) of controller-order positions `q`.
    pub fn chain_order(&self, q: &[f64]) -> Vec<f64> {
        self.controller_index().iter().map(|&k| q[k]).collect()
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
        // Defaults: home at zero, half the URDF's 3.15 and 3.2 rad/s, the UR5e's 40 ms policy step.
        assert_eq!(robot.home, vec![0.0; 6]);
        assert_eq!(robot.speed_limits, [3.15, 3.15, 3.15, 3.2, 3.2, 3.2].map(|v| 0.5 * v).to_vec());
        assert_eq!(robot.policy_period, DEFAULT_POLICY_PERIOD);
        assert_eq!(robot.acceleration_limits, None);

        let dir = std::env::temp_dir().join(format!("twinbots-robot-file-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let urdf = ur5.parent().unwrap().join("ur5/ur5_robot.urdf");
        let head = format!(
            "urdf = {:?}\nbase = \"base_link\"\ntool = \"tool0\"\ncontrol_period = 0.008\ncommand = \"position\"\n",
            urdf
        );
        let joints = "joints = [\"shoulder_pan_joint\", \"shoulder_lift_joint\", \"elbow_joint\", \"wrist_1_joint\", \"wrist_2_joint\", \"wrist_3_joint\"]\n";
        let cases = [
            ("unknown.toml", format!("{head}{joints}grip = true\n"), "unknown field `grip`"),
            ("cell.toml", format!("{head}{joints}cell = \"no-cell.toml\"\n"), "key 'cell': no file"),
            (
                "gripper.toml",
                format!("{head}{joints}[gripper]\nradius = 0.02\nstroke = 0\n"),
                "key 'gripper.stroke': 0 m is not in (0, 0.2]",
            ),
            (
                "joint.toml",
                format!("{head}{}", joints.replace("elbow_joint", "knee")),
                "key 'joints': 'knee' is not a movable joint",
            ),
            ("short.toml", format!("{head}joints = [\"elbow_joint\"]\n"), "key 'joints': 1 joints, but the chain"),
            ("tool.toml", format!("{}{joints}", head.replace("tool0", "world")), "not a descendant of the base link"),
            ("period.toml", format!("{}{joints}", head.replace("0.008", "0")), "key 'control_period'"),
            (
                "home.toml",
                format!("{head}{joints}home = [0, 0, 9, 0, 0, 0]\n"),
                "key 'home': 9 for 'elbow_joint' is outside",
            ),
            ("home_len.toml", format!("{head}{joints}home = [0]\n"), "key 'home': 1 positions for 6 joints"),
            (
                "speeds.toml",
                format!("{head}{joints}speed_limits = [1, 1, 0, 1, 1, 1]\n"),
                "'elbow_joint' has no speed limit",
            ),
            (
                "accelerations.toml",
                format!("{head}{joints}acceleration_limits = [10, 10, -1, 10, 10, 10]\n"),
                "key 'acceleration_limits': -1 for 'elbow_joint' is not in (0, 1000]",
            ),
            (
                "accelerations_len.toml",
                format!("{head}{joints}acceleration_limits = [10]\n"),
                "key 'acceleration_limits': 1 limits for 6 joints",
            ),
            ("safety.toml", format!("{head}{joints}safety_factor = 0\n"), "key 'safety_factor'"),
            ("policy.toml", format!("{head}{joints}policy_period = 0.005\n"), "key 'policy_period'"),
            ("hull.toml", format!("{head}{joints}hull_vertices = 3\n"), "key 'hull_vertices': 3 is not from 8 to 4096"),
            (
                "solver.toml",
                format!("{head}{joints}solver_iterations = 0\n"),
                "key 'solver_iterations': 0 is not from 1 to 64",
            ),
            ("packages.toml", format!("{head}{joints}[packages]\nur = \"no/such/folder\"\n"), "key 'packages.ur'"),
        ];
        for (name, text, expected) in cases {
            let path = write(&dir, name, &text);
            let err = format!("{:#}", RobotFile::read(&path).unwrap_err());
            assert!(err.contains(name) && err.contains(expected), "{name}: {err}");
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
