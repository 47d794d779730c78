//! `bench live`: what a connected live viewer costs training. `train ROBOT` (this binary, the
//! robot's defaults, seed 0: the same steps every run) with `--live` and a viewer subscribed to
//! arena 0's joint states, `/tf`, `/scene` and `/episodes`, against the same run without a live
//! view, taking turns. The viewer is written from Foxglove's WebSocket protocol specification
//! (`foxglove.sdk.v1`: advertisements in, a subscription out, binary message frames counted), not
//! with Foxglove's own SDK, and runs on the same cores as the run it watches.

use std::net::TcpStream;
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use tungstenite::Message;
use tungstenite::client::IntoClientRequest;
use twinbots_ops::deploy::percentiles;

/// One run of `train`: its training wall clock (`summary.json`) and the messages the viewer got.
struct Timed {
    seconds: f64,
    messages: u64,
}

/// Trains `robot` in a scratch directory (its default timesteps unless given), with a live
/// view watched by a viewer if `watched` (every control step with `every_step`).
fn train(robot: &str, watched: bool, every_step: bool, timesteps: Option<usize>) -> anyhow::Result<Timed> {
    let dir = std::env::temp_dir().join(format!("twinbots-bench-live-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let out = dir.join("run");
    let mut command = Command::new(std::env::current_exe()?);
    command.args(["train", robot, "--out"]).arg(&out).stdout(Stdio::piped()).stderr(Stdio::null());
    if let Some(n) = timesteps {
        command.args(["--timesteps", &n.to_string()]);
    }
    if watched {
        command.args(["--live", "127.0.0.1:0"]);
        if every_step {
            command.arg("--live-every-step");
        }
    }
    let mut child = command.spawn()?;
    let mut stdout = std::io::BufReader::new(child.stdout.take().expect("piped"));
    let stop = Arc::new(AtomicBool::new(false));
    let messages = Arc::new(AtomicU64::new(0));
    let mut viewer = None;
    if watched {
        let mut line = String::new();
        std::io::BufRead::read_line(&mut stdout, &mut line)?;
        let port: u16 = line
            .split("ws://127.0.0.1:")
            .nth(1)
            .and_then(|rest| rest.split_whitespace().next())
            .and_then(|p| p.parse().ok())
            .ok_or_else(|| anyhow::anyhow!("train printed no live view address: {line:?}"))?;
        let (stop, messages) = (stop.clone(), messages.clone());
        viewer = Some(std::thread::spawn(move || watch(port, &stop, &messages)));
    }
    // The rest of its output, so that it never blocks on a full pipe.
    std::io::copy(&mut stdout, &mut std::io::sink())?;
    let status = child.wait()?;
    stop.store(true, Ordering::Relaxed);
    if let Some(viewer) = viewer {
        viewer.join().map_err(|_| anyhow::anyhow!("the viewer panicked"))??;
    }
    anyhow::ensure!(status.success(), "train {robot} failed ({status})");
    let summary = read_summary(&out)?;
    let _ = std::fs::remove_dir_all(&dir);
    Ok(Timed { seconds: summary, messages: messages.load(Ordering::Relaxed) })
}

fn read_summary(run: &Path) -> anyhow::Result<f64> {
    let path = run.join("summary.json");
    let text = std::fs::read_to_string(&path).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    let summary: serde_json::Value = serde_json::from_str(&text)?;
    summary["wall_clock_s_this_session"]
        .as_f64()
        .ok_or_else(|| anyhow::anyhow!("{}: no wall_clock_s_this_session", path.display()))
}

/// The viewer: subscribes to every channel of arena 0, `/tf`, `/scene` and `/episodes` as they
/// are advertised, and counts the message frames until `stop` (or the server goes).
fn watch(port: u16, stop: &AtomicBool, messages: &AtomicU64) -> anyhow::Result<()> {
    let mut request = format!("ws://127.0.0.1:{port}").into_client_request()?;
    request.headers_mut().insert("Sec-WebSocket-Protocol", "foxglove.sdk.v1".parse()?);
    let stream = TcpStream::connect(("127.0.0.1", port))?;
    let (mut socket, _) = tungstenite::client(request, stream).map_err(|e| anyhow::anyhow!("{e}"))?;
    // Woken now and then to see whether the run has ended.
    socket.get_ref().set_read_timeout(Some(Duration::from_millis(200)))?;
    let mut subscribed = std::collections::HashSet::new();
    while !stop.load(Ordering::Relaxed) {
        match socket.read() {
            Ok(Message::Text(text)) => {
                let message: serde_json::Value = serde_json::from_str(&text)?;
                if message["op"] != "advertise" {
                    continue;
                }
                let wanted = ["/arena_0/", "/tf", "/scene", "/episodes"];
                let new: Vec<serde_json::Value> = message["channels"]
                    .as_array()
                    .into_iter()
                    .flatten()
                    .filter(|c| c["topic"].as_str().is_some_and(|t| wanted.iter().any(|w| t.starts_with(w))))
                    .filter_map(|c| c["id"].as_u64())
                    .filter(|id| subscribed.insert(*id))
                    .map(|id| serde_json::json!({"id": id, "channelId": id}))
                    .collect();
                if !new.is_empty() {
                    let subscribe = serde_json::json!({"op": "subscribe", "subscriptions": new});
                    socket.send(Message::text(subscribe.to_string()))?;
                }
            }
            Ok(Message::Binary(frame)) if frame.first() == Some(&1) => {
                messages.fetch_add(1, Ordering::Relaxed);
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => {}
            // The run ended and its server with it.
            Err(_) => break,
        }
    }
    Ok(())
}

/// Prints each run and the medians of `rounds` rounds (the order alternating); `timesteps`
/// shortens the runs (a check that it works, not a figure).
pub fn print_live(robot: &str, rounds: usize, every_step: bool, timesteps: Option<usize>) -> anyhow::Result<()> {
    anyhow::ensure!(rounds > 0, "--rounds must be at least 1");
    let (mut without, mut with) = (Vec::new(), Vec::new());
    let pace = if every_step { "every control step" } else { "paced" };
    println!("train {robot} (seed 0), without a live view and with a viewer subscribed ({pace}), {rounds} round(s)");
    for round in 0..rounds {
        let order = if round % 2 == 0 { [false, true] } else { [true, false] };
        for watched in order {
            let timed = train(robot, watched, every_step, timesteps)?;
            if watched {
                println!(
                    "round {round}: with a viewer    {:7.2} s, {} messages received",
                    timed.seconds, timed.messages
                );
                with.push(timed.seconds);
            } else {
                println!("round {round}: no live view     {:7.2} s", timed.seconds);
                without.push(timed.seconds);
            }
        }
    }
    let (a, b) = (percentiles(&without).0, percentiles(&with).0);
    println!("median: no live view {a:.2} s, with a viewer {b:.2} s ({:+.1} %)", 100.0 * (b - a) / a);
    Ok(())
}
