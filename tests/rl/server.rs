//! Design pattern 3: the RobotServer's protocol and error paths, disconnects, reconnection with
//! backoff, two real processes, and the Supervisor's absence.

use std::io::{BufReader, Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use twinbots_learn::{Flow, Ppo, PpoConfig};
use twinbots_link::frame::{read_message, write_message};
use twinbots_link::protocol::{RobotMessage, ServerMessage, VERSION};
use twinbots_server::server::{RobotServer, ServerLimits, ServerSettings};

pub fn server(timesteps: u64) -> RobotServer {
    server_with(
        timesteps,
        256,
        ServerLimits::default(),
        Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)),
    )
}

/// A cart-pole server with these limits and callbacks.
pub fn server_with(
    timesteps: u64,
    rollout: usize,
    limits: ServerLimits,
    callbacks: Box<dyn twinbots_learn::Callback + Send>,
) -> RobotServer {
    let spec = cartpole::task_spec();
    // One robot's worth of `rollout` steps per update.
    let config = PpoConfig { n_steps: rollout, ..PpoConfig::zoo_cartpole() };
    let model = Box::new(Ppo::new(config, spec.observation_space.clone(), spec.action_space.clone(), 0).unwrap());
    let mut settings = ServerSettings::new("cartpole", &spec, 1, timesteps);
    settings.task = settings.task.with_control_period(cartpole::robot().control_period_s());
    settings.limits = limits;
    RobotServer::start("127.0.0.1:0".parse().unwrap(), model, settings, callbacks).unwrap()
}

/// Two arenas of `robot` as a robot process of design pattern 3 (seed 3), pointed at the server
/// at `addr` and started up: no Supervisor in it.
pub fn robots_against(robot: &twinbots_task::robot::RobotDescription, addr: SocketAddr) -> bevy::prelude::App {
    let mut app = robot.app(None, 2, 3, twinbots_api::DesignPattern::Server).unwrap();
    app.insert_resource(twinbots_link::robot::ServerAddress { addr, patience: Duration::from_secs(5) });
    app.finish();
    app.cleanup();
    app.update();
    assert!(!app.world().contains_resource::<twinbots_sim::SupervisorAccess>(), "pattern 3 has no Supervisor");
    app
}

/// Steps a pattern-3 app (its robots against a server) until its robots stop, at most
/// `max_updates` times, and asserts they stopped because the server said training is done.
pub fn run_robots_until_done(app: &mut bevy::prelude::App, max_updates: usize) -> twinbots_link::robot::RobotRunState {
    use twinbots_link::robot::RobotRunState;
    for _ in 0..max_updates {
        app.update();
        if app.world().resource::<RobotRunState>().stop.is_some() {
            break;
        }
    }
    let run = app.world().resource::<RobotRunState>().clone();
    assert!(matches!(&run.stop, Some(Ok(_))), "{:?}", run.stop);
    run
}

/// A hand-driven robot connection (a test client that can misbehave).
pub struct Robot {
    pub reader: BufReader<TcpStream>,
    pub writer: TcpStream,
}

impl Robot {
    pub fn connect(addr: SocketAddr) -> Self {
        let stream = TcpStream::connect(addr).unwrap();
        stream.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
        Robot { reader: BufReader::new(stream.try_clone().unwrap()), writer: stream }
    }
    pub fn call(&mut self, m: &RobotMessage) -> ServerMessage {
        write_message(&mut self.writer, m).unwrap();
        read_message(&mut self.reader).unwrap()
    }
    pub fn raw(&mut self, bytes: &[u8]) -> ServerMessage {
        self.writer.write_all(bytes).unwrap();
        read_message(&mut self.reader).unwrap()
    }
    pub fn hello(addr: SocketAddr) -> Self {
        let mut r = Self::connect(addr);
        let reply = r.call(&hello(None));
        assert!(matches!(reply, ServerMessage::Welcome { .. }), "{reply:?}");
        r
    }
    pub fn step(&mut self) -> ServerMessage {
        self.call(&RobotMessage::Step {
            obs: vec![0.0; 4],
            reward: 1.0,
            terminated: false,
            truncated: false,
            success: None,
            ended_by: None,
        })
    }
}

/// A cart-pole robot's hello.
pub fn hello(token: Option<&str>) -> RobotMessage {
    let id = cartpole::task_spec();
    RobotMessage::Hello {
        version: VERSION,
        robot: "cartpole".into(),
        observation_space: id.observation_space,
        action_space: id.action_space,
        token: token.map(String::from),
    }
}

pub fn frame(payload: &[u8]) -> Vec<u8> {
    let mut f = (payload.len() as u32).to_le_bytes().to_vec();
    f.extend_from_slice(payload);
    f
}

#[test]
fn malformed_and_oversized_messages_get_error_replies_and_the_server_keeps_serving() {
    let server = server(1_000_000);
    let mut robot = Robot::hello(server.addr);
    let other = Robot::hello(server.addr);
    let is_recoverable_error = |m: &ServerMessage| matches!(m, ServerMessage::Error { fatal: false, .. });
    let rejected_before = server.rejections();

    let reply = robot.raw(&frame(b"{ this is not json"));
    assert!(is_recoverable_error(&reply), "{reply:?}");
    let reply = robot.raw(&frame(br#"{"type":"teleport","x":1}"#));
    assert!(is_recoverable_error(&reply), "unknown message type: {reply:?}");
    let big = vec![b' '; 100_000];
    let reply = robot.raw(&frame(&big));
    match &reply {
        ServerMessage::Error { message, fatal: false, .. } => assert!(message.contains("exceeds"), "{message}"),
        other => panic!("{other:?}"),
    }
    let reply = robot.call(&RobotMessage::Start { obs: vec![0.0; 3] });
    assert!(is_recoverable_error(&reply), "wrong observation size: {reply:?}");
    let reply = robot.step();
    assert!(is_recoverable_error(&reply), "a step before start: {reply:?}");
    // Still serving, this robot and the other.
    let reply = robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    assert!(matches!(&reply, ServerMessage::Action { action } if action.len() == 1), "{reply:?}");
    assert!(matches!(robot.step(), ServerMessage::Action { .. }));
    assert_eq!(server.load().0, 2);
    assert_eq!(server.rejections() - rejected_before, 5, "every refusal is logged and counted");
    drop(other);
}

#[test]
fn a_bad_hello_is_refused() {
    let server = server(1_000_000);
    let id = cartpole::task_spec();
    let mut r = Robot::connect(server.addr);
    let reply = r.call(&RobotMessage::Hello {
        version: VERSION + 1,
        robot: "cartpole".into(),
        observation_space: id.observation_space.clone(),
        action_space: id.action_space.clone(),
        token: None,
    });
    assert!(
        matches!(&reply, ServerMessage::Error { fatal: true, message, .. } if message.contains("version")),
        "{reply:?}"
    );
    let mut r = Robot::connect(server.addr);
    let reply = r.call(&RobotMessage::Hello {
        version: VERSION,
        robot: "cartpole".into(),
        observation_space: id.observation_space,
        action_space: twinbots_api::Space::Discrete { n: 3 },
        token: None,
    });
    assert!(
        matches!(&reply, ServerMessage::Error { fatal: true, message, .. } if message.contains("Discrete(3)")),
        "{reply:?}"
    );
    // After a fatal error the server closes the connection.
    let mut byte = [0u8; 1];
    assert_eq!(r.reader.read(&mut byte).unwrap_or(0), 0);
}

#[test]
fn a_robot_that_disconnects_mid_episode_has_that_episode_discarded() {
    let server = server(1_000_000);
    let mut a = Robot::hello(server.addr);
    let mut b = Robot::hello(server.addr);
    a.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    for _ in 0..5 {
        a.step();
    }
    b.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    for _ in 0..3 {
        b.step();
    }
    assert_eq!(server.load(), (2, 8));
    drop(a); // mid-episode
    for _ in 0..100 {
        if server.load().0 == 1 {
            break;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(server.load(), (1, 3), "robot A's unfinished episode is gone, B's steps remain");
}

#[test]
fn the_server_trains_with_callbacks_and_stops_once_solved() {
    use twinbots_api::SolvedCriterion;
    use twinbots_learn::callbacks::StopTrainingOnSolved;
    use twinbots_learn::{CallbackList, SolvedBy, TrainingEnd, UpdateStats};
    let id = cartpole::task_spec();
    let model = Box::new(
        Ppo::new(PpoConfig { n_steps: 8, ..PpoConfig::zoo_cartpole() }, id.observation_space, id.action_space, 0)
            .unwrap(),
    );
    let rows = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let seen = rows.clone();
    let callbacks = CallbackList::new()
        .with(move |s: &UpdateStats, _: &dyn twinbots_learn::Agent| {
            seen.lock().unwrap().push((s.update, s.timesteps, s.episodes));
            Ok(Flow::Continue)
        })
        .with(StopTrainingOnSolved::new(SolvedCriterion::mean_score(1, 2.0)));
    let settings = ServerSettings::new("cartpole", &cartpole::task_spec(), 1, 1_000_000);
    let server = RobotServer::start("127.0.0.1:0".parse().unwrap(), model, settings, Box::new(callbacks)).unwrap();
    let mut robot = Robot::hello(server.addr);
    let episode = |robot: &mut Robot| {
        robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
        for _ in 0..3 {
            assert!(matches!(robot.step(), ServerMessage::Action { .. }));
        }
        let last = RobotMessage::Step {
            obs: vec![0.0; 4],
            reward: 1.0,
            terminated: true,
            truncated: false,
            success: None,
            ended_by: None,
        };
        assert!(matches!(robot.call(&last), ServerMessage::Ack));
    };
    // Two episodes of 4 steps (score 4 > 2) fill the rollout of 8: one update, then solved.
    episode(&mut robot);
    episode(&mut robot);
    match robot.call(&RobotMessage::Start { obs: vec![0.0; 4] }) {
        ServerMessage::Done { reason } => assert_eq!(reason, "solved (training episodes) after 8 steps"),
        other => panic!("{other:?}"),
    }
    let (model, end) = server.wait().unwrap();
    assert_eq!(end, TrainingEnd::Solved { timesteps: 8, by: SolvedBy::TrainingEpisodes });
    assert_eq!((model.timesteps(), model.episodes()), (8, 2));
    assert_eq!(*rows.lock().unwrap(), [(1, 8, 2)]);
}

pub fn twinbots() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twinbots"))
}

/// Starts `twinbots serve` and returns the child and the address it listens on.
pub fn serve_process(listen: &str, timesteps: u64, out: &std::path::Path) -> (std::process::Child, SocketAddr) {
    serve_process_with(listen, timesteps, out, &["--robots", "2"])
}

/// [`serve_process`] with more flags.
pub fn serve_process_with(
    listen: &str,
    timesteps: u64,
    out: &std::path::Path,
    extra: &[&str],
) -> (std::process::Child, SocketAddr) {
    let mut child = twinbots()
        .args(["serve", "cartpole", "--listen", listen, "--timesteps", &timesteps.to_string(), "--out"])
        .arg(out)
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut stdout = BufReader::new(child.stdout.take().unwrap());
    std::io::BufRead::read_line(&mut stdout, &mut line).unwrap();
    std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    let addr = line.trim().strip_prefix("listening on ").unwrap().parse().unwrap();
    (child, addr)
}

pub fn temp(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn serve_and_robot_as_two_processes_train_a_round_trip() {
    let out = temp("serve");
    let (mut server, addr) = serve_process("127.0.0.1:0", 2048, &out);
    let robots =
        twinbots().args(["robot", "cartpole", "--arenas", "2", "--server", &addr.to_string()]).output().unwrap();
    assert!(robots.status.success(), "{}", String::from_utf8_lossy(&robots.stderr));
    assert!(String::from_utf8_lossy(&robots.stdout).contains("robots done"));
    assert!(server.wait().unwrap().success());
    let rows = std::fs::read_to_string(out.join("progress.csv")).unwrap().lines().count() - 1;
    assert_eq!(rows, 2048 / 64, "one update per 32 steps × 2 robots");
    let model = Ppo::load(out.join("model")).unwrap();
    assert!(model.state.timesteps >= 2048 && model.state.episodes > 0);
    let losses = crate::train_cli::event_scalars(&out).into_iter().filter(|(_, tag, _)| tag == "train/loss").count();
    assert_eq!(losses, rows, "the server logs TensorBoard scalars as train does");
    // It ends as `train` does (`twinbots_run::run::finish`): the final model evaluated in-process.
    let evaluation: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("eval.json")).unwrap()).unwrap();
    assert!(evaluation["episodes"].as_u64().is_some_and(|n| n >= 1), "{evaluation}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["evaluation"]["episodes"], evaluation["episodes"], "{summary}");
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn a_robot_reconnects_with_backoff_when_its_server_goes_away() {
    let (out1, out2) = (temp("reconnect-1"), temp("reconnect-2"));
    let (mut first, addr) = serve_process("127.0.0.1:0", 1_000_000, &out1);
    let robot = twinbots()
        .args(["robot", "cartpole", "--server", &addr.to_string(), "--patience", "20"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Let it train a little (until the first server has logged an update: the robot is
    // connected and stepping, however busy the machine), then take the server away and bring
    // another up on the same port.
    let deadline = Instant::now() + Duration::from_secs(120);
    let rows = || std::fs::read_to_string(out1.join("progress.csv")).map_or(0, |t| t.lines().count());
    while rows() < 2 {
        assert!(Instant::now() < deadline, "the first server never logged an update");
        std::thread::sleep(Duration::from_millis(20));
    }
    first.kill().unwrap();
    first.wait().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let (mut second, _) = serve_process(&addr.to_string(), 1024, &out2);
    let output = robot.wait_with_output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{stdout}{}", String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains("1 reconnections"), "{stdout}");
    assert!(second.wait().unwrap().success());
    for d in [out1, out2] {
        std::fs::remove_dir_all(d).ok();
    }
}

#[test]
fn the_supervisor_cannot_be_used_under_pattern_3() {
    use bevy::prelude::*;
    fn robot_code(_: twinbots_sim::Supervisor) {}
    let mut app = App::new();
    app.add_plugins(MinimalPlugins)
        .add_plugins(twinbots_sim::SimPlugin { supervisor: false, ..Default::default() })
        .add_systems(Update, robot_code);
    let caught = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| app.update()));
    let message = caught.expect_err("a system asking for the Supervisor fails");
    let text = message
        .downcast_ref::<String>()
        .cloned()
        .or_else(|| message.downcast_ref::<&str>().map(|s| s.to_string()))
        .unwrap_or_default();
    assert!(text.contains("design_pattern_3_forbids_the_supervisor"), "{text}");
}
