//! What a robot's task is to every front: its spaces, observation names, reward range, goal and
//! solved criterion ([`TaskSpec`]), and the design pattern (paper §3) it runs under.

use crate::episode::SolvedCriterion;
use crate::goal::GoalSpec;
use crate::spaces::Space;

/// The paper's three ways (§3) to put a robot and its RL model together.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum DesignPattern {
    /// 1. RLRobot + RLModel: the task reads the robot's sensors and may use the Supervisor.
    #[default]
    Supervised,
    /// 2. SupervisorRobot + SlaveRobot: the slave only has sensors, actuators and a radio; the
    ///    supervisor robot relays readings to the model and actions back, one step late each way.
    Radio,
    /// 3. Supervisor-free: a RobotServer hosts the model; the robot's Communicator talks to it.
    Server,
}

impl DesignPattern {
    /// From the paper's numbering (1, 2, 3).
    pub fn from_number(n: u8) -> Option<Self> {
        match n {
            1 => Some(Self::Supervised),
            2 => Some(Self::Radio),
            3 => Some(Self::Server),
            _ => None,
        }
    }

    pub fn number(self) -> u8 {
        match self {
            Self::Supervised => 1,
            Self::Radio => 2,
            Self::Server => 3,
        }
    }
}

/// What a robot's task promises: its spaces, the meaning of its observation, and when it counts
/// as solved. Built from the task's terms, so it cannot drift from what the task computes.
#[derive(Clone, Debug)]
pub struct TaskSpec {
    pub name: String,
    pub observation_space: Space,
    pub action_space: Space,
    pub solved: Option<SolvedCriterion>,
    /// What each observation value is, in order (see [`TaskTerms::observation_names`]).
    pub observation_names: Vec<String>,
    /// The reward's terms, whose per-episode sums each episode's summary logs.
    pub reward_terms: Vec<String>,
    /// The termination terms, by name (what a step's `ended_by` names).
    pub termination_terms: Vec<String>,
    /// The lowest and highest reward of one step ([`TaskTerms::reward_range`]); a RobotServer
    /// refuses rewards outside it.
    pub reward_range: (f32, f32),
    /// Where a working sensor's readings lie, per observation value (a Box; each term's
    /// declared range, else its bounds): a RobotServer refuses observations outside it, so a
    /// faulty sensor cannot reach the learner.
    pub observation_plausible: Space,
    /// For goal-conditioned tasks: where the observation holds its goals, and the reward for a
    /// substituted goal (what HER relabels with).
    pub goal: Option<GoalSpec>,
}
