//! Hostile and broken RobotServer clients (issue 15) and a failing server (issue 18): each case
//! reproduces what a client did and shows the fix: refused at the boundary with an error
//! reply naming why, logged, and the other robots served on; or, for the server's own
//! failures, an error instead of a hang.

use std::io::{Read, Write};
use std::net::SocketAddr;
use std::process::Stdio;
use std::time::{Duration, Instant};

use twinbots_learn::{Flow, UpdateStats};
use twinbots_link::protocol::{ErrorCode, RobotMessage, ServerMessage, VERSION};
use twinbots_server::server::ServerLimits;

use crate::server::{Robot, frame, hello, serve_process, server, server_with, temp, twinbots};

fn code(reply: &ServerMessage) -> (ErrorCode, bool) {
    match reply {
        ServerMessage::Error { code, fatal, .. } => (*code, *fatal),
        other => panic!("expected an error reply, got {other:?}"),
    }
}

fn message(reply: &ServerMessage) -> &str {
    match reply {
        ServerMessage::Error { message, .. } => message,
        other => panic!("expected an error reply, got {other:?}"),
    }
}

/// Whether the server closed the connection (end of stream within the read timeout).
fn closed(robot: &mut Robot) -> bool {
    let mut byte = [0u8; 1];
    matches!(robot.reader.read(&mut byte), Ok(0) | Err(_))
}

fn step_json(obs: &str, reward: &str) -> Vec<u8> {
    frame(format!(r#"{{"type":"step","obs":{obs},"reward":{reward},"terminated":false,"truncated":false}}"#).as_bytes())
}

#[test]
fn a_reward_of_1e39_is_refused_and_never_reaches_the_learner() {
    let server = server(1_000_000);
    let mut robot = Robot::hello(server.addr);
    robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    robot.step();
    assert_eq!(server.load().1, 1);
    // Valid JSON, but infinite as an f32: it once made every loss NaN.
    let reply = robot.raw(&step_json("[0,0,0,0]", "1e39"));
    assert_eq!(code(&reply), (ErrorCode::NonFinite, false), "{reply:?}");
    assert!(message(&reply).contains("reward"), "{reply:?}");
    let reply = robot.raw(&step_json("[0,0,0,0]", "-1e39"));
    assert_eq!(code(&reply), (ErrorCode::NonFinite, false));
    // Beyond f64 too: serde refuses it as malformed.
    let reply = robot.raw(&step_json("[0,0,0,0]", "1e400"));
    assert_eq!(code(&reply), (ErrorCode::Malformed, false));
    assert_eq!(server.load().1, 1, "nothing refused was recorded");
    assert!(matches!(robot.step(), ServerMessage::Action { .. }), "the robot goes on after a refusal");
    assert_eq!(server.load().1, 2);
}

#[test]
fn non_finite_observations_are_refused() {
    let server = server(1_000_000);
    let mut robot = Robot::hello(server.addr);
    // JSON has no NaN: the literal is malformed; an overflowing value is infinite as f32.
    let reply = robot.raw(&frame(br#"{"type":"start","obs":[0,NaN,0,0]}"#));
    assert_eq!(code(&reply), (ErrorCode::Malformed, false));
    let reply = robot.raw(&frame(br#"{"type":"start","obs":[0,0,3.5e38,0]}"#));
    assert_eq!(code(&reply), (ErrorCode::NonFinite, false));
    assert!(message(&reply).contains("pole_angle"), "names the value: {reply:?}");
    robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    let reply = robot.raw(&step_json("[0,-1e39,0,0]", "1"));
    assert_eq!(code(&reply), (ErrorCode::NonFinite, false));
    assert_eq!(server.load().1, 0);
}

#[test]
fn rewards_outside_the_tasks_range_are_refused_so_no_robot_can_claim_solved() {
    use twinbots_api::SolvedCriterion;
    use twinbots_learn::CallbackList;
    use twinbots_learn::callbacks::StopTrainingOnSolved;
    // The cart-pole pays exactly 1 per step; a robot claiming 1000 per step once ended
    // training as "solved after 128 steps".
    let callbacks = CallbackList::new().with(StopTrainingOnSolved::new(SolvedCriterion::mean_score(1, 100.0)));
    let server = server_with(1_000_000, 8, ServerLimits::default(), Box::new(callbacks));
    let mut robot = Robot::hello(server.addr);
    let rich = |terminated| RobotMessage::Step {
        obs: vec![0.0; 4],
        reward: 1000.0,
        terminated,
        truncated: false,
        success: None,
        ended_by: None,
    };
    for _ in 0..3 {
        robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
        for i in 0..4 {
            let reply = robot.call(&rich(i == 3));
            assert_eq!(code(&reply), (ErrorCode::RewardOutOfRange, false), "{reply:?}");
            assert!(message(&reply).contains("[1, 1]"), "names the range: {reply:?}");
        }
    }
    assert_eq!(server.load().1, 0);
    // Honest steps are taken, and training is not over.
    for _ in 0..8 {
        assert!(matches!(robot.step(), ServerMessage::Action { .. }));
    }
    assert!(matches!(robot.step(), ServerMessage::Action { .. }), "not solved");
}

#[test]
fn a_4_gib_length_prefix_is_refused_at_once_and_the_others_are_served() {
    let server = server(1_000_000);
    let mut hostile = Robot::hello(server.addr);
    let mut other = Robot::hello(server.addr);
    let t = Instant::now();
    let reply = hostile.raw(&u32::MAX.to_le_bytes());
    assert_eq!(code(&reply), (ErrorCode::Oversized, true), "{reply:?}");
    assert!(closed(&mut hostile), "a frame too large to skip closes the connection");
    assert!(t.elapsed() < Duration::from_secs(2), "no waiting for 4 GiB: {:?}", t.elapsed());
    assert!(matches!(other.call(&RobotMessage::Start { obs: vec![0.0; 4] }), ServerMessage::Action { .. }));
}

#[test]
fn half_a_frame_then_silence_times_out() {
    let limits = ServerLimits {
        read_timeout: Duration::from_millis(300),
        handshake_timeout: Duration::from_millis(300),
        ..Default::default()
    };
    let server =
        server_with(1_000_000, 256, limits, Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)));
    // After the handshake: a frame of 100 bytes announced, 10 sent.
    let mut robot = Robot::hello(server.addr);
    let t = Instant::now();
    let mut half = 100u32.to_le_bytes().to_vec();
    half.extend_from_slice(br#"{"type":"s"#);
    let reply = robot.raw(&half);
    assert_eq!(code(&reply), (ErrorCode::Timeout, true), "{reply:?}");
    assert!(closed(&mut robot));
    assert!(t.elapsed() >= Duration::from_millis(250) && t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());
    // A trickle does not reset the clock: the deadline is per message.
    let mut robot = Robot::hello(server.addr);
    let t = Instant::now();
    robot.writer.write_all(&100u32.to_le_bytes()).unwrap();
    let trickle = std::thread::spawn({
        let mut w = robot.writer.try_clone().unwrap();
        move || {
            for _ in 0..20 {
                std::thread::sleep(Duration::from_millis(100));
                if w.write_all(b" ").is_err() {
                    break;
                }
            }
        }
    });
    let reply: ServerMessage = twinbots_link::frame::read_message(&mut robot.reader).unwrap();
    assert_eq!(code(&reply), (ErrorCode::Timeout, true));
    assert!(t.elapsed() < Duration::from_millis(1500), "{:?}", t.elapsed());
    trickle.join().unwrap();
    // Before the handshake: connected, silent.
    let mut silent = Robot::connect(server.addr);
    let reply: ServerMessage = twinbots_link::frame::read_message(&mut silent.reader).unwrap();
    assert_eq!(code(&reply), (ErrorCode::Timeout, true));
    assert_eq!(server.load().0, 0);
}

#[test]
fn the_65th_robot_is_refused_over_the_cap_of_64() {
    let server = server(1_000_000);
    let robots: Vec<Robot> = (0..64).map(|_| Robot::hello(server.addr)).collect();
    let mut extra = Robot::connect(server.addr);
    let reply = extra.call(&hello(None));
    assert_eq!(code(&reply), (ErrorCode::ServerFull, true), "{reply:?}");
    assert!(message(&reply).contains("--max-robots 64"), "{reply:?}");
    assert_eq!(server.load().0, 64);
    // One leaves: there is room again.
    drop(robots);
    let t = Instant::now();
    loop {
        let mut again = Robot::connect(server.addr);
        match again.call(&hello(None)) {
            ServerMessage::Welcome { .. } => break,
            reply => assert_eq!(code(&reply).0, ErrorCode::ServerFull),
        }
        assert!(t.elapsed() < Duration::from_secs(5), "slots are given back");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_wrong_or_missing_token_is_refused() {
    let limits = ServerLimits { token: Some("s3cret".into()), ..Default::default() };
    let server =
        server_with(1_000_000, 256, limits, Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)));
    for (token, why) in [(None, "needs a token"), (Some("guess"), "wrong token"), (Some("s3cre"), "wrong token")] {
        let mut robot = Robot::connect(server.addr);
        let reply = robot.call(&hello(token));
        assert_eq!(code(&reply), (ErrorCode::Unauthorized, true), "{reply:?}");
        assert!(message(&reply).contains(why), "{reply:?}");
        assert!(closed(&mut robot));
    }
    let mut robot = Robot::connect(server.addr);
    assert!(matches!(robot.call(&hello(Some("s3cret"))), ServerMessage::Welcome { .. }));
    assert_eq!(server.rejections(), 3);
}

#[test]
fn a_version_1_hello_is_told_which_version_to_speak() {
    let server = server(1_000_000);
    // Exactly what a v1 Communicator sent.
    let v1 = br#"{"type":"hello","version":1,"robot":"cartpole","observation_space":{"Box":{"low":["-inf","-inf","-inf","-inf"],"high":["inf","inf","inf","inf"]}},"action_space":{"Discrete":{"n":2}}}"#;
    for payload in [&v1[..], br#"{"type":"hello","robot":"cartpole"}"#, br#"{"type":"hello","version":3,"shiny":true}"#]
    {
        let mut robot = Robot::connect(server.addr);
        let reply = robot.raw(&frame(payload));
        assert_eq!(code(&reply), (ErrorCode::UnsupportedVersion, true), "{reply:?}");
        assert!(message(&reply).contains(&format!("version {VERSION}")), "{reply:?}");
        assert!(closed(&mut robot));
    }
    // Anything before hello is refused too.
    let mut robot = Robot::connect(server.addr);
    let reply = robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    assert_eq!(code(&reply), (ErrorCode::HandshakeExpected, true));
}

#[test]
fn welcome_carries_the_tasks_interface_as_robots_json_prints_it() {
    let server = server(1_000_000);
    let mut robot = Robot::connect(server.addr);
    let ServerMessage::Welcome { task, .. } = robot.call(&hello(None)) else { panic!("no welcome") };
    let spec = cartpole::task_spec();
    assert_eq!(task.observation_space, spec.observation_space);
    assert_eq!(task.observation_names, ["cart_x", "cart_velocity", "pole_angle", "pole_rate"]);
    assert_eq!((task.reward_range.low, task.reward_range.high), (1.0, 1.0));
    assert_eq!(task.control_period_s, Some(0.032), "the cart-pole acts every 32 ms");
    let out = twinbots().args(["robots", "--json"]).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(doc["protocol_version"], VERSION);
    let robots = doc["robots"].as_array().unwrap();
    let cartpole = robots.iter().find(|r| r["name"] == "cartpole").unwrap();
    assert_eq!(cartpole["tasks"][0], serde_json::to_value(&task).unwrap(), "the same description");
    for robot in robots {
        for task in robot["tasks"].as_array().unwrap() {
            let task: twinbots_link::protocol::TaskInterface = serde_json::from_value(task.clone()).unwrap();
            assert_eq!(task.observation_names.len(), task.observation_space.dim(), "{}", task.task);
            assert!(task.reward_range.high.is_finite(), "{}: a declared upper bound", task.task);
            assert!(task.control_period_s.is_some_and(|s| s > 0.0 && s < 1.0), "{}: a control period", task.task);
        }
    }
}

#[test]
fn abort_drops_the_running_episode_and_is_acknowledged() {
    let server = server(1_000_000);
    let mut robot = Robot::hello(server.addr);
    robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    for _ in 0..3 {
        robot.step();
    }
    assert_eq!(server.load().1, 3);
    assert_eq!(robot.call(&RobotMessage::Abort), ServerMessage::Ack);
    assert_eq!(server.load().1, 0, "the aborted episode is not learned from");
    assert_eq!(code(&robot.step()), (ErrorCode::OutOfOrder, false), "no action awaits an outcome");
    assert_eq!(robot.call(&RobotMessage::Abort), ServerMessage::Ack, "abort with no episode is fine");
    assert!(matches!(robot.call(&RobotMessage::Start { obs: vec![0.0; 4] }), ServerMessage::Action { .. }));
}

#[test]
fn a_panic_in_the_learner_ends_wait_with_the_reason() {
    let panicking =
        |_: &UpdateStats, _: &dyn twinbots_learn::Agent| -> anyhow::Result<Flow> { panic!("boom in the update") };
    let server = server_with(1_000_000, 8, ServerLimits::default(), Box::new(panicking));
    let mut robot = Robot::hello(server.addr);
    let mut bystander = Robot::hello(server.addr);
    robot.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    for _ in 0..7 {
        robot.step();
    }
    let reply = robot.step(); // the 8th fills the rollout: the update panics
    assert_eq!(code(&reply), (ErrorCode::LearnerFailed, true), "{reply:?}");
    assert!(message(&reply).contains("boom in the update"));
    let reply = bystander.call(&RobotMessage::Start { obs: vec![0.0; 4] });
    assert_eq!(code(&reply), (ErrorCode::LearnerFailed, true), "the others hear it too: {reply:?}");
    let (done, waited) = std::sync::mpsc::channel();
    std::thread::spawn(move || done.send(server.wait().map(|_| ()).unwrap_err().to_string()));
    let error = waited.recv_timeout(Duration::from_secs(10)).expect("wait returns instead of hanging");
    assert!(error.contains("the learner panicked: boom in the update"), "{error}");
}

#[test]
fn a_connection_without_a_thread_is_refused_and_accepting_goes_on() {
    // A stack no system can give: every connection thread fails to start.
    let limits = ServerLimits { connection_stack: 1 << 50, ..Default::default() };
    let server =
        server_with(1_000_000, 256, limits, Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)));
    for _ in 0..3 {
        let mut robot = Robot::connect(server.addr);
        let reply = robot.call(&hello(None));
        assert_eq!(code(&reply), (ErrorCode::Unavailable, true), "{reply:?}");
        assert!(message(&reply).contains("no thread"), "{reply:?}");
    }
    assert_eq!(server.load().0, 0);
    assert_eq!(server.rejections(), 3);
}

/// Runs `twinbots args…`, which must fail within `limit` (not spin), and returns its stderr.
fn fails_quickly(args: &[&str], limit: Duration) -> String {
    let mut child = twinbots().args(args).stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let t = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut stderr = String::new();
            child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
            assert_eq!(status.code(), Some(1), "{args:?}: {stderr}");
            return stderr;
        }
        if t.elapsed() > limit {
            child.kill().unwrap();
            panic!("{args:?} still running after {limit:?}");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn zero_arenas_are_a_clear_error_not_a_spin() {
    let stderr =
        fails_quickly(&["robot", "cartpole", "--arenas", "0", "--server", "127.0.0.1:9"], Duration::from_secs(30));
    assert!(stderr.contains("--arenas 0: at least one robot"), "{stderr}");
    let out = temp("arenas-0");
    let out = out.to_str().unwrap();
    let stderr =
        fails_quickly(&["train", "cartpole", "--pattern", "3", "--arenas", "0", "--out", out], Duration::from_secs(30));
    assert!(stderr.contains("arenas = 0"), "{stderr}");
    let stderr = fails_quickly(
        &["serve", "cartpole", "--listen", "127.0.0.1:0", "--max-robots", "0", "--out", out],
        Duration::from_secs(30),
    );
    assert!(stderr.contains("--max-robots must be at least 1"), "{stderr}");
}

#[test]
fn serve_logs_refusals_with_the_peer() {
    let out = temp("refusal-log");
    let mut server = twinbots()
        .args(["serve", "cartpole", "--listen", "127.0.0.1:0", "--robots", "1", "--timesteps", "64", "--out"])
        .arg(&out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut stdout = std::io::BufReader::new(server.stdout.take().unwrap());
    std::io::BufRead::read_line(&mut stdout, &mut line).unwrap();
    std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    let addr: SocketAddr = line.trim().strip_prefix("listening on ").unwrap().parse().unwrap();
    let mut stderr_pipe = server.stderr.take().unwrap();
    let mut refused = Robot::connect(addr);
    let peer = refused.writer.local_addr().unwrap();
    assert_eq!(code(&refused.raw(&frame(br#"{"type":"hello","version":1}"#))).0, ErrorCode::UnsupportedVersion);
    let robots = twinbots().args(["robot", "cartpole", "--server", &addr.to_string()]).output().unwrap();
    assert!(robots.status.success(), "{}", String::from_utf8_lossy(&robots.stderr));
    assert!(server.wait().unwrap().success());
    let mut stderr = String::new();
    stderr_pipe.read_to_string(&mut stderr).unwrap();
    assert!(stderr.contains(&format!("refused {peer}")), "{stderr}");
    std::fs::remove_dir_all(&out).ok();
}

/// A hosted run whose learner panics in its first update ends with that error instead of
/// hanging, and its robots hear that training failed (a callback that panics stands for a
/// learner that does: no settings that pass validation make an update fail).
#[test]
fn a_hosted_run_ends_with_an_error_when_its_learner_panics() {
    use twinbots_run::run::{Hosting, Run};
    use twinbots_run::settings::{ConfigFile, TrainSettings};
    let out = temp("learner-panic");
    let entry = twinbots_run::registry::find("cartpole").unwrap();
    let flags = ConfigFile { arenas: Some(1), timesteps: Some(100_000), pattern: Some(3), ..Default::default() };
    let settings = TrainSettings::resolve(&entry, ConfigFile::default(), flags).unwrap();
    let mut run = Run::create(settings, &out).unwrap();
    run.extra_callbacks.push(|_: &UpdateStats, _: &dyn twinbots_learn::Agent| -> anyhow::Result<Flow> {
        panic!("the learner panics in its update")
    });
    let (tx, rx) = std::sync::mpsc::channel();
    let hosting = Hosting { listen: "127.0.0.1:0".parse().unwrap(), limits: ServerLimits::default() };
    let host = std::thread::spawn(move || {
        run.host(hosting, |addr| {
            tx.send(addr).unwrap();
            Ok(())
        })
    });
    let addr: SocketAddr = rx.recv_timeout(Duration::from_secs(60)).unwrap();
    let robots = twinbots().args(["robot", "cartpole", "--server", &addr.to_string()]).output().unwrap();
    assert!(!robots.status.success(), "the robots hear that the learner failed");
    let t = Instant::now();
    while !host.is_finished() {
        assert!(t.elapsed() < Duration::from_secs(60), "the hosted run hangs after its learner panicked");
        std::thread::sleep(Duration::from_millis(20));
    }
    let error = host.join().unwrap().unwrap_err();
    assert!(format!("{error:#}").contains("training failed: the learner panicked"), "{error:#}");
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn serve_and_robot_agree_on_a_token_from_the_environment() {
    let out = temp("token");
    let mut server = twinbots()
        .args(["serve", "cartpole", "--listen", "127.0.0.1:0", "--robots", "1", "--timesteps", "64", "--out"])
        .arg(&out)
        .env("TWINBOTS_TOKEN", "from-env")
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    let mut stdout = std::io::BufReader::new(server.stdout.take().unwrap());
    std::io::BufRead::read_line(&mut stdout, &mut line).unwrap();
    std::thread::spawn(move || std::io::copy(&mut stdout, &mut std::io::sink()));
    let addr = line.trim().strip_prefix("listening on ").unwrap().to_string();
    let wrong = twinbots().args(["robot", "cartpole", "--server", &addr, "--token", "nope"]).output().unwrap();
    assert!(!wrong.status.success());
    assert!(
        String::from_utf8_lossy(&wrong.stderr).contains("wrong token"),
        "{}",
        String::from_utf8_lossy(&wrong.stderr)
    );
    let right =
        twinbots().args(["robot", "cartpole", "--server", &addr]).env("TWINBOTS_TOKEN", "from-env").output().unwrap();
    assert!(right.status.success(), "{}", String::from_utf8_lossy(&right.stderr));
    assert!(server.wait().unwrap().success());
    std::fs::remove_dir_all(&out).ok();
    let _ = serve_process; // the shared helper, used by server.rs
}

/// One robot of `spec` trains a normalising PPO server for about two rollouts on a fixed,
/// plausible sensor sequence; with `attack`, its sensor also reports ±1e6 every seventh step
/// (each such step is sent before the true one). The actions it got and the server's
/// observation statistics.
fn trained_under_attack(
    robot_name: &str,
    spec: &twinbots_api::TaskSpec,
    attack: bool,
) -> (Vec<Vec<f32>>, twinbots_learn::normalize::RunningMeanStd) {
    use twinbots_learn::{Ppo, PpoConfig};
    use twinbots_server::server::{RobotServer, ServerSettings};
    let config = PpoConfig { normalize_observations: true, ..PpoConfig::zoo_cartpole() };
    let model = Box::new(Ppo::new(config, spec.observation_space.clone(), spec.action_space.clone(), 0).unwrap());
    // Updates every 128 steps: 4 robots' worth of 32.
    let server = RobotServer::start(
        "127.0.0.1:0".parse().unwrap(),
        model,
        ServerSettings::new(robot_name, spec, 4, 300),
        Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)),
    )
    .unwrap();
    let mut robot = crate::server::Robot::connect(server.addr);
    let hello = RobotMessage::Hello {
        version: VERSION,
        robot: robot_name.into(),
        observation_space: spec.observation_space.clone(),
        action_space: spec.action_space.clone(),
        token: None,
    };
    assert!(matches!(robot.call(&hello), ServerMessage::Welcome { .. }));
    let dim = spec.observation_space.dim();
    // Readings well inside every value's plausible range (and the UR5e's bounded terms).
    let reading = |t: usize| (0..dim).map(|i| 0.5 * ((t * 7 + i * 3) as f32 * 0.1).sin()).collect::<Vec<f32>>();
    let reward = 0f32.clamp(spec.reward_range.0, spec.reward_range.1);
    let mut actions = Vec::new();
    let mut reply = robot.call(&RobotMessage::Start { obs: reading(0) });
    for t in 1.. {
        match reply {
            ServerMessage::Action { action } => actions.push(action),
            ServerMessage::Ack => {}
            ServerMessage::Done { .. } => break,
            other => panic!("{other:?}"),
        }
        if attack && t % 7 == 0 {
            let mut wild = reading(t);
            wild[t % dim] = if t % 14 == 0 { -1e6 } else { 1e6 };
            let refused = robot.call(&RobotMessage::Step {
                obs: wild,
                reward,
                terminated: false,
                truncated: false,
                success: None,
                ended_by: None,
            });
            assert_eq!(code(&refused), (ErrorCode::ObservationOutOfRange, false), "{refused:?}");
            assert!(message(&refused).contains("outside its plausible range"), "{refused:?}");
        }
        let ended = t % 50 == 0;
        reply = robot.call(&RobotMessage::Step {
            obs: reading(t),
            reward,
            terminated: ended,
            truncated: false,
            success: None,
            ended_by: None,
        });
        if ended {
            assert_eq!(reply, ServerMessage::Ack);
            reply = robot.call(&RobotMessage::Start { obs: reading(t) });
        }
    }
    let (model, _) = server.wait().unwrap();
    (actions, model.policy_net().unwrap().obs_rms.expect("the model normalises"))
}

#[test]
fn a_faulty_sensors_1e6_is_refused_and_training_ends_as_a_clean_run() {
    for (name, spec) in [("cartpole", cartpole::task_spec()), ("ur5e", ur5e::task_spec())] {
        let (clean_actions, clean_rms) = trained_under_attack(name, &spec, false);
        let (attacked_actions, attacked_rms) = trained_under_attack(name, &spec, true);
        assert!(clean_actions.len() > 256, "{name}: two rollouts and more");
        assert_eq!(attacked_rms, clean_rms, "{name}: the attack never reached the statistics");
        assert_eq!(attacked_actions, clean_actions, "{name}: nor the policy");
        assert!(clean_rms.var.iter().all(|v| *v < 1.0), "{name}: {:?}", clean_rms.var);
    }
}
