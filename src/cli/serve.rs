//! `twinbots serve <robot>`: the RobotServer (design pattern 3) as its own process. It hosts the
//! policy and the learner, trains on whatever robots connect, and writes a run directory like
//! `train` does. Its first line of output is `listening on <address>`.
//!
//! `twinbots robot <robot> --server <address>`: simulated robots that connect to it.

use std::io::Write;
use std::net::SocketAddr;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use twinbots_rl::{DesignPattern, Flow, Ppo, UpdateStats};
use twinbots_server::server::{RobotServer, ServerSettings};

use crate::cli::run_log::RunLog;
use crate::cli::train::TrainSettings;
use crate::registry;

/// Runs a server until training ends. `settings.arenas` is the number of robots a rollout is
/// sized for (rollout = n_steps × robots).
pub fn serve(settings: TrainSettings, listen: SocketAddr, out: &Path) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let spec = entry.task();
    anyhow::ensure!(entry.supports(None, DesignPattern::Server)?, "{} has no design-pattern-3 robot", entry.name);
    anyhow::ensure!(
        !out.join("progress.csv").exists(),
        "{} already holds a run (choose another --out)",
        out.display()
    );
    std::fs::create_dir_all(out)?;
    std::fs::write(out.join("config.toml"), toml::to_string_pretty(&settings)?)?;
    let model = Ppo::new(settings.ppo.clone(), spec.observation_space.clone(), spec.action_space.clone(), settings.seed)?;
    let title = format!("{} — PPO through the RobotServer (pattern 3), seed {}", settings.robot, settings.seed);
    let log = Arc::new(Mutex::new(RunLog::open(out, title, spec.solved, settings.checkpoint_every, settings.timesteps, 0, Vec::new())?));
    let server_log = log.clone();
    let callback = Box::new(move |s: &UpdateStats, m: &Ppo| -> anyhow::Result<Flow> {
        server_log.lock().map_err(|_| anyhow::anyhow!("run log lock poisoned"))?.on_update(s, m)?;
        Ok(Flow::Continue)
    });
    let server_settings = ServerSettings {
        robot: settings.robot.clone(),
        rollout: settings.ppo.n_steps * settings.arenas.max(1),
        timesteps: settings.timesteps,
        solved: spec.solved,
    };
    let started = Instant::now();
    let server = RobotServer::start(listen, model, server_settings, callback)?;
    println!("listening on {}", server.addr);
    std::io::stdout().flush()?;
    let (model, reason) = server.wait()?;
    let wall = started.elapsed().as_secs_f64();
    model.save(out.join("model"))?;
    let solved = reason.starts_with("solved");
    let summary = serde_json::json!({
        "robot": settings.robot,
        "pattern": 3,
        "timesteps": model.timesteps,
        "episodes": model.episodes,
        "wall_clock_s": wall,
        "mean_reward_last_100": model.mean_recent_score(),
        "solved": solved,
        "ended": reason,
    });
    std::fs::write(out.join("summary.json"), serde_json::to_string_pretty(&summary)?)?;
    // The curve's last points since the last checkpoint, and the progress bar's end.
    log.lock().map_err(|_| anyhow::anyhow!("run log lock poisoned"))?.finish()?;
    println!(
        "{reason}: {} steps in {wall:.1} s, mean of last 100 episodes {:.1}",
        model.timesteps,
        model.mean_recent_score()
    );
    println!("run directory: {}", out.display());
    // Give connected robots a moment to read their `done` before the process exits.
    std::thread::sleep(Duration::from_millis(200));
    Ok(())
}

/// Runs `arenas` simulated robots against the server at `server` until it says training is
/// over. Returns the server's reason.
pub fn robots(robot: &str, server: SocketAddr, arenas: usize, seed: u64, patience: Duration) -> anyhow::Result<String> {
    let entry = registry::find(robot)?;
    anyhow::ensure!(entry.supports(None, DesignPattern::Server)?, "{robot} has no design-pattern-3 robot");
    let mut app = entry.app(None, arenas, seed, DesignPattern::Server)?;
    app.insert_resource(twinbots_server::robot::ServerAddress { addr: server, patience });
    app.finish();
    app.cleanup();
    loop {
        app.update();
        let state = app.world().resource::<twinbots_server::robot::RobotRunState>();
        if let Some(stop) = &state.stop {
            let (episodes, reconnects) = (state.episodes, state.reconnects);
            return match stop.clone() {
                Ok(reason) => {
                    println!("robots done ({reason}); {episodes} episodes, {reconnects} reconnections");
                    Ok(reason)
                }
                Err(e) => Err(anyhow::anyhow!("robots stopped: {e}")),
            };
        }
    }
}
