//! `twinbots robots`: what is registered. With `--json`, every task's interface as a
//! RobotServer's `welcome` gives it (the same `TaskInterface`), so a robot written in another
//! language can be checked against it before it connects.

use twinbots_link::protocol::TaskInterface;

use twinbots_run::registry;

/// The command's arguments.
#[derive(clap::Args)]
pub struct Args {
    /// Print each robot's tasks as the RobotServer's `welcome` describes them (spaces with
    /// bounds, observation names, reward range), as JSON.
    #[arg(long)]
    pub json: bool,
}

/// `twinbots robots`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    emit(&if args.json { listing_json()? } else { listing() })
}

/// Writes `text` to standard output; a reader that stopped early (`twinbots robots | head`)
/// ends the listing quietly, as it does for other Unix tools.
fn emit(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    match out.write_all(text.as_bytes()).and_then(|()| out.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        other => Ok(other?),
    }
}

fn listing() -> String {
    use std::fmt::Write;
    let mut out = String::new();
    for robot in registry::robots() {
        let _ = writeln!(out, "{:<12} {}", robot.name, robot.description);
        let _ = writeln!(out, "{:<12} control step {:.0} ms", "", robot.control_period_s() * 1e3);
        let patterns: Vec<String> = robot.all_patterns().iter().map(|p| p.number().to_string()).collect();
        let _ = writeln!(out, "{:<12} task: {}; design patterns: {}", "", robot.main_task().name, patterns.join(", "));
        for task in &robot.tasks[1..] {
            let _ = writeln!(out, "{:<12} also --task {}: {}", "", task.name, task.description);
        }
    }
    out
}

/// One JSON document: `{"protocol_version": 2, "robots": [{name, description,
/// design_patterns, tasks: [TaskInterface…]}]}`.
fn listing_json() -> anyhow::Result<String> {
    let robots: Vec<serde_json::Value> = registry::robots()
        .iter()
        .map(|robot| {
            let tasks: Vec<TaskInterface> = robot
                .tasks
                .iter()
                .map(|t| TaskInterface::of(robot.name, &(t.spec)()).with_control_period(robot.control_period_s()))
                .collect();
            serde_json::json!({
                "name": robot.name,
                "description": robot.description,
                "design_patterns": robot.all_patterns().iter().map(|p| p.number()).collect::<Vec<_>>(),
                "tasks": tasks,
            })
        })
        .collect();
    let document = serde_json::json!({ "protocol_version": twinbots_link::protocol::VERSION, "robots": robots });
    Ok(serde_json::to_string_pretty(&document)? + "\n")
}
