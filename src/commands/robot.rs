//! `twinbots robot <robot>`: simulated design-pattern-3 robots (no Supervisor; they home
//! themselves and an operator re-places objects) whose actions come from
//! - `--server ADDR`: a RobotServer that trains on them, until it says training is over;
//! - `--policy FILE.onnx`: an exported policy each robot runs itself, as it would beside a real
//!   controller, for a number of episodes, reporting the task's figures as `eval` does.

use std::time::Duration;

use twinbots_link::robot::ServerTlsLink;
use twinbots_link::tls::ClientTls;
use twinbots_ops::fleet::{ServerLink, against_server_with, with_policy};
use twinbots_run::registry;
use twinbots_run::twin::Twin;

/// The command's arguments.
#[derive(clap::Args)]
#[command(group = clap::ArgGroup::new("source").required(true).args(["server", "policy"]))]
pub struct Args {
    pub robot: String,
    /// The RobotServer's address.
    #[arg(long)]
    pub server: Option<std::net::SocketAddr>,
    /// An exported policy (`twinbots export`: an ONNX file, or a deploy bundle's directory)
    /// that the robots run on board, no server.
    #[arg(long)]
    pub policy: Option<std::path::PathBuf>,
    #[arg(long, default_value_t = 1)]
    pub arenas: usize,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Seconds the robots wait for the server at most: for a reply (the welcome too), for it
    /// to take a request, and for a connection that answers (reconnections back off up to 1 s).
    #[arg(long, default_value_t = 30, conflicts_with = "policy")]
    pub patience: u64,
    /// The server's shared secret (default: $TWINBOTS_TOKEN, else none; an empty one is refused).
    #[arg(long, conflicts_with = "policy", value_parser = twinbots_link::token::non_empty)]
    pub token: Option<String>,
    /// TLS: the certificate authority (PEM) that signed the server's certificate, or the
    /// server's self-signed certificate itself (not marked as a CA: docs/protocol.md).
    /// Without it the robots speak plain TCP.
    #[arg(long, conflicts_with = "policy")]
    pub tls_ca: Option<std::path::PathBuf>,
    /// TLS: the name the server's certificate must bear (default: the --server IP address).
    #[arg(long, requires = "tls_ca")]
    pub tls_name: Option<String>,
    /// Send the token to a server beyond this machine without TLS (a trusted network only: the
    /// token and every observation travel in clear).
    #[arg(long)]
    pub insecure: bool,
    /// With --policy: episodes to run before reporting their figures.
    #[arg(long, default_value_t = 10, conflicts_with = "server")]
    pub episodes: usize,
    /// Run the twin calibrated by this file (`twinbots identify`'s calibration.toml).
    #[arg(long)]
    pub calibration: Option<std::path::PathBuf>,
    /// Write robot 0's whole run (its episodes and its homing between them) as a robot log
    /// (.mcap or .csv) when the run ends, as a real robot's controller would record it.
    #[arg(long)]
    pub log: Option<std::path::PathBuf>,
}

/// `twinbots robot`.
pub fn exec(args: Args) -> anyhow::Result<()> {
    let twin = Twin::of_files(&registry::find(&args.robot)?, args.calibration.as_deref(), args.log.as_deref())?;
    match (args.server, args.policy) {
        (Some(server), _) => {
            anyhow::ensure!(args.patience >= 1, "--patience {}: must be at least 1 second", args.patience);
            let token = args.token.or_else(twinbots_link::token::from_env);
            check_exposure(server, token.is_some(), args.tls_ca.is_some(), args.insecure)?;
            let tls = match &args.tls_ca {
                Some(ca) => Some(ServerTlsLink {
                    tls: ClientTls::from_ca_file(ca)?,
                    name: twinbots_link::tls::server_name(args.tls_name.as_deref(), server.ip())?,
                }),
                None => None,
            };
            let link = ServerLink { token, tls };
            against_server_with(
                &args.robot,
                server,
                args.arenas,
                args.seed,
                Duration::from_secs(args.patience),
                link,
                &twin,
            )
            .map(|_| ())
        }
        (None, Some(policy)) => {
            with_policy(&args.robot, &policy, args.arenas, args.episodes, args.seed, &twin).map(|_| ())
        }
        (None, None) => unreachable!("clap requires --server or --policy"),
    }
}

/// A token goes beyond this machine only inside TLS, unless `--insecure` says the network is
/// trusted (as `serve` asks of a server listening beyond loopback).
fn check_exposure(server: std::net::SocketAddr, token: bool, tls: bool, insecure: bool) -> anyhow::Result<()> {
    if !token || tls || server.ip().is_loopback() {
        return Ok(());
    }
    anyhow::ensure!(
        insecure,
        "--server {server} is beyond this machine: its token would travel in clear; give --tls-ca (docs/protocol.md), or --insecure on a trusted network"
    );
    eprintln!("warning: --insecure: sending the token to {server} without TLS; anyone on the path can read it");
    Ok(())
}
