//! The arm a cell study runs: the UR5e (its cell lays out every arena on its own) or a robot
//! file's arm with a `cell` and a `[gripper]` (one app per layout, the arm built standing in
//! it), and what the study reads of either in an arena.

use std::path::Path;
use std::sync::Arc;

use bevy::prelude::*;
use twinbots_arm::Arm;
use twinbots_arm::pick_place::ArmCell;
use twinbots_arm::reach::ReachState;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_task::cell::layout::{CellLayout, Fixtures};
use twinbots_task::cell::program::Stage;
use ur5e::CellState;
use ur5e::cell::CellParts;

use twinbots_run::registry::RobotEntry;

/// The arm of a cell study.
#[derive(Clone)]
pub enum CellArm {
    Ur5e,
    /// A robot file's arm (its own cell the default layout).
    File(Arc<Arm>),
}

/// The arm standing in one layout.
#[derive(Clone)]
pub struct PlacedArm {
    /// Where its base link stands in the cell.
    pub base: Pose,
    /// The fixtures' plates in its base frame.
    pub fixtures: Fixtures,
    /// A robot file's arm, built in the layout.
    file: Option<Arc<Arm>>,
}

impl CellArm {
    /// The arm of `entry`: the UR5e, or the arm of a robot file with a cell and a gripper.
    pub fn of(entry: &RobotEntry) -> anyhow::Result<Self> {
        if entry.name == "ur5e" {
            return Ok(Self::Ur5e);
        }
        anyhow::ensure!(
            RobotFile::is_path(entry.name),
            "cell studies run a pick-and-place program: the UR5e's, or a robot file's arm with a cell and a gripper; {} has none",
            entry.name
        );
        let arm = Arm::of(RobotFile::read(Path::new(entry.name))?)?;
        anyhow::ensure!(
            arm.cell.is_some() && arm.file.gripper.is_some(),
            "{}: a cell study runs the pick-and-place program, which needs the robot file's `cell` and `[gripper]` (docs/robot-files.md)",
            entry.name
        );
        Ok(Self::File(Arc::new(arm)))
    }

    /// Whether a study's `robot = "…"` names this arm: the UR5e by name, a robot file by its
    /// path (relative to the study file, or as given).
    pub fn is(&self, robot: &str, study: &Path) -> bool {
        match self {
            Self::Ur5e => robot == "ur5e",
            Self::File(arm) => {
                let same =
                    |p: &Path| p.canonicalize().ok().is_some_and(|p| arm.file.path.canonicalize().ok() == Some(p));
                same(&study.parent().unwrap_or(Path::new(".")).join(robot)) || same(Path::new(robot))
            }
        }
    }

    /// The layout a study's `[[layout]]` entries change: the UR5e's default cell, or the
    /// robot file's own.
    pub fn default_layout(&self) -> CellLayout {
        match self {
            Self::Ur5e => CellLayout::default(),
            Self::File(arm) => arm.cell.clone().expect("checked in CellArm::of"),
        }
    }

    /// The arm standing in `layout`.
    pub fn placed(&self, layout: &CellLayout) -> anyhow::Result<PlacedArm> {
        Ok(match self {
            Self::Ur5e => PlacedArm { base: layout.base_pose(), fixtures: layout.fixtures(), file: None },
            Self::File(arm) => {
                let arm = Arc::new((**arm).clone().in_cell(Some(layout.clone()))?);
                let fixtures = arm.fixtures().expect("the arm stands in a cell");
                PlacedArm { base: arm.base, fixtures, file: Some(arm) }
            }
        })
    }
}

impl PlacedArm {
    /// Whether the arm brings its tool to `target` (base frame) pointing down: the UR5e's
    /// `controller::reachable`, or [`Arm::reachable`].
    pub fn reachable(&self, target: Vec3) -> bool {
        match &self.file {
            None => ur5e::controller::reachable(target),
            Some(arm) => arm.reachable(target),
        }
    }

    /// The robot `entry` standing in this layout: a robot file's arm described afresh, the
    /// UR5e's as it is (its apps take the layout per arena).
    pub fn entry(&self, entry: &RobotEntry) -> anyhow::Result<RobotEntry> {
        Ok(match &self.file {
            None => entry.clone(),
            Some(arm) => twinbots_arm::describe(Path::new(entry.name), arm.clone()),
        })
    }
}

/// The entities of an arena's cell a study acts on.
pub struct Parts {
    pub part: Entity,
    pub gripper: Entity,
    /// Where a `push-tool` pushes: the UR5e's TCP, a robot file's tool link.
    pub tool: Entity,
}

/// The cell entities of `arena`, the UR5e's or a robot file's arm's.
pub fn cell_parts(world: &World, arena: Entity) -> anyhow::Result<Parts> {
    if let Some(p) = world.get::<CellParts>(arena) {
        return Ok(Parts { part: p.part, gripper: p.gripper, tool: p.tcp });
    }
    let cell = world
        .get::<ArmCell>(arena)
        .ok_or_else(|| anyhow::anyhow!("arena {arena} has no pick-and-place cell to study"))?;
    Ok(Parts { part: cell.part, gripper: cell.gripper, tool: cell.tool })
}

/// The stage of `arena`'s cell program, if it runs one.
pub fn stage(world: &World, arena: Entity) -> Option<Stage> {
    if let Some(state) = world.get::<CellState>(arena) {
        return Some(state.program.stage);
    }
    world.get::<ReachState>(arena)?.program.map(|p| p.stage)
}
