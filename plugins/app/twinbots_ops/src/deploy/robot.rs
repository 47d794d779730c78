//! The robots a deployment can drive: the built-in UR5e, or a robot file's six-joint arm (a
//! UR10 from its vendor's description, say). Each brings its reach task's controller side (the
//! task's observation over the joints as the controller reports them, its targets, actions as
//! joint speeds, homing) and its shadow; the deployment itself is the same for both.

use std::path::Path;
use std::sync::Arc;

use bevy::math::Vec3;
use rand_chacha::ChaCha8Rng;
use twinbots_sim::urdf::robot_file::RobotFile;
use twinbots_task::shadow::Shadow;
use ur5e::layout::CellLayout;

use crate::ur_sim::ServedArm;

/// The reach task's controller side on a robot, the controller's joint order.
pub trait ReachOnRobot {
    /// A new reach: a target from the task's sampler, no action yet.
    fn new_reach(&mut self, rng: &mut ChaCha8Rng);
    /// The joints as the controller reports them.
    fn read(&mut self, q: &[f64; 6], qd: &[f64; 6]);
    /// The task's observation of the arm as last read.
    fn observation(&mut self) -> Vec<f32>;
    /// Joint speeds for the policy's action.
    fn act(&mut self, action: &[f32]) -> [f64; 6];
    /// Joint speeds that take the arm home.
    fn homing(&self) -> [f64; 6];
    fn is_home(&self) -> bool;
    fn arrived(&self) -> bool;
    fn target(&self) -> Vec3;
    /// The tool's distance to the target (m).
    fn error(&self) -> f32;
}

impl ReachOnRobot for ur5e::deploy::ReachController {
    fn new_reach(&mut self, rng: &mut ChaCha8Rng) {
        ur5e::deploy::ReachController::new_reach(self, rng)
    }
    fn read(&mut self, q: &[f64; 6], qd: &[f64; 6]) {
        ur5e::deploy::ReachController::read(self, q, qd)
    }
    fn observation(&mut self) -> Vec<f32> {
        ur5e::deploy::ReachController::observation(self).to_vec()
    }
    fn act(&mut self, action: &[f32]) -> [f64; 6] {
        ur5e::deploy::ReachController::act(self, action)
    }
    fn homing(&self) -> [f64; 6] {
        ur5e::deploy::ReachController::homing(self)
    }
    fn is_home(&self) -> bool {
        ur5e::deploy::ReachController::is_home(self)
    }
    fn arrived(&self) -> bool {
        ur5e::deploy::ReachController::arrived(self)
    }
    fn target(&self) -> Vec3 {
        ur5e::deploy::ReachController::target(self)
    }
    fn error(&self) -> f32 {
        ur5e::deploy::ReachController::error(self)
    }
}

/// Six values of a six-joint arm's vector (checked six when the arm was taken on).
fn six(v: Vec<f64>) -> [f64; 6] {
    v.try_into().expect("a deployed arm has six joints")
}

impl ReachOnRobot for twinbots_arm::deploy::ReachController {
    fn new_reach(&mut self, rng: &mut ChaCha8Rng) {
        twinbots_arm::deploy::ReachController::new_reach(self, rng)
    }
    fn read(&mut self, q: &[f64; 6], qd: &[f64; 6]) {
        twinbots_arm::deploy::ReachController::read(self, q, qd)
    }
    fn observation(&mut self) -> Vec<f32> {
        twinbots_arm::deploy::ReachController::observation(self).to_vec()
    }
    fn act(&mut self, action: &[f32]) -> [f64; 6] {
        six(twinbots_arm::deploy::ReachController::act(self, action))
    }
    fn homing(&self) -> [f64; 6] {
        six(twinbots_arm::deploy::ReachController::homing(self))
    }
    fn is_home(&self) -> bool {
        twinbots_arm::deploy::ReachController::is_home(self)
    }
    fn arrived(&self) -> bool {
        twinbots_arm::deploy::ReachController::arrived(self)
    }
    fn target(&self) -> Vec3 {
        twinbots_arm::deploy::ReachController::target(self)
    }
    fn error(&self) -> f32 {
        twinbots_arm::deploy::ReachController::error(self)
    }
}

/// A robot a deployment can drive.
#[derive(Clone)]
pub enum Deployable {
    Ur5e,
    /// A robot file's arm: the file's path as the command was given it, the arm.
    File {
        path: String,
        arm: Arc<twinbots_arm::Arm>,
    },
}

impl Deployable {
    /// `robot` as a command's ROBOT argument names it: `ur5e`, or a robot file of a six-joint
    /// arm; any other robot is an error saying which deploy.
    pub fn of(robot: &str) -> anyhow::Result<Self> {
        if RobotFile::is_path(robot) {
            let file = RobotFile::read(Path::new(robot))?;
            let arm = Arc::new(twinbots_arm::Arm::of(file)?);
            anyhow::ensure!(
                arm.dof() == 6 && arm.file.chain.dof() == 6,
                "{robot}: deploy drives six-joint arms through a UR controller's RTDE; the file controls {} ({} in its chain)",
                arm.dof(),
                arm.file.chain.dof()
            );
            return Ok(Self::File { path: robot.to_string(), arm });
        }
        anyhow::ensure!(
            robot == "ur5e",
            "robot '{robot}' has no controller link: ur5e and robot files of six-joint arms deploy (RTDE)"
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
            Self::File { arm, .. } => twinbots_arm::deploy::shadow(arm).expect("a deployed arm has six joints"),
        }
    }

    /// The arm as the UR controller stand-in serves it (the dry run's twin).
    pub fn served_arm(&self) -> anyhow::Result<ServedArm> {
        match self {
            Self::Ur5e => Ok(ServedArm::ur5e()),
            Self::File { path, arm } => ServedArm::of_file(&arm.file, twinbots_arm::robot(Path::new(path))?),
        }
    }
}
