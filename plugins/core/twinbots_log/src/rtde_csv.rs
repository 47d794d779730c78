//! Recordings of a Universal Robots arm as its own tools write them: the CSV of UR's RTDE
//! recorder (`RTDE_Python_Client_Library/examples/record.py`: space-delimited) and of `ur_rtde`'s
//! `RTDEReceiveInterface::startFileRecording` (comma-delimited), plain or gzip. One header line of
//! RTDE output names, a vector's elements suffixed `_0` … `_5` (base to wrist 3), then a row per
//! controller cycle.
//!
//! Read as a [`RobotLog`] of the UR joints as `ur_description` names them (`shoulder_pan_joint`
//! … `wrist_3_joint`): `timestamp` (s, from the first row), `actual_q` and `actual_qd` the
//! measured state, `target_q` the commands (positions, as the controller's servo follows them),
//! and an effort column when the mapping names one: `target_moment` (N·m, the controller's model
//! torque) or `actual_current` times a torque constant per joint (N·m/A). Errors name the file's
//! line and column.

use crate::log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog};

/// The UR arm's joints, base to wrist 3, as `ur_description` names them.
pub const UR_JOINTS: [&str; 6] =
    ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"];

/// Where a recording's efforts come from.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Efforts {
    /// None: the log has positions, speeds and commands only.
    #[default]
    None,
    /// `target_moment_<j>`: the torque the controller's model expected (N·m).
    TargetMoment,
    /// `actual_current_<j>` (A) times each joint's torque constant (N·m/A).
    Current([f64; 6]),
}

impl Efforts {
    /// `--efforts` as the commands take it: `none`, `target_moment`, or `current:K0,…,K5` (each
    /// joint's torque constant, N·m/A).
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        match text {
            "none" => Ok(Self::None),
            "target_moment" => Ok(Self::TargetMoment),
            _ => {
                let Some(list) = text.strip_prefix("current:") else {
                    anyhow::bail!("--efforts '{text}': none, target_moment or current:K0,…,K5 (N*m/A per joint)")
                };
                let k: Vec<f64> = list
                    .split(',')
                    .map(|v| v.trim().parse::<f64>().ok().filter(|k| k.is_finite() && *k > 0.0))
                    .collect::<Option<_>>()
                    .ok_or_else(|| anyhow::anyhow!("--efforts '{text}': six positive torque constants"))?;
                let k: [f64; 6] = k
                    .try_into()
                    .map_err(|_| anyhow::anyhow!("--efforts '{text}': six torque constants, one a joint"))?;
                Ok(Self::Current(k))
            }
        }
    }
}

impl std::fmt::Display for Efforts {
    /// As [`Efforts::parse`] reads it.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::None => write!(f, "none"),
            Self::TargetMoment => write!(f, "target_moment"),
            Self::Current(k) => {
                write!(f, "current:{}", k.iter().map(|v| format!("{v:?}")).collect::<Vec<_>>().join(","))
            }
        }
    }
}

/// Whether `first_line` is the header of an RTDE recording (it names `timestamp` and `actual_q_0`).
pub fn is_rtde_header(first_line: &str) -> bool {
    let names: Vec<&str> = split(first_line).collect();
    names.first() == Some(&"timestamp") && names.contains(&"actual_q_0")
}

fn split(line: &str) -> impl Iterator<Item = &str> {
    line.split(|c: char| c == ',' || c.is_ascii_whitespace()).filter(|s| !s.is_empty())
}

/// Parses a recording's text (decompressed) with `efforts`; errors name the line and column.
pub fn from_str(text: &str, efforts: &Efforts) -> anyhow::Result<RobotLog> {
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else { anyhow::bail!("line 1: no header") };
    let names: Vec<&str> = split(header).collect();
    let column = |name: &str| names.iter().position(|n| *n == name);
    let vector = |prefix: &str| -> anyhow::Result<[usize; 6]> {
        let mut out = [0; 6];
        for (j, slot) in out.iter_mut().enumerate() {
            *slot = column(&format!("{prefix}_{j}")).ok_or_else(|| {
                anyhow::anyhow!(
                    "line 1: the header has no '{prefix}_{j}' (an RTDE recording names {prefix}_0 … {prefix}_5)"
                )
            })?;
        }
        Ok(out)
    };
    let time = column("timestamp").ok_or_else(|| anyhow::anyhow!("line 1: the header has no 'timestamp'"))?;
    let (q, qd, target) = (vector("actual_q")?, vector("actual_qd")?, vector("target_q")?);
    let effort = match efforts {
        Efforts::None => None,
        Efforts::TargetMoment => Some((vector("target_moment")?, [1.0; 6])),
        Efforts::Current(k) => Some((vector("actual_current")?, *k)),
    };
    let joints: Vec<String> = UR_JOINTS.iter().map(|j| j.to_string()).collect();
    let mut log = RobotLog {
        meta: LogMeta { source: "UR RTDE recording".into(), ..Default::default() },
        joints: joints.clone(),
        ..Default::default()
    };
    let mut start = None;
    let mut cells = Vec::with_capacity(names.len());
    for (i, line) in lines {
        let at = i + 1;
        cells.clear();
        for (c, cell) in split(line).enumerate() {
            let value: f64 = cell.parse().map_err(|_| {
                anyhow::anyhow!(
                    "line {at}, column {} ('{}'): '{cell}' is not a number",
                    c + 1,
                    names.get(c).unwrap_or(&"?")
                )
            })?;
            if !value.is_finite() {
                anyhow::bail!(
                    "line {at}, column {} ('{}'): {value} is not a finite number",
                    c + 1,
                    names.get(c).unwrap_or(&"?")
                );
            }
            cells.push(value);
        }
        anyhow::ensure!(
            cells.len() == names.len(),
            "line {at}: {} values for the header's {} columns",
            cells.len(),
            names.len()
        );
        let t0 = *start.get_or_insert(cells[time]);
        let t = cells[time] - t0;
        if let Some(last) = log.states.last() {
            anyhow::ensure!(
                t > last.time,
                "line {at}: timestamp {} s does not come after the previous row's",
                cells[time]
            );
        }
        let pick = |columns: &[usize; 6], scale: &[f64; 6]| -> Vec<f64> {
            columns.iter().zip(scale).map(|(&c, k)| cells[c] * k).collect()
        };
        log.states.push(JointSample {
            time: t,
            position: pick(&q, &[1.0; 6]),
            velocity: pick(&qd, &[1.0; 6]),
            effort: effort.as_ref().map_or_else(Vec::new, |(columns, k)| pick(columns, k)),
        });
        log.commands.push(CommandSample {
            time: t,
            joints: joints.clone(),
            modes: vec![CommandMode::Position; 6],
            values: pick(&target, &[1.0; 6]),
        });
    }
    anyhow::ensure!(!log.states.is_empty(), "no rows after the header");
    if log.states.len() > 1 {
        log.meta.control_period = log.duration() / (log.states.len() - 1) as f64;
    }
    Ok(log)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header() -> String {
        let mut names = vec!["timestamp".to_string()];
        for prefix in ["target_q", "target_moment", "actual_q", "actual_qd", "actual_current"] {
            names.extend((0..6).map(|j| format!("{prefix}_{j}")));
        }
        names.join(" ")
    }

    fn row(t: f64, v: f64) -> String {
        let mut cells = vec![format!("{t:.3}")];
        cells.extend((0..30).map(|k| format!("{:.3}", v + k as f64 * 0.01)));
        cells.join(" ")
    }

    #[test]
    fn a_recording_reads_as_states_and_position_commands() {
        let text = format!("{}\n{}\n{}\n", header(), row(1000.0, 0.1), row(1000.008, 0.2));
        assert!(is_rtde_header(&header()));
        let log = from_str(&text, &Efforts::Current([2.0; 6])).unwrap();
        log.validate().unwrap();
        assert_eq!(log.joints[0], "shoulder_pan_joint");
        assert_eq!(log.states.len(), 2);
        assert!((log.states[1].time - 0.008).abs() < 1e-9 && (log.meta.control_period - 0.008).abs() < 1e-9);
        // actual_q_0 is the 13th value (index 12), actual_current_0 the 25th: 0.1 + 0.24, × 2.
        assert!((log.states[0].position[0] - 0.22).abs() < 1e-12);
        assert!((log.states[0].effort[0] - 2.0 * 0.34).abs() < 1e-12);
        assert_eq!(log.commands[0].modes[0], CommandMode::Position);
        assert!((log.commands[0].values[0] - 0.1).abs() < 1e-12);
        // Commas as ur_rtde writes them read the same.
        let commas = text.replace(' ', ",");
        assert_eq!(from_str(&commas, &Efforts::Current([2.0; 6])).unwrap(), log);
    }

    #[test]
    fn the_efforts_option_reads_and_refuses() {
        assert_eq!(Efforts::parse("none").unwrap(), Efforts::None);
        assert_eq!(Efforts::parse("target_moment").unwrap(), Efforts::TargetMoment);
        assert_eq!(Efforts::parse("current:1,2,3,4,5,6").unwrap(), Efforts::Current([1.0, 2.0, 3.0, 4.0, 5.0, 6.0]));
        for bad in ["moment", "current:1,2", "current:1,2,3,4,5,-6", "current:1,2,3,4,5,x"] {
            assert!(Efforts::parse(bad).unwrap_err().to_string().starts_with(&format!("--efforts '{bad}'")), "{bad}");
        }
    }

    #[test]
    fn malformed_recordings_name_the_line_and_column() {
        let h = header();
        let cases = [
            (h.replace("actual_q_3", "actual_x_3"), row(0.0, 0.1), "line 1: the header has no 'actual_q_3'"),
            (h.clone(), row(0.0, 0.1).replacen("0.110", "nan", 1), "line 2, column 3 ('target_q_1'): NaN"),
            (
                h.clone(),
                row(0.0, 0.1).replacen("0.110", "x", 1),
                "line 2, column 3 ('target_q_1'): 'x' is not a number",
            ),
            (h.clone(), row(0.0, 0.1).rsplit_once(' ').unwrap().0.to_string(), "line 2: 30 values for the header's 31"),
            (h.clone(), format!("{}\n{}", row(1.0, 0.1), row(0.5, 0.1)), "line 3: timestamp 0.5 s does not come after"),
        ];
        for (header, rows, expected) in cases {
            let err = from_str(&format!("{header}\n{rows}\n"), &Efforts::None).unwrap_err().to_string();
            assert!(err.starts_with(expected), "{err:?} does not start with {expected:?}");
        }
    }
}
