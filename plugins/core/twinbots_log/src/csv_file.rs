//! Logs as CSV, for data exported from a robot controller (docs/logs.md):
//!
//! ```text
//! # robot = ur5e
//! # control_period = 0.008
//! # command_mode = velocity
//! time,shoulder_pan_joint.position,shoulder_pan_joint.velocity,shoulder_pan_joint.effort,shoulder_pan_joint.command,...
//! 0.000,0.0,0.0,1.2,0.1,...
//! ```
//!
//! `# key = value` lines before the header carry the metadata (`robot`, `source`, `calibration`,
//! `control_period` in s, `command_mode` for every joint or `command_mode.<joint>` for one).
//! Columns: `time` (s), then per joint `<joint>.position`, `<joint>.velocity`, optional
//! `<joint>.effort` and `<joint>.command`, and optional `tool.x tool.y tool.z tool.qx tool.qy
//! tool.qz tool.qw`. A row with its state cells empty carries only a command, and the reverse.

use std::collections::BTreeMap;

use crate::log::{CommandMode, CommandSample, JointSample, LogMeta, RobotLog, ToolSample};

const TOOL: [&str; 7] = ["tool.x", "tool.y", "tool.z", "tool.qx", "tool.qy", "tool.qz", "tool.qw"];

/// The log as CSV text.
pub fn to_string(log: &RobotLog) -> String {
    let mut out = String::new();
    let m = &log.meta;
    for (k, v) in [
        ("robot", m.robot.clone()),
        ("source", m.source.clone()),
        ("calibration", m.calibration.clone()),
        ("control_period", m.control_period.to_string()),
    ] {
        out += &format!("# {k} = {v}\n");
    }
    let mut modes = BTreeMap::new();
    for c in &log.commands {
        for (j, mode) in c.joints.iter().zip(&c.modes) {
            modes.insert(j.clone(), *mode);
        }
    }
    for (j, mode) in &modes {
        out += &format!("# command_mode.{j} = {}\n", mode.name());
    }
    let efforts = log.states.iter().any(|s| !s.effort.is_empty());
    let mut header = vec!["time".to_string()];
    for j in &log.joints {
        header.push(format!("{j}.position"));
        header.push(format!("{j}.velocity"));
        if efforts {
            header.push(format!("{j}.effort"));
        }
        if modes.contains_key(j) {
            header.push(format!("{j}.command"));
        }
    }
    if !log.tool.is_empty() {
        header.extend(TOOL.iter().map(|s| s.to_string()));
    }
    out += &header.join(",");
    out += "\n";

    // Rows: the union of the times of states, commands and tool poses.
    let mut rows: BTreeMap<u64, BTreeMap<String, f64>> = BTreeMap::new();
    let key = |t: f64| t.to_bits();
    for s in &log.states {
        let row = rows.entry(key(s.time)).or_default();
        for (k, j) in log.joints.iter().enumerate() {
            row.insert(format!("{j}.position"), s.position[k]);
            row.insert(format!("{j}.velocity"), s.velocity[k]);
            if let Some(e) = s.effort.get(k) {
                row.insert(format!("{j}.effort"), *e);
            }
        }
    }
    for c in &log.commands {
        let row = rows.entry(key(c.time)).or_default();
        for (j, v) in c.joints.iter().zip(&c.values) {
            row.insert(format!("{j}.command"), *v);
        }
    }
    for t in &log.tool {
        let row = rows.entry(key(t.time)).or_default();
        for (name, v) in TOOL.iter().zip(t.position.iter().chain(&t.orientation)) {
            row.insert(name.to_string(), *v);
        }
    }
    let mut times: Vec<f64> = rows.keys().map(|&b| f64::from_bits(b)).collect();
    times.sort_by(f64::total_cmp);
    for t in times {
        let row = &rows[&key(t)];
        let cells: Vec<String> =
            header[1..].iter().map(|h| row.get(h).map_or(String::new(), |v| v.to_string())).collect();
        out += &format!("{t},{}\n", cells.join(","));
    }
    out
}

/// Parses CSV text; errors name the line.
pub fn from_str(text: &str) -> anyhow::Result<RobotLog> {
    let mut meta = BTreeMap::new();
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let header = loop {
        let Some((n, line)) = lines.next() else { anyhow::bail!("no header line (time,<joint>.position,...)") };
        match line.strip_prefix('#') {
            Some(comment) => {
                if let Some((k, v)) = comment.split_once('=') {
                    meta.insert(k.trim().to_string(), v.trim().to_string());
                }
            }
            None => break (n + 1, line),
        }
    };
    let columns: Vec<&str> = header.1.split(',').map(str::trim).collect();
    anyhow::ensure!(
        columns.first() == Some(&"time"),
        "line {}: the first column must be 'time', not '{}'",
        header.0,
        columns[0]
    );
    let mut joints: Vec<String> = Vec::new();
    for c in &columns[1..] {
        let Some((joint, field)) = c.rsplit_once('.') else {
            anyhow::bail!("line {}: column '{c}' is not <joint>.<field>", header.0)
        };
        match field {
            "position" => joints.push(joint.to_string()),
            "velocity" | "effort" | "command" => {}
            _ if joint == "tool" && TOOL.contains(c) => {}
            _ => anyhow::bail!(
                "line {}: column '{c}': unknown field '{field}' (known: position, velocity, effort, command, tool.*)",
                header.0
            ),
        }
    }
    let column = |name: &str| columns.iter().position(|c| *c == name);
    let mut log = RobotLog { joints: joints.clone(), ..Default::default() };
    for j in &joints {
        anyhow::ensure!(
            column(&format!("{j}.velocity")).is_some(),
            "line {}: joint '{j}' has no '{j}.velocity' column",
            header.0
        );
    }
    let default_mode = meta.get("command_mode").map(|m| CommandMode::parse(m)).transpose()?;
    let mode_of = |j: &str| -> anyhow::Result<CommandMode> {
        match meta.get(&format!("command_mode.{j}")) {
            Some(m) => CommandMode::parse(m),
            None => default_mode.ok_or_else(|| {
                anyhow::anyhow!("column '{j}.command' but no '# command_mode = ...' line says its mode")
            }),
        }
    };
    let commanded: Vec<(String, usize, CommandMode)> = joints
        .iter()
        .filter_map(|j| column(&format!("{j}.command")).map(|c| (j.clone(), c)))
        .map(|(j, c)| mode_of(&j).map(|m| (j, c, m)))
        .collect::<anyhow::Result<_>>()?;
    let tool_columns: Option<Vec<usize>> = TOOL.iter().map(|t| column(t)).collect();

    for (n, line) in lines {
        let line_no = n + 1;
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        anyhow::ensure!(
            cells.len() == columns.len(),
            "line {line_no}: {} cells for {} columns",
            cells.len(),
            columns.len()
        );
        let number = |k: usize| -> anyhow::Result<Option<f64>> {
            if cells[k].is_empty() {
                return Ok(None);
            }
            let v: f64 = cells[k].parse().map_err(|_| {
                anyhow::anyhow!("line {line_no}, column '{}': '{}' is not a number", columns[k], cells[k])
            })?;
            Ok(Some(v))
        };
        let time = number(0)?.ok_or_else(|| anyhow::anyhow!("line {line_no}: empty time"))?;
        let field = |j: &str, f: &str| column(&format!("{j}.{f}")).map_or(Ok(None), number);
        let positions: Vec<Option<f64>> = joints.iter().map(|j| field(j, "position")).collect::<anyhow::Result<_>>()?;
        if positions.iter().any(Option::is_some) {
            let need = |v: Option<f64>, j: &str, f: &str| {
                v.ok_or_else(|| {
                    anyhow::anyhow!("line {line_no}: '{j}.{f}' is empty while other joints' states are given")
                })
            };
            let mut s = JointSample { time, position: vec![], velocity: vec![], effort: vec![] };
            for (j, p) in joints.iter().zip(&positions) {
                s.position.push(need(*p, j, "position")?);
                s.velocity.push(need(field(j, "velocity")?, j, "velocity")?);
                if column(&format!("{j}.effort")).is_some() {
                    s.effort.push(need(field(j, "effort")?, j, "effort")?);
                }
            }
            log.states.push(s);
        }
        let mut command = CommandSample { time, joints: vec![], modes: vec![], values: vec![] };
        for (j, c, mode) in &commanded {
            if let Some(v) = number(*c)? {
                command.joints.push(j.clone());
                command.modes.push(*mode);
                command.values.push(v);
            }
        }
        if !command.joints.is_empty() {
            log.commands.push(command);
        }
        if let Some(tc) = &tool_columns {
            let v: Vec<Option<f64>> = tc.iter().map(|&k| number(k)).collect::<anyhow::Result<_>>()?;
            if let Some(v) = v.into_iter().collect::<Option<Vec<f64>>>() {
                log.tool.push(ToolSample { time, position: [v[0], v[1], v[2]], orientation: [v[3], v[4], v[5], v[6]] });
            }
        }
    }
    let period = meta.remove("control_period").unwrap_or_default();
    log.meta = LogMeta {
        robot: meta.remove("robot").unwrap_or_default(),
        source: meta.remove("source").unwrap_or_default(),
        calibration: meta.remove("calibration").unwrap_or_default(),
        control_period: if period.is_empty() {
            0.0
        } else {
            period.parse().map_err(|_| anyhow::anyhow!("'# control_period = {period}' is not a number of seconds"))?
        },
        extra: meta.into_iter().filter(|(k, _)| !k.starts_with("command_mode")).collect(),
    };
    Ok(log)
}
