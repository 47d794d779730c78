//! The shadow: the twin's check of every joint-speed command before it reaches a robot (a
//! deployment's, a monitor's), for any six-joint arm whose geometry a robot crate describes
//! ([`ArmGeometry`]: the UR5e's DH table, a robot file's URDF chain).

use std::fmt::Debug;
use std::sync::Arc;

use bevy::math::DVec3;

/// What the shadow needs of an arm's kinematics, in the controller's joint order and the arm's
/// base frame.
pub trait ArmGeometry: Send + Sync + Debug {
    /// Joint `joint`'s stops (rad or m): lower, upper.
    fn range(&self, joint: usize) -> (f64, f64);
    /// The arm at `q` as a line of named points from the first that moves to the tool face, in
    /// order along the arm (the links run between consecutive points).
    fn skeleton(&self, q: &[f64; 6]) -> Vec<(&str, DVec3)>;
    /// The lowest of the points that must stay above the table (the elbow and what follows
    /// it): its name and its height above the table's surface (m). Borrowed names: this runs
    /// twice a command, at the controller's rate.
    fn lowest_point(&self, q: &[f64; 6]) -> (&str, f64);
}

/// What the shadow does with a command.
#[derive(Clone, Debug, PartialEq)]
pub struct Verdict {
    /// The command that may go to the robot (joint speeds, rad/s).
    pub command: [f64; 6],
    /// Whether any joint's command was changed.
    pub clipped: bool,
    /// Whether the command was refused: the robot is told to stop instead.
    pub refused: bool,
    /// Why, for the log.
    pub notes: Vec<String>,
}

/// A box the arm keeps clear of (a cell's `[[obstacle]]`), in the base frame: its centre, its
/// half sides along its own axes, and its turn about the base's z axis (rad).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Keepout {
    pub centre: DVec3,
    pub half: DVec3,
    pub yaw: f64,
}

impl Keepout {
    /// The distance (m) from `p` (base frame) to the box; 0 inside it.
    pub fn distance(&self, p: DVec3) -> f64 {
        let d = p - self.centre;
        let (s, c) = self.yaw.sin_cos();
        let local = DVec3::new(c * d.x + s * d.y, -s * d.x + c * d.y, d.z);
        (local.abs() - self.half).max(DVec3::ZERO).length()
    }
}

/// The twin's check of a joint-speed command before it goes to the robot: the joints' speed
/// and acceleration limits, their ranges and the workspace (no link or the tool near or under
/// the table, none within `keepout_clearance` of the cell's obstacles) over the next
/// `lookahead` seconds of the command. Speeds and accelerations past a limit are clipped to it;
/// a command that would take a joint out of its range or a point of the arm into the table or
/// towards an obstacle is refused.
#[derive(Clone, Debug)]
pub struct Shadow {
    /// The arm's kinematics and stops.
    pub geometry: Arc<dyn ArmGeometry>,
    /// Each joint's fastest speed (rad/s).
    pub max_speed: [f64; 6],
    /// Each joint's largest change of commanded speed (rad/s²).
    pub max_acceleration: [f64; 6],
    /// How far ahead a command is followed (s).
    pub lookahead: f64,
    /// The closest a joint may come to its stop (rad).
    pub range_margin: f64,
    /// The lowest the elbow, wrists, flange and tool may go, above the table (m).
    pub table_clearance: f64,
    /// The cell's obstacles (none in the default cell).
    pub keepouts: Vec<Keepout>,
    /// The closest the arm's skeleton (its points and the links between them) may come to an
    /// obstacle (m): the links' radius and a margin.
    pub keepout_clearance: f64,
}

impl Shadow {
    /// The shadow of an arm with these joint speed limits, at the defaults a UR's: 40 rad/s²,
    /// 80 ms ahead, 0.05 rad from a stop, 5 mm above the table, 0.1 m from an obstacle.
    pub fn new(geometry: Arc<dyn ArmGeometry>, max_speed: [f64; 6]) -> Self {
        Self {
            geometry,
            max_speed,
            max_acceleration: [40.0; 6],
            lookahead: 0.08,
            range_margin: 0.05,
            table_clearance: 0.005,
            keepouts: Vec::new(),
            keepout_clearance: 0.1,
        }
    }

    /// Checks `command` from measured joints `q` given the previous command, `period` seconds
    /// before.
    pub fn check(&self, q: &[f64; 6], command: &[f64; 6], previous: &[f64; 6], period: f64) -> Verdict {
        let mut notes = Vec::new();
        let mut out = *command;
        let mut clipped = false;
        for j in 0..6 {
            if !out[j].is_finite() {
                notes.push(format!("joint {}: command {} is not a number", j + 1, out[j]));
                return Verdict { command: [0.0; 6], clipped: true, refused: true, notes };
            }
            let limited = out[j].clamp(-self.max_speed[j], self.max_speed[j]);
            let step = self.max_acceleration[j] * period;
            let limited = limited.clamp(previous[j] - step, previous[j] + step);
            if limited != out[j] {
                notes.push(format!(
                    "joint {}: {:.3} rad/s clipped to {:.3} (speed ≤ {:.3}, acceleration ≤ {:.0} rad/s²)",
                    j + 1,
                    out[j],
                    limited,
                    self.max_speed[j],
                    self.max_acceleration[j]
                ));
                out[j] = limited;
                clipped = true;
            }
        }
        let ahead: [f64; 6] = std::array::from_fn(|j| q[j] + out[j] * self.lookahead);
        for j in 0..6 {
            let (lo, hi) = self.geometry.range(j);
            let (lo, hi) = (lo + self.range_margin, hi - self.range_margin);
            if (ahead[j] > hi && ahead[j] > q[j]) || (ahead[j] < lo && ahead[j] < q[j]) {
                notes.push(format!(
                    "joint {}: {:.3} rad in {:.2} s is past its range {lo:.3} … {hi:.3}",
                    j + 1,
                    ahead[j],
                    self.lookahead
                ));
                return Verdict { command: [0.0; 6], clipped, refused: true, notes };
            }
        }
        let lowest = self.geometry.lowest_point(&ahead);
        if lowest.1 < self.table_clearance && lowest.1 < self.geometry.lowest_point(q).1 {
            notes.push(format!("{} at z = {:.3} m in {:.2} s: into the table", lowest.0, lowest.1, self.lookahead));
            return Verdict { command: [0.0; 6], clipped, refused: true, notes };
        }
        if let Some((what, obstacle, gap)) = self.closest_keepout(&ahead)
            && gap < self.keepout_clearance
            && self.closest_keepout(q).is_none_or(|now| gap < now.2)
        {
            notes.push(format!(
                "{what} {gap:.3} m from obstacle[{obstacle}] in {:.2} s (clearance {:.3} m)",
                self.lookahead, self.keepout_clearance
            ));
            return Verdict { command: [0.0; 6], clipped, refused: true, notes };
        }
        Verdict { command: out, clipped, refused: false, notes }
    }

    /// The point of the arm at `q` closest to an obstacle: what it is, which obstacle, how far.
    /// The skeleton's points and four points on each link between them. None without
    /// obstacles (nothing is computed: this runs every control cycle).
    pub fn closest_keepout(&self, q: &[f64; 6]) -> Option<(String, usize, f64)> {
        if self.keepouts.is_empty() {
            return None;
        }
        let points = self.geometry.skeleton(q);
        // (point, fifths of the way to the next, obstacle, distance)
        let mut best: Option<(usize, usize, usize, f64)> = None;
        for (at, (_, p)) in points.iter().enumerate() {
            let next = points.get(at + 1).map(|n| n.1);
            for fifths in 0..if next.is_some() { 5 } else { 1 } {
                let x = next.map_or(*p, |n| p.lerp(n, fifths as f64 / 5.0));
                for (i, k) in self.keepouts.iter().enumerate() {
                    let d = k.distance(x);
                    if best.is_none_or(|b| d < b.3) {
                        best = Some((at, fifths, i, d));
                    }
                }
            }
        }
        best.map(|(at, fifths, i, d)| {
            let what = match fifths {
                0 => points[at].0.to_string(),
                _ => format!("the link from {} to {}", points[at].0, points[at + 1].0),
            };
            (what, i, d)
        })
    }
}
