//! The pick-and-place cell program: its stages, the tool target of each, and how it moves on
//! (as a UR program of MoveL waypoints and digital outputs), for any arm whose controller can
//! tell where its tool is ([`ToolReading`]).

use bevy::prelude::*;

use super::layout::Fixtures;
use super::parts::{PART_HEIGHT, Placement, part_seat};
use crate::task::EpisodeFigures;

/// The controller's speed slider on an arena (a UR's: a fraction of every commanded joint
/// speed, the program's straight moves included); absent, full speed. Cell studies sweep it.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct SpeedSlider(pub f32);

/// Height of the approach and retract waypoints above the part's top (m).
pub const CLEARANCE: f32 = 0.10;
/// The TCP stops this far above the part's top to seize it: inside the cup's stroke.
pub const GRIP_GAP: f32 = 0.003;
/// The part is let go this far above the pocket floor (m), below the rails' 20 mm so that it
/// drops inside them. Measured over 1,000 programs (docs/benchmarks.md): from 3 to 9 mm the
/// straight move stalled short of its waypoint now and then (1 to 30 %); from 22 mm the part
/// tipped over on landing in 2 %; at 15 mm a part landing 10 mm off centre could still tip
/// against a rail (the classical controller: 2 in 3,000). With the align move the controller's
/// too: at 13.5 mm the classical controller 3 in 3,000 fail; at 12 mm none of 3,000, the
/// seed-0 reach models 100 % (SAC) and 99.8 % (PPO).
pub const DROP_HEIGHT: f32 = 0.012;
/// Before lowering it, the part is aligned over the pocket this high above its seat (m): its
/// bottom clear of the rails, so the last descent is short and straight.
pub const ALIGN_HEIGHT: f32 = 0.04;
/// Control steps before a program is given up.
pub const EPISODE_STEPS: u32 = 400;
/// Control steps the suction is given to seize or release.
pub const SUCTION_STEPS: u32 = 3;

/// What the program reads of the arm: its controller's view of the tool.
pub trait ToolReading {
    /// The tool centre point in the base frame.
    fn tool(&self) -> Vec3;
    /// Whether the tool is within `tolerance` (m) of `target` and at rest; `level`: and
    /// pointing down, as a straight move must leave it to seize or let go of the part (an arm
    /// whose every move keeps it so may check that always).
    fn has_reached_within(&self, target: Vec3, tolerance: f32, level: bool) -> bool;
}

/// How close (m) a free move brings the tool to its waypoint: a reach's 1 cm.
pub const REACH_TOLERANCE: f32 = 0.01;
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    Approach,
    Descend,
    Grip,
    Lift,
    Transfer,
    /// Over fixture B's pocket, the part just clear of its rails.
    Align,
    Lower,
    Release,
    Retract,
    /// The program ran to its end.
    Done,
    /// The part was not seized.
    Failed,
}

/// The cell program's state in an arena.
#[derive(Component, Clone, Copy, Debug, PartialEq)]
pub struct Program {
    pub stage: Stage,
    /// Control steps spent waiting for the suction.
    waited: u32,
    /// Whether the cup held a part at the last step (its vacuum sensor).
    pub holding: bool,
    /// Where, across the part, the tool seized it: the tool's offset from the grip waypoint in
    /// the table's plane (the controller's kinematics). The part hangs off the cup's centre by
    /// as much, so the moves that carry and place it are shifted by it (a UR program's
    /// pose_trans of the grip pose). Heightwise the cup drew the part against its face.
    pub grip_offset: Vec3,
    /// Where the cell's fixtures are (its layout's).
    pub fixtures: Fixtures,
}

impl Default for Program {
    /// The program of the default cell.
    fn default() -> Self {
        Self::new(Fixtures::default())
    }
}

/// The TCP target of a stage, in the base frame, for the cell's `fixtures`.
pub fn waypoint(stage: Stage, fixtures: &Fixtures) -> Vec3 {
    let top = |fixture: Vec3| part_seat(fixture) + Vec3::Z * PART_HEIGHT;
    let (pick, place) = (fixtures.pick, fixtures.place);
    match stage {
        Stage::Approach | Stage::Lift => top(pick) + Vec3::Z * CLEARANCE,
        Stage::Descend | Stage::Grip | Stage::Failed => top(pick) + Vec3::Z * GRIP_GAP,
        Stage::Transfer | Stage::Retract | Stage::Done => top(place) + Vec3::Z * CLEARANCE,
        Stage::Align => top(place) + Vec3::Z * ALIGN_HEIGHT,
        Stage::Lower | Stage::Release => top(place) + Vec3::Z * DROP_HEIGHT,
    }
}

/// How close (m) a straight move brings the tool to its waypoint: the cup must seize the part
/// inside its stroke and let it go at its drop height, where the reach's 1 cm would leave it
/// dropping twice as far.
pub const STRAIGHT_TOLERANCE: f32 = 0.003;

impl Program {
    /// A program at its start, in a cell with these fixtures.
    pub fn new(fixtures: Fixtures) -> Self {
        Self { stage: Stage::Approach, waited: 0, holding: false, grip_offset: Vec3::ZERO, fixtures }
    }

    /// The tool target of the stage: [`waypoint`], shifted by the grip offset while the part
    /// is carried to its place.
    pub fn waypoint(&self, stage: Stage) -> Vec3 {
        let carried = matches!(stage, Stage::Transfer | Stage::Align | Stage::Lower | Stage::Release);
        waypoint(stage, &self.fixtures) + if carried { self.grip_offset } else { Vec3::ZERO }
    }

    /// Where the tool is sent now: the stage's waypoint.
    pub fn target(&self) -> Vec3 {
        self.waypoint(self.stage)
    }

    /// Whether the controller moves the arm now, in a straight line (a UR program's MoveL),
    /// rather than the policy: the last centimetres onto the part, the descent over the pocket
    /// and into it, and the waits for the suction there. The reach policy, trained to arrive
    /// within 1 cm, neither goes straight nor holds still there: it swung the part onto the
    /// pocket's rails and floor and dropped it tilted; and where it ends a move over the pocket
    /// its tool leans 25–60 mrad (the tilt it is allowed is 0.1 rad), which the short lowering
    /// move did not take out: a part let go 1–3 mrad off level lands on its rim and can rock
    /// against a rail (measured in docs/benchmarks.md).
    pub fn moves_straight(&self) -> bool {
        matches!(self.stage, Stage::Descend | Stage::Grip | Stage::Align | Stage::Lower | Stage::Release)
    }

    /// One control step of the program: moves on when the arm has reached the waypoint or the
    /// suction has had its time; returns whether the suction should be on.
    pub fn step(&mut self, arm: &impl ToolReading, holding: bool) -> bool {
        self.holding = holding;
        let target = self.target();
        let straight = self.moves_straight();
        let tolerance = if straight { STRAIGHT_TOLERANCE } else { REACH_TOLERANCE };
        let reached = arm.has_reached_within(target, tolerance, straight);
        if self.stage == Stage::Grip && holding {
            self.grip_offset = (arm.tool() - waypoint(Stage::Grip, &self.fixtures)).with_z(0.0);
        }
        let next = match self.stage {
            Stage::Approach if reached => Some(Stage::Descend),
            Stage::Descend if reached => Some(Stage::Grip),
            Stage::Grip if holding => Some(Stage::Lift),
            Stage::Grip if self.waited >= SUCTION_STEPS => Some(Stage::Failed),
            Stage::Lift if reached => Some(Stage::Transfer),
            Stage::Transfer if reached => Some(Stage::Align),
            Stage::Align if reached => Some(Stage::Lower),
            Stage::Lower if reached => Some(Stage::Release),
            Stage::Release if self.waited >= SUCTION_STEPS => Some(Stage::Retract),
            Stage::Retract if reached => Some(Stage::Done),
            _ => None,
        };
        match next {
            Some(stage) => {
                self.stage = stage;
                self.waited = 0;
            }
            None if matches!(self.stage, Stage::Grip | Stage::Release) => self.waited += 1,
            None => {}
        }
        matches!(self.stage, Stage::Grip | Stage::Lift | Stage::Transfer | Stage::Align | Stage::Lower)
    }

    pub fn is_over(&self) -> bool {
        matches!(self.stage, Stage::Done | Stage::Failed)
    }
}

/// How a pick-and-place episode ended: placed, or the first failure that explains it. `eval`
/// reports each as the share of episodes (`outcome_<name>`), so failures can be told apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    Placed,
    /// A protective stop halted the program.
    ProtectiveStop,
    /// The suction found no part to seize.
    GraspMissed,
    /// The part was seized and lost before the program let it go.
    PartDropped,
    /// The program ran to its end and the part is not in fixture B's pocket.
    PlaceMissed,
    /// The episode's step limit came first.
    TimeLimit,
}

impl Outcome {
    pub const ALL: [Outcome; 6] =
        [Self::Placed, Self::ProtectiveStop, Self::GraspMissed, Self::PartDropped, Self::PlaceMissed, Self::TimeLimit];

    pub fn name(self) -> &'static str {
        match self {
            Self::Placed => "placed",
            Self::ProtectiveStop => "protective_stop",
            Self::GraspMissed => "grasp_missed",
            Self::PartDropped => "part_dropped",
            Self::PlaceMissed => "place_missed",
            Self::TimeLimit => "time_limit",
        }
    }

    /// The outcome of an episode that ended with the program at `stage`.
    pub fn of(stage: Stage, stopped: bool, holding: bool, placed: bool) -> Self {
        let carrying = matches!(stage, Stage::Lift | Stage::Transfer | Stage::Align | Stage::Lower);
        match stage {
            Stage::Done if placed => Self::Placed,
            _ if stopped => Self::ProtectiveStop,
            Stage::Failed => Self::GraspMissed,
            Stage::Done => Self::PlaceMissed,
            _ if carrying && !holding => Self::PartDropped,
            _ => Self::TimeLimit,
        }
    }

    /// Judges the episode of a program that ended, `stopped` in a protective stop or not, the
    /// part where the evaluator sees it (`placement`): its outcome, written into `figures` with
    /// the success (the part placed) and, for a finished program, how well it put the part down.
    pub fn judge(program: &Program, stopped: bool, placement: Option<Placement>, figures: &mut EpisodeFigures) -> Self {
        let done = program.stage == Stage::Done;
        let placed = done && placement.as_ref().is_some_and(Placement::placed);
        if let Some(p) = placement.filter(|_| done) {
            p.record(&mut figures.metrics);
        }
        let outcome = Self::of(program.stage, stopped, program.holding, placed);
        figures.success = Some(outcome == Self::Placed);
        outcome.record(&mut figures.metrics);
        outcome
    }

    /// Adds the outcome to an episode's figures: one `outcome_<name>` per outcome, 1 for this.
    pub fn record(self, metrics: &mut std::collections::BTreeMap<String, f32>) {
        for o in Self::ALL {
            metrics.insert(format!("outcome_{}", o.name()), f32::from(u8::from(o == self)));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An arm at rest, pointing down, with its tool at a point.
    struct ArmAt(Vec3);

    impl ToolReading for ArmAt {
        fn tool(&self) -> Vec3 {
            self.0
        }

        fn has_reached_within(&self, target: Vec3, tolerance: f32, _level: bool) -> bool {
            self.0.distance(target) < tolerance
        }
    }

    fn arm_at(tool: Vec3) -> ArmAt {
        ArmAt(tool)
    }

    #[test]
    fn an_ended_program_is_told_by_its_first_failure() {
        use Outcome::*;
        assert_eq!(Outcome::of(Stage::Done, false, false, true), Placed);
        assert_eq!(Outcome::of(Stage::Done, false, false, false), PlaceMissed);
        assert_eq!(Outcome::of(Stage::Lower, true, true, false), ProtectiveStop);
        assert_eq!(Outcome::of(Stage::Failed, false, false, false), GraspMissed);
        assert_eq!(Outcome::of(Stage::Transfer, false, false, false), PartDropped);
        assert_eq!(Outcome::of(Stage::Transfer, false, true, false), TimeLimit);
        assert_eq!(Outcome::of(Stage::Approach, false, false, false), TimeLimit);
        let names: std::collections::BTreeSet<_> = Outcome::ALL.iter().map(|o| o.name()).collect();
        assert_eq!(names.len(), Outcome::ALL.len(), "one figure per outcome");
    }

    #[test]
    fn the_last_centimetres_are_straight_moves_brought_within_3_mm() {
        let mut program = Program { stage: Stage::Lower, ..default() };
        assert!(program.moves_straight());
        // 5 mm above the waypoint: within the reach's 1 cm, not yet within the 3 mm.
        program.step(&arm_at(waypoint(Stage::Lower, &Fixtures::default()) + Vec3::Z * 0.005), true);
        assert_eq!(program.stage, Stage::Lower);
        program.step(&arm_at(waypoint(Stage::Lower, &Fixtures::default()) + Vec3::Z * 0.002), true);
        assert_eq!(program.stage, Stage::Release);
        // Over the pocket the controller descends too.
        assert!(Program { stage: Stage::Align, ..default() }.moves_straight());
        // The free moves are the policy's, done within its 1 cm.
        let mut transfer = Program { stage: Stage::Transfer, ..default() };
        assert!(!transfer.moves_straight());
        transfer.step(&arm_at(waypoint(Stage::Transfer, &Fixtures::default()) + Vec3::Z * 0.008), true);
        assert_eq!(transfer.stage, Stage::Align);
    }

    #[test]
    fn the_part_is_placed_where_the_tool_seized_it_across_its_top() {
        let mut program = Program { stage: Stage::Grip, ..default() };
        let off = Vec3::new(0.006, -0.004, 0.002);
        // Seized with the tool 6 mm and −4 mm off the grip waypoint across, 2 mm higher.
        assert!(program.step(&arm_at(waypoint(Stage::Grip, &Fixtures::default()) + off), true), "suction stays on");
        assert_eq!(program.stage, Stage::Lift);
        assert!((program.grip_offset - off.with_z(0.0)).length() < 1e-6, "{}", program.grip_offset);
        // The moves that carry and place the part are shifted across by as much; the pick's not.
        for stage in [Stage::Transfer, Stage::Align, Stage::Lower, Stage::Release] {
            assert!(
                (program.waypoint(stage) - (waypoint(stage, &Fixtures::default()) + off.with_z(0.0))).length() < 1e-6,
                "{stage:?}"
            );
        }
        assert_eq!(program.waypoint(Stage::Lift), waypoint(Stage::Lift, &Fixtures::default()));
        assert_eq!(program.waypoint(Stage::Retract), waypoint(Stage::Retract, &Fixtures::default()));
        // Lowered onto the shifted waypoint, the program lets go there.
        program.stage = Stage::Lower;
        program.step(&arm_at(program.waypoint(Stage::Lower)), true);
        assert_eq!(program.stage, Stage::Release);
    }
}
