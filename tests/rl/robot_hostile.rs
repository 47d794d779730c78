//! A robot against broken and hostile servers (issue 32): `twinbots robot` exits non-zero with
//! the real reason within its `--patience`, whichever point of the exchange the server fails
//! at, and never storms a server that drops its connections.

use std::io::Write;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::process::Output;
use std::sync::Arc;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use twinbots_link::frame::read_frame;
use twinbots_link::protocol::{ErrorCode, ServerMessage, TaskInterface, VERSION, error};

use crate::server::{frame, twinbots};

/// A stand-in server on a free loopback port: `script` runs on every connection it accepts
/// (each on its own thread); the count is of connections accepted.
pub fn fake_server(script: impl Fn(TcpStream) + Send + Sync + 'static) -> (SocketAddr, Arc<AtomicU32>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let count = Arc::new(AtomicU32::new(0));
    let (script, accepted) = (Arc::new(script), count.clone());
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            accepted.fetch_add(1, Ordering::SeqCst);
            let script = script.clone();
            std::thread::spawn(move || script(stream));
        }
    });
    (addr, count)
}

fn send(stream: &mut TcpStream, message: &ServerMessage) {
    let _ = stream.write_all(&frame(&serde_json::to_vec(message).unwrap()));
}

/// What a cart-pole server's welcome says, as JSON (to be edited by a test).
fn welcome() -> serde_json::Value {
    let spec = twinbots_run::registry::find("cartpole").unwrap().task();
    serde_json::to_value(ServerMessage::Welcome {
        version: VERSION,
        robot_id: 7,
        task: TaskInterface::of("cartpole", &spec),
    })
    .unwrap()
}

/// Reads the hello, welcomes, and answers the next `answered` requests with an action.
fn welcome_and_answer(stream: &mut TcpStream, welcome: &serde_json::Value, answered: usize) {
    let _ = read_frame(stream);
    let _ = stream.write_all(&frame(welcome.to_string().as_bytes()));
    for _ in 0..answered {
        let _ = read_frame(stream);
        send(stream, &ServerMessage::Action { action: vec![1.0] });
    }
}

/// Holds a connection open without a word for longer than any test waits.
fn silent(stream: TcpStream) {
    std::thread::sleep(Duration::from_secs(30));
    drop(stream);
}

/// `twinbots robot cartpole` against `addr` with 2 s of patience: its output and how long it ran.
fn robot(addr: SocketAddr) -> (Output, Duration) {
    let started = Instant::now();
    let output =
        twinbots().args(["robot", "cartpole", "--server", &addr.to_string(), "--patience", "2"]).output().unwrap();
    (output, started.elapsed())
}

/// The robot failed, within its patience (and start-up), saying `reason`.
fn fails_saying(addr: SocketAddr, reason: &str) {
    let (output, took) = robot(addr);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "a robot against a broken server succeeded: {stderr}");
    assert!(stderr.contains(reason), "expected {reason:?} in:\n{stderr}");
    assert!(took < Duration::from_secs(8), "it took {took:?} to give up: {stderr}");
}

#[test]
fn a_server_silent_at_any_point_of_the_exchange_ends_the_robot_within_its_patience() {
    let (addr, _) = fake_server(silent);
    fails_saying(addr, &format!("the server at {addr} sent no welcome within 2.0s"));
    let (addr, _) = fake_server(|mut s| {
        let _ = read_frame(&mut s);
        silent(s);
    });
    fails_saying(addr, "sent no welcome within 2.0s");
    // After welcome: silent on the first `start`, and after some answered steps.
    for answered in [0, 5] {
        let (addr, _) = fake_server(move |mut s| {
            welcome_and_answer(&mut s, &welcome(), answered);
            silent(s);
        });
        fails_saying(addr, "sent no reply within 2.0s");
    }
    // After a refusal that leaves the robot without an action, and after an empty action.
    let (addr, _) = fake_server(|mut s| {
        welcome_and_answer(&mut s, &welcome(), 0);
        let _ = read_frame(&mut s);
        send(&mut s, &error(ErrorCode::OutOfOrder, false, "not now"));
        silent(s);
    });
    fails_saying(addr, "sent no reply within 2.0s");
    let (addr, _) = fake_server(|mut s| {
        welcome_and_answer(&mut s, &welcome(), 0);
        let _ = read_frame(&mut s);
        send(&mut s, &ServerMessage::Action { action: vec![] });
        silent(s);
    });
    fails_saying(addr, "it sent the action [], outside this robot's action space Discrete(2)");
}

#[test]
fn a_server_that_closes_after_welcome_sees_a_handful_of_connections_a_second() {
    let (addr, connections) = fake_server(|mut s| welcome_and_answer(&mut s, &welcome(), 0));
    let (output, took) = robot(addr);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("answered no request on them (it closes them)"), "{stderr}");
    let n = connections.load(Ordering::SeqCst);
    // Backoff 20 ms doubling to 1 s: 7 connections in the first 2 s (53,140 in 15 s before).
    assert!((2..=10).contains(&n), "{n} connections in {took:?}: {stderr}");
}

#[test]
fn garbage_other_versions_and_other_robots_are_named_not_unreachable() {
    let cases: [(&[u8], &str); 3] = [
        (b"HTTP/1.1 400 Bad Request\r\n\r\n", "unreadable welcome: frame of"),
        (&[0xff, 0xff, 0xff, 0xff], "unreadable welcome: frame of 4294967295 bytes exceeds"),
        (b"\x05\x00\x00\x00hello", "its reply to hello is not a message"),
    ];
    for (reply, reason) in cases {
        let (addr, _) = fake_server(move |mut s| {
            let _ = read_frame(&mut s);
            let _ = s.write_all(reply);
            silent(s);
        });
        fails_saying(addr, reason);
    }
    let edited = |edit: fn(&mut serde_json::Value)| {
        let mut w = welcome();
        edit(&mut w);
        w
    };
    let cases = [
        (edited(|w| w["version"] = 3.into()), "it speaks protocol version 3; this robot speaks version 2"),
        (edited(|w| w["task"]["robot"] = "ur5e".into()), "it welcomed a \"ur5e\", not this \"cartpole\""),
        (
            edited(|w| w["task"]["action_space"] = serde_json::json!({"Discrete": {"n": 3}})),
            "its model has observation Box(4) and action Discrete(3)",
        ),
    ];
    for (welcome, reason) in cases {
        let (addr, _) = fake_server(move |mut s| {
            welcome_and_answer(&mut s, &welcome, 0);
            silent(s);
        });
        fails_saying(addr, reason);
    }
}

#[test]
fn an_empty_token_is_refused_as_a_value() {
    for command in [
        &["serve", "cartpole", "--token", ""][..],
        &["robot", "cartpole", "--server", "127.0.0.1:9", "--token", ""][..],
    ] {
        let output = twinbots().args(command).output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success(), "{command:?} accepted an empty token");
        assert!(stderr.contains("an empty token is refused"), "{stderr}");
    }
}

/// A token is not sent in clear beyond this machine: without TLS the robot refuses, naming
/// `--tls-ca` and `--insecure`, before it connects (192.0.2.1 is TEST-NET-1: nothing answers).
#[test]
fn a_token_is_not_sent_in_clear_beyond_loopback() {
    let output =
        twinbots().args(["robot", "cartpole", "--server", "192.0.2.1:7878", "--token", "secret"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "sent the token in clear");
    assert!(
        stderr.contains("travel in clear") && stderr.contains("--tls-ca") && stderr.contains("--insecure"),
        "{stderr}"
    );
}
