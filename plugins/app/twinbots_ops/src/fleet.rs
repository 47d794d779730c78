//! The simulated robots of design pattern 3 (no Supervisor; they home themselves and an
//! operator re-places objects), one app each, whose actions come from a RobotServer that trains
//! on them ([`against_server`]) or from an exported policy each robot runs itself
//! ([`with_policy`]), as it would beside a real controller.

use std::net::SocketAddr;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use bevy::prelude::*;
use twinbots_api::DesignPattern;
use twinbots_learn::EvalResult;
use twinbots_link::audit::Plumbing;
use twinbots_link::robot::{OnBoardPolicy, RobotRunState, ServerAddress, ServerTlsLink, ServerToken};
use twinbots_onnx::OnnxPolicy;
use twinbots_run::registry;
use twinbots_run::twin::Twin;
use twinbots_task::Episode;

/// Robot `k` of a run, in an app of its own: one world per robot, as each real robot has its
/// own controller, so robot code cannot name another robot's devices or arena — they are in
/// another world (docs/design/patterns.md). Its arena is index `k`, with
/// arena `k`'s random stream, as if all ran in one app. It gets its actions from `source` (a
/// [`ServerAddress`] or an [`OnBoardPolicy`]), is configured by `configure`, and is checked by
/// the pattern-3 audit against `plumbing` ([`run_plumbing`]); robot 0's run is the one `twin`
/// logs.
fn robot_app(
    k: usize,
    robot: &str,
    seed: u64,
    twin: &Twin,
    plumbing: &Plumbing,
    source: impl Resource,
    configure: impl Fn(&mut App),
) -> anyhow::Result<App> {
    let entry = registry::find(robot)?;
    let mut app = entry.app(None, 1, seed, DesignPattern::Server)?;
    app.world_mut().resource_mut::<twinbots_sim::ArenaConfig>().first = k;
    let twin = if k == 0 { twin.clone() } else { Twin { log: None, ..twin.clone() } };
    twin.configure(&mut app, &entry)?;
    app.insert_resource(source);
    configure(&mut app);
    app.finish();
    app.cleanup();
    // The second line behind pattern 3's types: no system of the robot may reach the true world.
    let found = plumbing.violations(&mut app);
    anyhow::ensure!(found.is_empty(), "{robot}'s pattern-3 app reaches beyond the robot:\n  {}", found.join("\n  "));
    Ok(app)
}

/// What the audit of a run's robot apps counts as the framework's: its own plumbing and the
/// twin's calibration and robot log (robot 0's, the fullest), found once for all robots.
/// Errors when `robot` has no pattern-3 robot.
fn run_plumbing(robot: &str, twin: &Twin) -> anyhow::Result<Plumbing> {
    let entry = registry::find(robot)?;
    anyhow::ensure!(entry.supports(None, DesignPattern::Server)?, "{robot} has no design-pattern-3 robot");
    Ok(Plumbing::beside(|probe| {
        let _ = twin.configure(probe, &entry);
    }))
}

/// How one robot's run ended: the server's reason or an error (`None`: another robot ended the
/// run first), and its episodes and reconnections.
struct RobotEnd {
    stop: Option<Result<String, String>>,
    episodes: u64,
    reconnects: u32,
}

/// Runs `arenas` simulated robots of `twin` against the server at `server` until it says
/// training is over. Returns the server's reason.
pub fn against_server(
    robot: &str,
    server: SocketAddr,
    arenas: usize,
    seed: u64,
    patience: Duration,
    twin: &Twin,
) -> anyhow::Result<String> {
    against_server_with(robot, server, arenas, seed, patience, ServerLink::default(), twin)
}

/// How robots reach their server beyond its address: its shared secret, and TLS.
#[derive(Default)]
pub struct ServerLink {
    pub token: Option<String>,
    pub tls: Option<ServerTlsLink>,
}

/// [`against_server`] over `link` (a token in every `hello`, TLS).
pub fn against_server_with(
    robot: &str,
    server: SocketAddr,
    arenas: usize,
    seed: u64,
    patience: Duration,
    link: ServerLink,
    twin: &Twin,
) -> anyhow::Result<String> {
    // No robot would ever stop the loop that waits for them.
    anyhow::ensure!(arenas >= 1, "--arenas {arenas}: at least one robot is needed");
    let plumbing = &run_plumbing(robot, twin)?;
    let (token, tls) = (&link.token, &link.tls);
    let halt = AtomicBool::new(false);
    // Each robot steps on its own thread, as robots do: the server hears them at once.
    let ends: Vec<anyhow::Result<RobotEnd>> = std::thread::scope(|scope| {
        let robots: Vec<_> = (0..arenas)
            .map(|k| {
                let halt = &halt;
                scope.spawn(move || {
                    let end = run_robot(
                        k,
                        robot,
                        seed,
                        twin,
                        plumbing,
                        ServerAddress { addr: server, patience },
                        token,
                        tls,
                        halt,
                    );
                    halt.store(true, Ordering::Relaxed);
                    end
                })
            })
            .collect();
        robots
            .into_iter()
            .map(|r| r.join().unwrap_or_else(|_| Err(anyhow::anyhow!("a robot's thread panicked"))))
            .collect()
    });
    let ends = ends.into_iter().collect::<anyhow::Result<Vec<RobotEnd>>>()?;
    let (episodes, reconnects) = ends.iter().fold((0, 0), |(e, r), end| (e + end.episodes, r + end.reconnects));
    let stops: Vec<&Result<String, String>> = ends.iter().filter_map(|end| end.stop.as_ref()).collect();
    match stops.iter().find(|s| s.is_err()).or(stops.first()) {
        Some(Ok(reason)) => {
            println!("robots done ({reason}); {episodes} episodes, {reconnects} reconnections");
            Ok(reason.clone())
        }
        Some(Err(e)) => Err(anyhow::anyhow!("robots stopped: {e}")),
        None => Err(anyhow::anyhow!("robots stopped without a reason")),
    }
}

/// Robot `k` against its server until it stops or another robot ends the run (`halt`).
#[allow(clippy::too_many_arguments)]
fn run_robot(
    k: usize,
    robot: &str,
    seed: u64,
    twin: &Twin,
    plumbing: &Plumbing,
    address: ServerAddress,
    token: &Option<String>,
    tls: &Option<ServerTlsLink>,
    halt: &AtomicBool,
) -> anyhow::Result<RobotEnd> {
    let mut app = robot_app(k, robot, seed, twin, plumbing, address, |app| {
        app.insert_resource(ServerToken(token.clone()));
        if let Some(tls) = tls {
            app.insert_resource(tls.clone());
        }
    })?;
    loop {
        app.update();
        let state = app.world().resource::<RobotRunState>();
        let stop = state.stop.clone();
        if stop.is_some() || halt.load(Ordering::Relaxed) {
            let (episodes, reconnects) = (state.episodes, state.reconnects);
            if k == 0 {
                report_log(&mut app, twin)?;
            }
            return Ok(RobotEnd { stop, episodes, reconnects });
        }
    }
}

/// Runs `arenas` robots on the exported policy at `policy` until `episodes` episodes have
/// ended, prints their figures as `eval` does and returns them.
pub fn with_policy(
    robot: &str,
    policy: &Path,
    arenas: usize,
    episodes: usize,
    seed: u64,
    twin: &Twin,
) -> anyhow::Result<EvalResult> {
    anyhow::ensure!(episodes > 0, "--episodes must be at least 1");
    let entry = registry::find(robot)?;
    let onnx = if policy.is_dir() {
        // A deploy bundle: refused unless it is this robot's, with its joints and control period.
        let bundle = crate::bundle::Bundle::read(policy)?;
        anyhow::ensure!(
            bundle.manifest.robot == robot,
            "the bundle {} is for the robot '{}', not '{robot}'",
            policy.display(),
            bundle.manifest.robot
        );
        let app = entry.app(None, 1, seed, twinbots_api::DesignPattern::Server)?;
        let period = app.world().resource::<twinbots_sim::SimSettings>().control_seconds();
        // The bundle's robot (its manifest's, checked to be this one) knows its joints.
        let joints = bundle.robot.joints();
        let joints: Vec<&str> = joints.iter().map(String::as_str).collect();
        bundle.check(robot, &joints, period)?;
        bundle.policy
    } else {
        OnnxPolicy::load(policy)?
    };
    let task = entry.main_task().name;
    onnx.metadata.check_fits(robot, task, &entry.task())?;
    if onnx.metadata.design_pattern != 3 {
        println!(
            "note: the policy was trained under design pattern {}; these robots observe through their own devices (pattern 3)",
            onnx.metadata.design_pattern
        );
    }
    // On board nothing waits on a network: the robots step in turn, each in its own app, which
    // keeps the run deterministic.
    let robots = arenas.clamp(1, episodes);
    let policy_link = OnBoardPolicy::new(move |obs: &[f32]| onnx.act(obs));
    let plumbing = run_plumbing(robot, twin)?;
    let mut apps = (0..robots)
        .map(|k| {
            let mut app = robot_app(k, robot, seed, twin, &plumbing, policy_link.clone(), |_| {})?;
            let ended = app.world_mut().query::<&Episode>();
            Ok((app, ended))
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    let mut finished = Vec::with_capacity(episodes);
    while finished.len() < episodes {
        for (app, ended) in &mut apps {
            app.update();
            if let Some(Err(e)) = app.world().resource::<RobotRunState>().stop.clone() {
                anyhow::bail!("robots stopped: {e}");
            }
            let left = episodes - finished.len();
            finished.extend(ended.iter(app.world()).filter_map(|e| e.finished().cloned()).take(left));
        }
    }
    let result = EvalResult::of_episodes(task, &finished);
    println!("{robot} running {}: {}", policy.display(), result.describe());
    report_log(&mut apps[0].0, twin)?;
    Ok(result)
}

/// Writes robot 0's run to the twin's log, if it has one, and says what it holds.
fn report_log(app: &mut App, twin: &Twin) -> anyhow::Result<()> {
    if let (Some(path), Some((states, commands))) = (&twin.log, twinbots_run::robot_log::finish_log(app.world_mut())?) {
        println!("logged robot 0's run ({states} states, {commands} commands) to {}", path.display());
    }
    Ok(())
}
