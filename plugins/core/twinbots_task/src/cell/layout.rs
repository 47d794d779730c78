//! The cell's layout as data (docs/cells.md): the table, the robot's place on it, the pick and
//! place fixtures and any obstacles, from a TOML file. The default cell is the UR5e's,
//! `assets/cells/ur5e.toml`, compiled in; a run or a robot file may name another, and a study
//! may give each arena its own ([`CellLayouts`]).

use std::path::Path;
use std::sync::LazyLock;

use bevy::prelude::*;
use serde::{Deserialize, Serialize};
use twinbots_sim::rapier::math::Pose;

/// The default cell's file, compiled in.
pub const DEFAULT: &str = include_str!("../../../../../assets/cells/ur5e.toml");
pub const DEFAULT_PATH: &str = "assets/cells/ur5e.toml";

/// Half the side of a fixture's square plate (m): `assets/cells/fixture.urdf`.
pub const FIXTURE_HALF: f32 = 0.06;
/// The robot's base: a cylinder of this radius (m) must stand on the table top.
pub const BASE_RADIUS: f32 = 0.075;

static DEFAULT_LAYOUT: LazyLock<CellLayout> = LazyLock::new(|| {
    CellLayout::parse(DEFAULT, DEFAULT_PATH).unwrap_or_else(|e| panic!("the built-in cell layout: {e}"))
});

/// A cell layout file. Positions in the cell frame: x, y on the floor plan, z up, floor at 0 (m).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CellLayout {
    pub table: Table,
    #[serde(default)]
    pub floor: Floor,
    pub robot: RobotPlacement,
    /// The fixture the part starts in.
    pub pick: FixturePlacement,
    /// The fixture the program puts it in.
    pub place: FixturePlacement,
    #[serde(default, rename = "obstacle", skip_serializing_if = "Vec::is_empty")]
    pub obstacles: Vec<Obstacle>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Table {
    /// Its top's centre (m).
    pub centre: [f32; 2],
    /// Along x and y (m).
    pub size: [f32; 2],
    /// The top above the floor (m): the robot's base plane.
    pub height: f32,
    #[serde(default = "default_friction")]
    pub friction: f32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Floor {
    #[serde(default = "default_friction")]
    pub friction: f32,
}

impl Default for Floor {
    fn default() -> Self {
        Self { friction: default_friction() }
    }
}

fn default_friction() -> f32 {
    0.8
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotPlacement {
    /// The base's centre on the table top (m).
    pub position: [f32; 2],
    /// Degrees about z; 0: the arm's zero pose points along −x.
    #[serde(default)]
    pub yaw: f32,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixturePlacement {
    /// The plate's centre on the table top (m).
    pub position: [f32; 2],
}

/// A static box.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    pub centre: [f32; 3],
    pub size: [f32; 3],
}

/// Where the fixtures' plates are centred on the table top, in the robot's base frame: what the
/// program and the tasks work with.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Fixtures {
    pub pick: Vec3,
    pub place: Vec3,
}

impl Default for Fixtures {
    /// The default cell's.
    fn default() -> Self {
        DEFAULT_LAYOUT.fixtures()
    }
}

impl Default for CellLayout {
    fn default() -> Self {
        DEFAULT_LAYOUT.clone()
    }
}

/// The layout of each arena: arena i has `layouts[i % len]`. Insert it before the app's
/// start-up to build other cells than the default.
#[derive(Resource, Clone, Debug, PartialEq)]
pub struct CellLayouts(pub Vec<CellLayout>);

impl Default for CellLayouts {
    fn default() -> Self {
        Self(vec![CellLayout::default()])
    }
}

impl CellLayouts {
    pub fn of_arena(&self, index: usize) -> &CellLayout {
        &self.0[index % self.0.len()]
    }
}

/// [`crate::robot::CellDescription::install`]: the layout of `text` in every arena.
pub fn install(app: &mut App, text: &str, file: &str) -> Result<(), String> {
    app.insert_resource(CellLayouts(vec![CellLayout::parse(text, file)?]));
    Ok(())
}

impl CellLayout {
    /// Parses and checks a layout; `file` names it in every error, with the entry at fault.
    pub fn parse(text: &str, file: &str) -> Result<Self, String> {
        let layout: Self = toml::from_str(text).map_err(|e| format!("{file}: {e}"))?;
        layout.check().map_err(|e| format!("{file}: {e}"))?;
        Ok(layout)
    }

    /// Reads and checks a layout file.
    pub fn read(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::parse(&text, &path.display().to_string())
    }

    /// Everything must stand where it can: sizes positive, the robot's base and the fixtures'
    /// plates on the table top, the fixtures apart.
    pub fn check(&self) -> Result<(), String> {
        let t = &self.table;
        let finite = [
            t.centre[0],
            t.centre[1],
            t.size[0],
            t.size[1],
            t.height,
            self.robot.position[0],
            self.robot.position[1],
            self.robot.yaw,
        ]
        .into_iter()
        .chain(self.pick.position)
        .chain(self.place.position)
        .chain(self.obstacles.iter().flat_map(|o| o.centre.into_iter().chain(o.size)));
        if finite.into_iter().any(|v| !v.is_finite()) {
            return Err("every number must be finite".into());
        }
        if !(t.size[0] > 0.0 && t.size[1] > 0.0) {
            return Err(format!("table.size = {:?}: both sides must be positive", t.size));
        }
        if t.height <= 0.0 {
            return Err(format!("table.height = {}: must be positive", t.height));
        }
        for (key, f) in [("table.friction", t.friction), ("floor.friction", self.floor.friction)] {
            if f < 0.0 {
                return Err(format!("{key} = {f}: must be at least 0"));
            }
        }
        let bounds = format!(
            "the table top spans x {:.3}…{:.3} m, y {:.3}…{:.3} m",
            t.centre[0] - t.size[0] / 2.0,
            t.centre[0] + t.size[0] / 2.0,
            t.centre[1] - t.size[1] / 2.0,
            t.centre[1] + t.size[1] / 2.0
        );
        let on_table = |p: [f32; 2], half: [f32; 2]| {
            (0..2).all(|i| (p[i] - t.centre[i]).abs() + half[i] <= t.size[i] / 2.0 + 1e-6)
        };
        if !on_table(self.robot.position, [BASE_RADIUS; 2]) {
            return Err(format!(
                "robot.position = {:?}: the base ({BASE_RADIUS} m radius) leaves the table top ({bounds})",
                self.robot.position
            ));
        }
        let yaw = self.robot.yaw.to_radians();
        let plate = FIXTURE_HALF * (yaw.cos().abs() + yaw.sin().abs());
        for (key, f) in [("pick", &self.pick), ("place", &self.place)] {
            if !on_table(f.position, [plate; 2]) {
                return Err(format!(
                    "{key}.position = {:?}: the fixture's 12 cm plate leaves the table top ({bounds})",
                    f.position
                ));
            }
        }
        let apart = Vec2::from(self.pick.position).distance(Vec2::from(self.place.position));
        if apart < 2.0 * FIXTURE_HALF {
            return Err(format!(
                "place.position = {:?}: its plate overlaps the pick fixture's ({apart:.3} m apart, at least {} needed)",
                self.place.position,
                2.0 * FIXTURE_HALF
            ));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            if o.size.iter().any(|&s| s <= 0.0) {
                return Err(format!("obstacle[{i}].size = {:?}: every side must be positive", o.size));
            }
        }
        Ok(())
    }

    /// The robot's base in the cell (arena) frame.
    pub fn base_pose(&self) -> Pose {
        let [x, y] = self.robot.position;
        Pose::from_parts(Vec3::new(x, y, self.table.height), Quat::from_rotation_z(self.robot.yaw.to_radians()))
    }

    /// A fixture's frame in the cell: on the table top, turned with the robot.
    pub fn fixture_pose(&self, fixture: &FixturePlacement) -> Pose {
        let [x, y] = fixture.position;
        Pose::from_parts(Vec3::new(x, y, self.table.height), Quat::from_rotation_z(self.robot.yaw.to_radians()))
    }

    /// The fixtures' plate centres in the base frame.
    pub fn fixtures(&self) -> Fixtures {
        let base = self.base_pose().inverse();
        let local = |f: &FixturePlacement| (base * self.fixture_pose(f)).translation;
        Fixtures { pick: local(&self.pick), place: local(&self.place) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_cell_puts_the_fixtures_where_they_always_were() {
        let f = Fixtures::default();
        assert!((f.pick - Vec3::new(-0.45, 0.20, 0.0)).length() < 1e-6, "{f:?}");
        assert!((f.place - Vec3::new(-0.45, -0.35, 0.0)).length() < 1e-6, "{f:?}");
        assert!((CellLayout::default().base_pose().translation - Vec3::new(0.0, 0.0, 0.75)).length() < 1e-6);
    }

    #[test]
    fn a_turned_robot_sees_its_fixtures_turned_back() {
        let text = DEFAULT.replace("yaw = 0.0", "yaw = 90.0");
        let layout = CellLayout::parse(&text, "turned.toml").unwrap();
        // The pick plate at (−0.45, 0.20) in the cell, the base turned +90°: (0.20, 0.45) in its frame.
        assert!((layout.fixtures().pick - Vec3::new(0.20, 0.45, 0.0)).length() < 1e-5, "{:?}", layout.fixtures());
    }

    #[test]
    fn bad_layouts_name_the_file_and_the_entry() {
        for (from, to, expected) in [
            (
                "position = [-0.45, 0.20]",
                "position = [-0.98, 0.20]",
                "pick.position = [-0.98, 0.2]: the fixture's 12 cm plate leaves the table top (the table top spans x -1.000…0.300 m",
            ),
            (
                "position = [-0.45, -0.35]",
                "position = [-0.45, 0.25]",
                "place.position = [-0.45, 0.25]: its plate overlaps the pick fixture's",
            ),
            (
                "position = [0.0, 0.0]",
                "position = [0.3, 0.0]",
                "robot.position = [0.3, 0.0]: the base (0.075 m radius) leaves the table top",
            ),
            ("height = 0.75", "height = -1", "table.height = -1: must be positive"),
            ("size = [1.3, 1.2]", "size = [1.3, 0]", "table.size = [1.3, 0.0]"),
            ("[floor]", "[flor]", "unknown field `flor`"),
            (
                "# [[obstacle]]\n# centre = [-0.1, 0.45, 0.95]   # m, cell frame\n# size = [0.1, 0.1, 0.4]",
                "[[obstacle]]\ncentre = [0, 1, 1]\nsize = [0.1, -0.1, 0.4]",
                "obstacle[0].size",
            ),
        ] {
            assert!(DEFAULT.contains(from), "{from}");
            let err = CellLayout::parse(&DEFAULT.replacen(from, to, 1), "cell.toml").unwrap_err();
            assert!(err.starts_with("cell.toml: ") && err.contains(expected), "{to}: {err}");
        }
    }
}
