//! `--live [ADDR]`: the options of the live view (`twinbots_live`) every command that runs a
//! twin shares, and the server they start.

use std::net::SocketAddr;
use std::sync::Arc;

use twinbots_live::{LiveServer, Pace};

/// The live view's options, flattened into a command's arguments.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct LiveArgs {
    /// Serve a live view over Foxglove's WebSocket protocol (open ws://127.0.0.1:8765 in
    /// Foxglove or Lichtblick; docs/live.md), on ADDR if given.
    #[arg(long, num_args = 0..=1, default_missing_value = twinbots_live::DEFAULT_ADDR, value_name = "ADDR")]
    pub live: Option<SocketAddr>,
    /// With --live on an address beyond loopback: serve it although the protocol has no
    /// authentication.
    #[arg(long, requires = "live")]
    pub insecure: bool,
    /// With --live: send every control step, not at most one a control period of wall time
    /// (a training run's every step: it slows the run, docs/live.md).
    #[arg(long, requires = "live")]
    pub live_every_step: bool,
}

impl LiveArgs {
    /// Starts the live view if asked for, and says where it is.
    pub fn start(&self) -> anyhow::Result<Option<Arc<LiveServer>>> {
        self.start_with(Ok)
    }

    /// Starts the live view if asked for, lets `advertise` add the command's own channels (and
    /// make what it needs of the server), then says where it is: a viewer that connects on
    /// reading the address finds every channel in its first advertisement. A channel advertised
    /// to a client already connected can be refused for a moment: foxglove 0.30 sends the
    /// advertisement before it takes subscriptions to it, and a client that subscribes at once
    /// is told "Unknown channel ID" (seen under load, the test's client subscribing on receipt).
    pub fn start_with<T>(
        &self,
        advertise: impl FnOnce(Arc<LiveServer>) -> anyhow::Result<T>,
    ) -> anyhow::Result<Option<T>> {
        let Some(addr) = self.live else { return Ok(None) };
        let pace = if self.live_every_step { Pace::EveryStep } else { Pace::RealTime };
        let server = LiveServer::start(addr, self.insecure, pace)?;
        let port = server.port();
        let made = advertise(server)?;
        println!("live view on ws://{}:{port} (Foxglove or Lichtblick: open connection)", addr.ip());
        Ok(Some(made))
    }
}
