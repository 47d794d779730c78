//! The work area of an arm's cell for the learned pick-and-place, in the task's frame (the arm's
//! base frame with its origin on the table top): the free table between the two fixtures where
//! parts start and goals lie, and the safety planes the tool keeps within (a UR's tool-position
//! limits). The area is the gap between the fixtures, as the UR5e's is: a convex patch clear
//! of both, so a part carried straight from any of its points to any other passes neither
//! (around the fixtures, a carried part caught a fixture's rail on the way, and the knock
//! whipped a wrist past its speed limit: the UR10's scripted baseline met 158 of 200 goals).

use bevy::prelude::*;
use rand::Rng;
use twinbots_sim::rapier::math::Pose;
use twinbots_task::cell::layout::{CellLayout, FIXTURE_HALF};
use twinbots_task::cell::learned::{PLANE_CEILING, TOOL_FLOOR};
use twinbots_task::cell::parts::PART_RADIUS;

/// Parts start and goals lie between the fixtures, this far (m) from either plate's centre
/// along the line joining them (a plate's half diagonal, the part's radius and 1 cm)…
const FIXTURE_CLEARANCE: f32 = FIXTURE_HALF * std::f32::consts::SQRT_2 + PART_RADIUS + 0.01;
/// …up to this far (m) either side of that line…
const AREA_HALF_WIDTH: f32 = 0.15;
/// …on the table top, this far (m) inside its edges.
const TABLE_INSET: f32 = PART_RADIUS + 0.02;
/// The grid (m) on which the area's points are laid out (each draw lands anywhere in a cell).
const AREA_STEP: f32 = 0.01;
/// The safety planes lie this far (m) outside the area, and around the tool at home.
const PLANE_MARGIN: f32 = 0.12;

/// The cell's work area in the task's frame: where parts start and goals lie, and the planes the
/// tool keeps within.
#[derive(Clone, Debug)]
pub struct WorkArea {
    /// The table top's height in the base frame (m): the task frame's origin.
    pub table: f32,
    /// The grid points (x, y; task frame) a part may stand on.
    points: Vec<Vec2>,
    /// `[min, max]` per axis (task frame, m).
    pub planes: [[f32; 2]; 3],
}

impl WorkArea {
    /// The work area of an arm standing in `cell`, its base link at `base`, its tool at home at
    /// `home_tool` (base frame): the table top between the two fixtures; the planes around it
    /// and the tool at home, from [`TOOL_FLOOR`] to [`PLANE_CEILING`] (or above home).
    pub fn of(cell: &CellLayout, base: Pose, home_tool: Vec3) -> Result<Self, String> {
        let table = cell.table.height - base.translation.z;
        let to_base = base.inverse();
        let plate = |f| (to_base * cell.fixture_pose(f)).translation.truncate();
        let (pick, place) = (plate(&cell.pick), plate(&cell.place));
        let (along, apart) = ((place - pick).normalize_or_zero(), pick.distance(place));
        let across = along.perp();
        let between = |p: Vec2| {
            let (s, d) = ((p - pick).dot(along), (p - pick).dot(across));
            s > FIXTURE_CLEARANCE && s < apart - FIXTURE_CLEARANCE && d.abs() <= AREA_HALF_WIDTH
        };
        let reach = AREA_HALF_WIDTH + FIXTURE_CLEARANCE;
        let (lo, hi) = (pick.min(place) - reach, pick.max(place) + reach);
        let t = &cell.table;
        let on_table = |p: Vec2| {
            let at = (base * p.extend(table)).truncate() - Vec2::from(t.centre);
            at.x.abs() <= t.size[0] / 2.0 - TABLE_INSET && at.y.abs() <= t.size[1] / 2.0 - TABLE_INSET
        };
        let (nx, ny) = (((hi.x - lo.x) / AREA_STEP) as usize, ((hi.y - lo.y) / AREA_STEP) as usize);
        let points: Vec<Vec2> = (0..nx)
            .flat_map(|i| (0..ny).map(move |j| lo + Vec2::new(i as f32 + 0.5, j as f32 + 0.5) * AREA_STEP))
            .filter(|&p| on_table(p) && between(p))
            .collect();
        if points.is_empty() {
            return Err(format!(
                "no free table between the fixtures for a part to stand on (their plates' centres {:.3} m apart, at least {:.3} m needed)",
                apart,
                2.0 * FIXTURE_CLEARANCE + AREA_STEP
            ));
        }
        let [lo, hi] = bounds(&points);
        let home = home_tool - Vec3::Z * table;
        let planes = [
            [lo.x.min(home.x) - PLANE_MARGIN, hi.x.max(home.x) + PLANE_MARGIN],
            [lo.y.min(home.y) - PLANE_MARGIN, hi.y.max(home.y) + PLANE_MARGIN],
            [TOOL_FLOOR, PLANE_CEILING.max(home.z + PLANE_MARGIN)],
        ];
        Ok(Self { table, points, planes })
    }

    /// A point (x, y; task frame) of the free table.
    pub fn sample(&self, rng: &mut impl Rng) -> Vec2 {
        let p = self.points[rng.random_range(0..self.points.len())];
        let half = AREA_STEP / 2.0;
        p + Vec2::new(rng.random_range(-half..half), rng.random_range(-half..half))
    }

    /// Whether `p` (x, y; task frame) lies in a cell of the free table's grid.
    pub fn contains(&self, p: Vec2) -> bool {
        self.points.iter().any(|q| (p - *q).abs().max_element() <= AREA_STEP / 2.0)
    }

    /// The rectangle the free table's points span (task frame): `[min, max]`.
    pub fn bounds(&self) -> [Vec2; 2] {
        bounds(&self.points)
    }
}

fn bounds(points: &[Vec2]) -> [Vec2; 2] {
    points.iter().fold([Vec2::INFINITY, Vec2::NEG_INFINITY], |[lo, hi], p| [lo.min(*p), hi.max(*p)])
}
