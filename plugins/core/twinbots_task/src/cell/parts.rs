//! What an assembly cell is built of besides its robot: the floor, the table, its obstacles,
//! the two nest fixtures and the part (`assets/cells/fixture.urdf`, `part.urdf`), where the part
//! rests in a fixture, and where a finished program left the part ([`Placement`]).

use std::path::Path;

use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_sim::urdf::{RobotModel, parse_urdf};
use twinbots_sim::{Arena, Handled, SpawnOptions, Supervisor, spawn_robot};

use super::layout::CellLayout;

const FIXTURE_URDF: &str = include_str!("../../../../../assets/cells/fixture.urdf");
const PART_URDF: &str = include_str!("../../../../../assets/cells/part.urdf");
const ASSETS: &str = "assets/cells";

/// Thickness of a fixture's plate: the pocket floor's height.
pub const POCKET_FLOOR: f32 = 0.02;
/// How far the part can sit off its pocket's centre (m): an 8 cm pocket for a 5 cm part.
pub const POCKET_PLAY: f32 = 0.015;
pub const PART_HEIGHT: f32 = 0.05;
pub const PART_RADIUS: f32 = 0.025;
/// A placed part's centre lies within the pocket's play of its centre along each side of the
/// square pocket (m: a part in a corner is in the pocket too)…
pub const PLACE_TOLERANCE: f32 = POCKET_PLAY + 0.001;
/// …and it stands upright within this angle (rad).
pub const UPRIGHT_TOLERANCE: f32 = 0.2;

/// How far (m) the part may sit off its pocket's centre at a program's start. With the reach's
/// 1 cm, the part then never lands more than the pocket's play of its centre.
pub const PART_PLAY: f32 = 0.005;

/// Where the part rests in a fixture: its bottom on the pocket floor, in the base frame.
pub fn part_seat(fixture: Vec3) -> Vec3 {
    fixture + Vec3::new(0.0, 0.0, POCKET_FLOOR)
}

/// A program's start draw of the part in its pick pocket: its offset from the seat (up to
/// [`PART_PLAY`] along x and y) and its yaw (any).
pub fn draw_part_start(rng: &mut impl Rng) -> (Vec3, f32) {
    let offset = Vec3::new(rng.random_range(-PART_PLAY..=PART_PLAY), rng.random_range(-PART_PLAY..=PART_PLAY), 0.0);
    (offset, rng.random_range(-std::f32::consts::PI..=std::f32::consts::PI))
}

/// The part's pose in the base frame, seated in the pick fixture at `pick` off its seat by
/// `offset`, turned `yaw` about the vertical.
pub fn part_start_pose(pick: Vec3, offset: Vec3, yaw: f32) -> Pose {
    Pose::from_parts(part_seat(pick) + offset, Quat::from_rotation_z(yaw))
}

/// The fixture's and the part's models, parsed once.
#[derive(Resource, Clone)]
pub struct CellFurniture {
    pub fixture: RobotModel,
    pub part: RobotModel,
}

fn parse(text: &str, file: &str) -> RobotModel {
    let path = Path::new(ASSETS).join(file);
    parse_urdf(text, &path, Path::new(ASSETS)).unwrap_or_else(|e| panic!("built-in URDF {}: {e}", path.display()))
}

impl Default for CellFurniture {
    fn default() -> Self {
        Self { fixture: parse(FIXTURE_URDF, "fixture.urdf"), part: parse(PART_URDF, "part.urdf") }
    }
}

impl CellFurniture {
    /// Builds everything of `layout` but the robot into `arena`: the floor, the table, the
    /// obstacles, the fixtures welded to the table top, and the part seated in the pick
    /// fixture. Returns the part's link (marked [`Handled`]: the one thing of the cell a person
    /// puts back by hand).
    pub fn spawn(
        &self,
        commands: &mut Commands,
        arena_entity: Entity,
        arena: &mut Arena,
        layout: &CellLayout,
    ) -> Entity {
        arena.add_ground(layout.floor.friction);
        let table = &layout.table;
        let half = Vec3::new(table.size[0] / 2.0, table.size[1] / 2.0, table.height / 2.0);
        arena.add_static_box(half, Vec3::new(table.centre[0], table.centre[1], table.height / 2.0), table.friction);
        for obstacle in &layout.obstacles {
            arena.add_static_box(Vec3::from(obstacle.size) / 2.0, Vec3::from(obstacle.centre), 0.8);
        }
        for fixture in [&layout.pick, &layout.place] {
            let pose = layout.fixture_pose(fixture);
            spawn_robot(
                commands,
                arena_entity,
                arena,
                &self.fixture,
                SpawnOptions { base: pose, fixed_base: true, environment: true, ..default() },
            );
        }
        let part_pose = layout.base_pose() * Pose::from_translation(part_seat(layout.fixtures().pick));
        let part = spawn_robot(
            commands,
            arena_entity,
            arena,
            &self.part,
            SpawnOptions { base: part_pose, environment: true, friction: 0.8, ..default() },
        );
        let part = part.link("part").expect("the cell's part URDF has a link 'part'");
        commands.entity(part).insert(Handled);
        part
    }
}

/// Where the part stands against the place fixture's seat, as the evaluator (who may look)
/// sees it: off the pocket's centre along each side (m), off the pocket floor (m), tilted (rad).
pub struct Placement {
    pub off_centre: Vec2,
    pub height: f32,
    pub tilt: f32,
}

impl Placement {
    /// The part's link `part` of a cell whose robot base is at `base` (arena frame) against
    /// the seat of the place fixture at `place` (base frame).
    pub fn of(supervisor: &Supervisor, part: Entity, base: Pose, place: Vec3) -> Option<Self> {
        let part = supervisor.link_state(part)?;
        let pose = base.inverse() * part.pose;
        let seat = part_seat(place);
        Some(Self {
            off_centre: (pose.translation - seat).truncate().abs(),
            height: (pose.translation.z - seat.z).abs(),
            tilt: (pose.rotation * Vec3::Z).angle_between(Vec3::Z),
        })
    }

    /// In the pocket and upright.
    pub fn placed(&self) -> bool {
        self.off_centre.max_element() < PLACE_TOLERANCE && self.height < 0.005 && self.tilt < UPRIGHT_TOLERANCE
    }

    /// Adds how well a finished program put the part down to an episode's figures: what a
    /// failed place is told by.
    pub fn record(&self, metrics: &mut std::collections::BTreeMap<String, f32>) {
        metrics.insert("place_offset_mm".into(), 1e3 * self.off_centre.length());
        metrics.insert("part_tilt_rad".into(), self.tilt);
    }
}
