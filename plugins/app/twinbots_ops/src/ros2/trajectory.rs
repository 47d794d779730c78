//! A `trajectory_msgs/JointTrajectory` being followed: the joints' position targets at each
//! moment, linearly interpolated between the points from where the joints stood when it came.
//! (ros2_control's joint trajectory controller interpolates splines when points carry speeds;
//! a twin commanded by position through bounded-speed drives moves the same way within a step.)

use twinbots_link::checks::truncated;
use twinbots_ros2::JointTrajectory;

/// The most of a peer-supplied name an error repeats.
const NAME_SHOWN: usize = 64;

/// The trajectory as the twin follows it: per point, its time (s, twin clock) and positions.
#[derive(Clone, Debug, PartialEq)]
pub struct Following {
    /// The joints it commands (indices into the twin's joints), in the message's order.
    pub joints: Vec<usize>,
    /// Where those joints stood when it began, and when (twin clock, s).
    start: (f64, Vec<f64>),
    points: Vec<(f64, Vec<f64>)>,
}

impl Following {
    /// Checks `message` against the commandable joints (`commandable`: name and index) and
    /// starts it at twin time `now` from `current` (every joint's position, by index), `delay`
    /// seconds later (the header's stamp less the wall clock; 0 for a zero stamp, as "start
    /// now"). Positions are clipped into `range` (by joint index); returns how many were.
    pub fn new(
        message: &JointTrajectory,
        commandable: &[(String, usize)],
        current: &[f64],
        range: impl Fn(usize) -> Option<[f64; 2]>,
        now: f64,
        delay: f64,
    ) -> Result<(Self, usize), String> {
        if message.joint_names.is_empty() {
            return Err("a trajectory with no joint_names".into());
        }
        if message.points.is_empty() {
            return Err("a trajectory with no points".into());
        }
        let mut joints = Vec::with_capacity(message.joint_names.len());
        for name in &message.joint_names {
            let Some(&(_, index)) = commandable.iter().find(|(n, _)| n == name) else {
                let known: Vec<&str> = commandable.iter().map(|(n, _)| n.as_str()).collect();
                return Err(format!(
                    "no commandable joint '{}' (the robot's: {})",
                    truncated(name, NAME_SHOWN),
                    known.join(", ")
                ));
            };
            if joints.contains(&index) {
                return Err(format!("joint '{}' named twice", truncated(name, NAME_SHOWN)));
            }
            joints.push(index);
        }
        let begin = now + delay;
        let mut clipped = 0;
        let mut points = Vec::with_capacity(message.points.len());
        let mut last = f64::NEG_INFINITY;
        for (k, point) in message.points.iter().enumerate() {
            let t = point.time_from_start.seconds();
            if point.time_from_start.nanosec >= 1_000_000_000 || t < 0.0 || t <= last {
                return Err(format!("point {k}: time_from_start {t} s is not after the point before's"));
            }
            last = t;
            if point.positions.len() != joints.len() {
                return Err(format!("point {k}: {} positions for {} joints", point.positions.len(), joints.len()));
            }
            let mut positions = Vec::with_capacity(joints.len());
            for (&q, &j) in point.positions.iter().zip(&joints) {
                if !q.is_finite() {
                    return Err(format!("point {k}: position {q} is not a number"));
                }
                let inside = range(j).map_or(q, |[lo, hi]| q.clamp(lo, hi));
                clipped += usize::from(inside != q);
                positions.push(inside);
            }
            points.push((begin + t, positions));
        }
        let from = joints.iter().map(|&j| current[j]).collect();
        Ok((Self { joints, start: (begin, from), points }, clipped))
    }

    /// Each commanded joint's target at twin time `t`: where it stood until the trajectory
    /// begins, then along it, then its last point.
    pub fn target(&self, t: f64) -> Vec<f64> {
        let mut before = &self.start;
        for point in &self.points {
            if t < point.0 {
                let span = point.0 - before.0;
                let s = if span > 0.0 { ((t - before.0) / span).clamp(0.0, 1.0) } else { 1.0 };
                return before.1.iter().zip(&point.1).map(|(a, b)| a + (b - a) * s).collect();
            }
            before = point;
        }
        before.1.clone()
    }

    /// When its last point is due (twin clock, s).
    pub fn end(&self) -> f64 {
        self.points.last().map_or(self.start.0, |p| p.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use twinbots_ros2::JointTrajectoryPoint;
    use twinbots_ros2::messages::Duration;

    fn message(names: &[&str], points: &[(f64, &[f64])]) -> JointTrajectory {
        JointTrajectory {
            joint_names: names.iter().map(|s| s.to_string()).collect(),
            points: points
                .iter()
                .map(|(t, q)| JointTrajectoryPoint {
                    positions: q.to_vec(),
                    time_from_start: Duration::from_seconds(*t),
                    ..Default::default()
                })
                .collect(),
            ..Default::default()
        }
    }

    fn joints() -> Vec<(String, usize)> {
        vec![("a".into(), 0), ("b".into(), 2)]
    }

    #[test]
    fn positions_are_interpolated_from_where_the_joints_stood() {
        let m = message(&["b", "a"], &[(1.0, &[1.0, -1.0]), (3.0, &[3.0, 1.0])]);
        let (f, clipped) = Following::new(&m, &joints(), &[0.5, 9.0, 0.0], |_| None, 10.0, 0.0).unwrap();
        assert_eq!((f.joints.clone(), clipped), (vec![2, 0], 0));
        assert_eq!(f.target(9.0), vec![0.0, 0.5]);
        assert_eq!(f.target(10.5), vec![0.5, -0.25]);
        assert_eq!(f.target(11.0), vec![1.0, -1.0]);
        assert_eq!(f.target(12.0), vec![2.0, 0.0]);
        assert_eq!(f.target(20.0), vec![3.0, 1.0]);
        assert_eq!(f.end(), 13.0);
    }

    #[test]
    fn a_stamp_ahead_delays_the_start_and_ranges_clip() {
        let m = message(&["a"], &[(1.0, &[5.0])]);
        let (f, clipped) = Following::new(&m, &joints(), &[0.0, 0.0, 0.0], |_| Some([-1.0, 2.0]), 0.0, 0.5).unwrap();
        assert_eq!(clipped, 1);
        assert_eq!(f.target(0.4), vec![0.0]);
        assert_eq!(f.target(1.0), vec![1.0]);
        assert_eq!(f.target(1.5), vec![2.0]);
    }

    #[test]
    fn bad_trajectories_say_what_is_wrong() {
        let current = [0.0; 3];
        // A peer's 10,000-character name is repeated cut short.
        let long = format!("joint '{}…' (the robot's: a, b)", "x".repeat(64));
        let cases = [
            (message(&[], &[(1.0, &[])]), "no joint_names"),
            (message(&["a"], &[]), "no points"),
            (message(&["c"], &[(1.0, &[0.0])]), "no commandable joint 'c' (the robot's: a, b)"),
            (message(&["a", "a"], &[(1.0, &[0.0, 0.0])]), "named twice"),
            (message(&["a"], &[(1.0, &[0.0]), (1.0, &[1.0])]), "point 1: time_from_start 1 s"),
            (message(&["a", "b"], &[(1.0, &[0.0])]), "point 0: 1 positions for 2 joints"),
            (message(&["a"], &[(1.0, &[f64::NAN])]), "not a number"),
            (message(&[&"x".repeat(10_000)], &[(1.0, &[0.0])]), long.as_str()),
        ];
        for (m, expected) in &cases {
            let e = Following::new(m, &joints(), &current, |_| None, 0.0, 0.0).unwrap_err();
            assert!(e.contains(expected) && e.len() < 200, "{e} (expected {expected})");
        }
    }
}
