//! The arms twinbots reaches through a UR controller's link (RTDE): the built-in UR5e, or a
//! robot file's six-joint arm (a UR10 from its vendor's description, say). `deploy` drives one,
//! `monitor` follows one, `ur-sim` stands in for one. Each brings its reach task's controller
//! side ([`ReachOnRobot`]: the task's observation over the joints as the controller reports
//! them, its targets, actions as joint speeds, homing), its shadow and the stand-in's arm; the
//! loops themselves are the same for both.

use std::path::Path;
use std::sync::Arc;

use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_task::RobotDescription;
use twinbots_task::on_robot::ReachOnRobot;
use twinbots_task::shadow::Shadow;
use ur5e::layout::CellLayout;

use crate::ur_sim::ServedArm;

/// An arm behind a UR controller's link.
#[derive(Clone)]
pub enum LinkedArm {
    Ur5e,
    /// A robot file's arm: the file's path as the command was given it, the arm, its
    /// description (as `registry::find` gives it) and its shadow, each made once.
    File {
        path: String,
        arm: Arc<twinbots_arm::Arm>,
        robot: Box<RobotDescription>,
        shadow: Box<Shadow>,
    },
}

impl LinkedArm {
    /// `robot` as a command's ROBOT argument names it: `ur5e`, or a robot file of a six-joint
    /// arm; any other robot is an error saying which have a controller link.
    pub fn of(robot: &str) -> anyhow::Result<Self> {
        if RobotFile::is_path(robot) {
            let file = RobotFile::read(Path::new(robot))?;
            let arm = Arc::new(twinbots_arm::Arm::of(file)?);
            // Its shadow takes six joints, as a UR controller does: an error naming the file.
            let shadow = Box::new(twinbots_arm::deploy::shadow(&arm)?);
            let description = Box::new(twinbots_arm::describe(Path::new(robot), arm.clone()));
            return Ok(Self::File { path: robot.to_string(), arm, robot: description, shadow });
        }
        anyhow::ensure!(
            robot == "ur5e",
            "robot '{robot}' has no controller link: the UR5e and robot files of six-joint arms have one (RTDE)"
        );
        Ok(Self::Ur5e)
    }

    /// The name a bundle records (a run's ROBOT).
    pub fn name(&self) -> &str {
        match self {
            Self::Ur5e => "ur5e",
            Self::File { path, .. } => path,
        }
    }

    /// Whether a bundle made for `recorded` (its manifest's robot) is for this robot: the same
    /// built-in name, or a robot file of the same name (a bundle travels without the folder
    /// it was trained in; the joints and control period are checked as well).
    pub fn is(&self, recorded: &str) -> bool {
        match self {
            Self::Ur5e => recorded == "ur5e",
            Self::File { arm, .. } => {
                RobotFile::is_path(recorded)
                    && Path::new(recorded).file_stem().is_some_and(|stem| *stem == *arm.file.name)
            }
        }
    }

    /// The joints in the controller's order.
    pub fn joints(&self) -> Vec<String> {
        match self {
            Self::Ur5e => ur5e::deploy::ROBOT_JOINTS.map(String::from).to_vec(),
            Self::File { arm, .. } => arm.file.joints.clone(),
        }
    }

    /// Seconds between two of the policy's actions.
    pub fn control_period(&self) -> f64 {
        match self {
            Self::Ur5e => ur5e::sim_settings().control_seconds(),
            Self::File { arm, .. } => twinbots_arm::sim_settings(&arm.file).control_seconds(),
        }
    }

    /// Control steps before a reach is given up.
    pub fn episode_steps(&self) -> u32 {
        match self {
            Self::Ur5e => ur5e::reach::EPISODE_STEPS,
            Self::File { .. } => twinbots_arm::reach::EPISODE_STEPS,
        }
    }

    /// The reach's controller side in `cell` (the UR5e's targets avoid its pick fixture).
    pub fn controller(&self, cell: &CellLayout) -> Box<dyn ReachOnRobot> {
        match self {
            Self::Ur5e => {
                let mut controller = ur5e::deploy::ReachController::default();
                controller.state.fixtures = cell.fixtures();
                Box::new(controller)
            }
            Self::File { arm, .. } => Box::new(twinbots_arm::deploy::ReachController::new(arm.clone())),
        }
    }

    /// The shadow at its defaults; the UR5e's keeps out of its cell's obstacles (a robot file's
    /// arm stands in an empty cell).
    pub fn shadow(&self, cell: &CellLayout) -> Shadow {
        match self {
            Self::Ur5e => Shadow { keepouts: ur5e::deploy::keepouts(cell), ..ur5e::deploy::shadow() },
            Self::File { shadow, .. } => (**shadow).clone(),
        }
    }

    /// The arm as the UR controller stand-in serves it (the dry run's twin, the monitor's).
    pub fn served_arm(&self) -> anyhow::Result<ServedArm> {
        match self {
            Self::Ur5e => Ok(ServedArm::ur5e()),
            Self::File { arm, robot, .. } => ServedArm::of_file(&arm.file, (**robot).clone()),
        }
    }
}
