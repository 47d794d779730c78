//! `twinbots serve <robot>`: the RobotServer (design pattern 3) as its own process. It hosts the
//! policy and the learner, trains on whatever robots connect, and writes a run directory like
//! `train` does. Its first line of output is `listening on <address>`.
//!
//! Robots connect to it with `twinbots robot <robot> --server <address>` (`cli::robot`).

use std::io::Write;
use std::net::SocketAddr;
use std::path::Path;
use std::time::{Duration, Instant};

use twinbots_rl::run_dir::Summary;
use twinbots_rl::{DesignPattern, Ppo, RunDir};
use twinbots_server::server::{RobotServer, ServerSettings};

use crate::cli::runs::TrainSettings;
use crate::registry;

/// Runs a server until training ends. `settings.arenas` is the number of robots a rollout is
/// sized for (rollout = n_steps × robots). The server trains with the same callbacks as
/// `train` (periodic evaluation runs the policy in-process, under pattern 1); the final model
/// is not evaluated here: `twinbots eval <run>` does that.
pub fn serve(settings: TrainSettings, listen: SocketAddr, out: &Path) -> anyhow::Result<()> {
    let entry = registry::find(&settings.robot)?;
    let spec = entry.task();
    anyhow::ensure!(entry.supports(None, DesignPattern::Server)?, "{} has no design-pattern-3 robot", entry.name);
    let run_dir = RunDir::new(out);
    anyhow::ensure!(!run_dir.holds_run(), "{} already holds a run (choose another --out)", out.display());
    run_dir.create()?;
    run_dir.write_config(&settings)?;
    let model = Ppo::new(settings.ppo.clone(), spec.observation_space.clone(), spec.action_space.clone(), settings.seed)?;
    let title = format!("{} — PPO through the RobotServer (pattern 3), seed {}", settings.robot, settings.seed);
    let callbacks = crate::cli::runs::callbacks(&settings, &run_dir, &entry, title, spec.solved)?;
    let server_settings = ServerSettings {
        robot: settings.robot.clone(),
        rollout: settings.ppo.n_steps * settings.arenas.max(1),
        timesteps: settings.timesteps,
    };
    let started = Instant::now();
    let server = RobotServer::start(listen, model, server_settings, Box::new(callbacks))?;
    println!("listening on {}", server.addr);
    std::io::stdout().flush()?;
    let (model, end) = server.wait()?;
    let wall = started.elapsed().as_secs_f64();
    run_dir.save_model(&model)?;
    run_dir.write_summary(&Summary::new(&settings.robot, 3, &model, &end, wall, None))?;
    println!("{end} in {wall:.1} s, mean of last 100 episodes {:.1}", model.mean_recent_score());
    println!("run directory: {}", out.display());
    // Give connected robots a moment to read their `done` before the process exits.
    std::thread::sleep(Duration::from_millis(200));
    Ok(())
}
