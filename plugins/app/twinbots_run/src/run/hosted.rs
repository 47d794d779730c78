//! A run hosted by a RobotServer (design pattern 3): the learner lives in the server, robots
//! reach it over the network, and the run ends as an in-process run does.

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use twinbots_api::DesignPattern;
use twinbots_server::server::{RobotServer, ServerLimits, ServerSettings};

use super::{Run, finish};

/// Where the server of a hosted run listens, and whom it lets in.
pub struct Hosting {
    pub listen: SocketAddr,
    pub limits: ServerLimits,
}

impl Run {
    /// Hosts the run's learner in a RobotServer on `hosting.listen` until training ends, then
    /// ends the run ([`finish`]: the final model evaluated in-process, pattern 1 running the
    /// same policy). `listening` hears the address the server took (port 0: any free one)
    /// before any robot can connect. `settings.arenas` is the number of robots the learner's
    /// batches are sized for (PPO's rollout is n_steps × robots). A failure anywhere in the
    /// server (the learner's error, a panic in a server thread) is the error returned.
    pub fn host(
        mut self,
        hosting: Hosting,
        listening: impl FnOnce(SocketAddr) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        let (settings, entry) = (&self.settings, &self.entry);
        entry.check_supports(settings.task.as_deref(), DesignPattern::Server)?;
        anyhow::ensure!(hosting.limits.max_robots >= 1, "--max-robots must be at least 1");
        self.learner.check_spaces(&self.spec.observation_space, &self.spec.action_space)?;
        let title = format!(
            "{} — {} through the RobotServer (pattern 3), seed {}",
            settings.robot,
            self.learner.algorithm(),
            settings.seed
        );
        let mut server_settings =
            ServerSettings::new(&settings.robot, &self.spec, settings.arenas.max(1), settings.timesteps);
        server_settings.limits = hosting.limits;
        server_settings.task = server_settings.task.with_control_period(entry.control_period_s());
        let (callbacks, tally) = self.callbacks(title)?;
        self.truncate_if_resumed()?;
        let Run { settings, dir, entry, learner, .. } = self;
        let started = Instant::now();
        let server = RobotServer::start(hosting.listen, learner, server_settings, Box::new(callbacks))?;
        listening(server.addr)?;
        let (model, end) = server.wait()?;
        tally.check()?;
        let wall = started.elapsed().as_secs_f64();
        finish(&settings, &dir, &entry, model.as_ref(), &end, wall, None)?;
        println!("{end} in {wall:.1} s, mean of last 100 episodes {:.1}", model.history().mean_score());
        println!("run directory: {}", dir.path().display());
        // Give connected robots a moment to read their `done` before the process exits.
        std::thread::sleep(Duration::from_millis(200));
        Ok(())
    }
}
