//! RTDE: the client against `ur-sim`'s stand-in in real time (speedj moves the twin, the
//! watchdog stops it), and the bad input both ends must turn into clear errors.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use twinbots_ops::ur_sim::program::{ACCELERATION, COUNTER, MODE, MODE_SPEEDJ, MODE_STOP, ProgramState, STATE, TARGET};
use twinbots_ops::ur_sim::{UrSim, UrSimOptions, controller_info};
use twinbots_rtde::server::{InputState, RtdeServer};
use twinbots_rtde::{RtdeClient, RtdeError, Value};

use crate::robot_hostile::fake_server;

const PATIENCE: Duration = Duration::from_secs(5);

/// A stand-in serving on a free port until dropped.
pub struct Standin {
    pub address: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Vec<String>>>,
}

impl Standin {
    pub fn start(watchdog: f64) -> Self {
        Self::serving(UrSimOptions { watchdog, ..Default::default() })
    }

    /// The stand-in built with `options` (another arm, say).
    pub fn serving(options: UrSimOptions) -> Self {
        let server = RtdeServer::bind("127.0.0.1:0", controller_info()).unwrap();
        let address = server.local_addr();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        // The twin's app stays on the thread that steps it.
        let thread = std::thread::spawn(move || {
            let mut sim = UrSim::new(&options).unwrap();
            sim.serve(&server, Some(60.0), &flag, 1e9);
            server.take_events()
        });
        Self { address, stop, thread: Some(thread) }
    }

    pub fn address(&self) -> String {
        self.address.to_string()
    }
}

impl Drop for Standin {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn int(p: &twinbots_rtde::DataPackage, name: &str) -> i64 {
    p.get(name).and_then(Value::as_i64).unwrap()
}

fn vec6(p: &twinbots_rtde::DataPackage, name: &str) -> [f64; 6] {
    p.vector6(name).unwrap()
}

#[test]
fn rtde_speedj_moves_the_twin_and_the_watchdog_stops_it() {
    let standin = Standin::start(0.1);
    let mut client = RtdeClient::connect(&standin.address(), PATIENCE).unwrap();
    let version = client.controller_version().unwrap();
    assert_eq!((version.major, version.minor), (5, 11));
    let outputs =
        client.setup_outputs(&["timestamp", "actual_q", "actual_qd", "actual_TCP_pose", STATE], 125.0).unwrap();
    assert_eq!(
        outputs.types.iter().map(|t| t.name()).collect::<Vec<_>>(),
        ["DOUBLE", "VECTOR6D", "VECTOR6D", "VECTOR6D", "INT32"]
    );
    let mut names = vec![MODE, COUNTER, ACCELERATION];
    names.extend(TARGET);
    let inputs = client.setup_inputs(&names).unwrap();
    client.start().unwrap();

    // 125 Hz: packages 8 ms apart in the controller's time.
    let first = client.receive().unwrap();
    let second = client.receive().unwrap();
    let t = |p: &twinbots_rtde::DataPackage| p.get("timestamp").and_then(Value::as_f64).unwrap();
    assert!((t(&second) - t(&first) - 0.008).abs() < 1e-9, "{} then {}", t(&first), t(&second));
    let q0 = vec6(&second, "actual_q")[0];

    // speedj: the base at 0.5 rad/s for 1 s of controller time, a fresh counter every package.
    let command = |counter: i32, mode: i32, speed: f64| {
        let mut v = vec![Value::Int32(mode), Value::Int32(counter), Value::Double(0.0)];
        v.extend((0..6).map(|j| Value::Double(if j == 0 { speed } else { 0.0 })));
        v
    };
    let start = t(&second);
    let mut last = second;
    let mut counter = 1;
    while t(&last) < start + 1.0 {
        client.send(&inputs, &command(counter, MODE_SPEEDJ, 0.5)).unwrap();
        counter += 1;
        last = client.receive().unwrap();
    }
    assert_eq!(int(&last, STATE), ProgramState::Speedj as i64);
    let qd = vec6(&last, "actual_qd");
    assert!((qd[0] - 0.5).abs() < 0.02, "base speed {qd:?}");
    assert!(qd[1..].iter().all(|v| v.abs() < 0.02), "the other joints hold: {qd:?}");
    let moved = vec6(&last, "actual_q")[0] - q0;
    assert!((moved - 0.5).abs() < 0.05, "the base turned {moved} rad in 1 s at 0.5 rad/s");

    // The counter stands still: within the 0.1 s watchdog (and a cycle) the program stops the arm.
    let silent_from = t(&last);
    let stopped = loop {
        let p = client.receive().unwrap();
        if int(&p, STATE) == ProgramState::WatchdogStop as i64 {
            break p;
        }
        assert!(t(&p) < silent_from + 0.5, "no watchdog stop 0.5 s after the last command");
    };
    assert!(t(&stopped) - silent_from <= 0.1 + 0.02, "stopped {} s after the last command", t(&stopped) - silent_from);
    let rest = loop {
        let p = client.receive().unwrap();
        if vec6(&p, "actual_qd")[0].abs() < 0.01 {
            break p;
        }
        assert!(t(&p) < t(&stopped) + 0.5, "the base still turns 0.5 s after the stop");
    };
    // A fresh command does not restart it: the stop holds until the client sets mode 0.
    client.send(&inputs, &command(counter + 1, MODE_SPEEDJ, 0.5)).unwrap();
    for _ in 0..10 {
        assert_eq!(int(&client.receive().unwrap(), STATE), ProgramState::WatchdogStop as i64);
    }
    assert!(client.take_messages().iter().any(|m| m.message.contains("watchdog")), "the clients are told why");
    client.send(&inputs, &command(counter + 2, MODE_STOP, 0.0)).unwrap();
    let idle = (0..20).map(|_| client.receive().unwrap()).last().unwrap();
    assert_eq!(int(&idle, STATE), ProgramState::Idle as i64);
    assert!(t(&rest) > 0.0);
}

#[test]
fn rtde_bad_input_gets_clear_errors_and_the_standin_keeps_serving() {
    let standin = Standin::start(0.1);
    let address = standin.address();

    // An unknown output, a bad frequency: named refusals.
    let mut client = RtdeClient::connect(&address, PATIENCE).unwrap();
    match client.setup_outputs(&["actual_q", "no_such_variable"], 125.0) {
        Err(RtdeError::NotFound(names)) => assert_eq!(names, ["no_such_variable"]),
        other => panic!("{other:?}"),
    }
    let err = client.setup_outputs(&["actual_q"], 1000.0).unwrap_err();
    assert!(err.to_string().contains("frequency 1000 Hz outside (0, 500]"), "{err}");
    assert!(matches!(client.start(), Err(RtdeError::Usage(_))), "no start before a recipe");

    // One client per input: the next is told IN_USE, and may have it once the first is gone.
    client.setup_outputs(&["timestamp"], 10.0).unwrap();
    client.setup_inputs(&[MODE, COUNTER]).unwrap();
    let mut second = RtdeClient::connect(&address, PATIENCE).unwrap();
    match second.setup_inputs(&[COUNTER]) {
        Err(RtdeError::InUse(names)) => assert_eq!(names, [COUNTER]),
        other => panic!("{other:?}"),
    }
    drop(client);
    let deadline = Instant::now() + PATIENCE;
    while second.setup_inputs(&[COUNTER]).is_err() {
        assert!(Instant::now() < deadline, "the input stays held after its client left");
        std::thread::sleep(Duration::from_millis(20));
    }

    // Protocol version 1, a package whose size is below its header's, one cut short: the
    // stand-in refuses or closes that connection and goes on serving the next client.
    let mut raw = TcpStream::connect(standin.address).unwrap();
    raw.set_read_timeout(Some(PATIENCE)).unwrap();
    raw.write_all(&[0, 5, b'V', 0, 1]).unwrap();
    let mut reply = [0u8; 4];
    raw.read_exact(&mut reply).unwrap();
    assert_eq!(reply, [0, 4, b'V', 0], "version 1 refused");
    raw.write_all(&[0, 2, b'U']).unwrap();
    let mut rest = Vec::new();
    let _ = raw.read_to_end(&mut rest);
    let text = String::from_utf8_lossy(&rest);
    assert!(text.contains("below the header"), "an error message before the close: {text}");
    let mut cut = TcpStream::connect(standin.address).unwrap();
    cut.write_all(&[0, 40, b'O', 0x40]).unwrap();
    drop(cut);
    let mut after = RtdeClient::connect(&address, PATIENCE).unwrap();
    after.setup_outputs(&["timestamp"], 500.0).unwrap();
    after.start().unwrap();
    after.receive().unwrap();
    after.pause().unwrap();
    drop(after);
    drop(second);
    drop(standin);
}

#[test]
fn rtde_client_gives_up_on_a_silent_or_refusing_controller() {
    // A controller that accepts and never answers: the client's wait ends at its timeout.
    let (silent, _) = fake_server(|stream| {
        std::thread::sleep(Duration::from_secs(3));
        drop(stream);
    });
    let began = Instant::now();
    let err = RtdeClient::connect(&silent.to_string(), Duration::from_millis(300)).err().unwrap();
    assert!(matches!(err, RtdeError::Timeout(_)), "{err}");
    assert!(began.elapsed() < Duration::from_secs(2));

    // One that refuses version 2.
    let (refusing, _) = fake_server(|mut stream| {
        let mut request = [0u8; 5];
        let _ = stream.read_exact(&mut request);
        let _ = stream.write_all(&[0, 4, b'V', 0]);
        std::thread::sleep(Duration::from_millis(500));
    });
    assert!(matches!(RtdeClient::connect(&refusing.to_string(), PATIENCE), Err(RtdeError::VersionRefused(2))));

    // One that stops streaming after the start: receive() times out instead of hanging.
    let standin = Standin::start(0.1);
    let mut client = RtdeClient::connect(&standin.address(), Duration::from_millis(500)).unwrap();
    client.setup_outputs(&["timestamp"], 500.0).unwrap();
    client.start().unwrap();
    client.receive().unwrap();
    drop(standin);
    let began = Instant::now();
    let err = loop {
        match client.receive() {
            Ok(_) => assert!(began.elapsed() < PATIENCE, "still streaming"),
            Err(e) => break e,
        }
    };
    assert!(matches!(err, RtdeError::Closed | RtdeError::Timeout(_) | RtdeError::Io(_)), "{err}");
    // One that answers nothing but text messages, many a millisecond: the client gives up at its
    // timeout (it looped for ever, keeping every message).
    let (chatty, _) = fake_server(|mut stream| {
        let mut request = [0u8; 5];
        let _ = stream.read_exact(&mut request);
        let text = twinbots_rtde::package::TextMessage {
            level: twinbots_rtde::package::MessageLevel::Info,
            message: "hello".into(),
            source: "chatty".into(),
        };
        let bytes = twinbots_rtde::package::Package::new(b'M', text.encode()).encode().unwrap();
        let began = Instant::now();
        while began.elapsed() < Duration::from_secs(5) && stream.write_all(&bytes).is_ok() {}
    });
    let began = Instant::now();
    let err = RtdeClient::connect(&chatty.to_string(), Duration::from_millis(500)).err().unwrap();
    assert!(matches!(err, RtdeError::Timeout(_)), "{err}");
    assert!(began.elapsed() < Duration::from_secs(2), "{:?}", began.elapsed());
    // A wrong recipe name and a malformed address are caught before any traffic.
    assert!(matches!(RtdeClient::connect("robot:port", PATIENCE), Err(RtdeError::Address(_))));
}

#[test]
fn ur_sim_program_runs_without_a_network() {
    // Deterministic: the same inputs give the same trajectory, and speedj ramps at its
    // acceleration.
    let run = || {
        let mut sim = UrSim::new(&UrSimOptions::default()).unwrap();
        let mut inputs = InputState::new();
        inputs.set(MODE, Value::Int32(MODE_SPEEDJ));
        inputs.set(ACCELERATION, Value::Double(5.0));
        inputs.set(TARGET[1], Value::Double(-0.5));
        let mut trace = Vec::new();
        for k in 0..250 {
            inputs.set(COUNTER, Value::Int32(k));
            let (out, _) = sim.cycle(&inputs);
            trace.push(out.get("actual_q"));
        }
        (trace, sim.program.target_qd)
    };
    let (a, target_qd) = run();
    let (b, _) = run();
    assert_eq!(a, b);
    // 5 rad/s² reaches 0.5 rad/s in 0.1 s (50 cycles); after 250 it holds.
    assert!((target_qd[1] + 0.5).abs() < 1e-9, "{target_qd:?}");
}

/// The stand-in bounds its clients: one past the limit is closed at once, a client silent
/// before starting its stream is closed after the idle limit, a streaming one may just listen;
/// `ur-sim` listens beyond loopback only with `--insecure`.
#[test]
fn the_standin_caps_its_clients_and_closes_silent_ones() {
    use twinbots_rtde::server::Limits;
    let limits = Limits { max_clients: 2, idle: Duration::from_millis(400) };
    let server = RtdeServer::bind_with("127.0.0.1:0", controller_info(), limits).unwrap();
    let address = server.local_addr();
    // The stand-in never speaks first: a read that ends (0 bytes) is the connection closed.
    let closed_within = |stream: &mut TcpStream, within: Duration| {
        stream.set_read_timeout(Some(within)).unwrap();
        stream.read(&mut [0u8; 1]).is_ok_and(|n| n == 0)
    };
    let mut first = TcpStream::connect(address).unwrap();
    let _second = TcpStream::connect(address).unwrap();
    std::thread::sleep(Duration::from_millis(100));
    let mut third = TcpStream::connect(address).unwrap();
    assert!(closed_within(&mut third, Duration::from_secs(2)), "a third client was served");
    // The first said nothing: closed after the idle limit, and its place is free again.
    let began = Instant::now();
    assert!(closed_within(&mut first, Duration::from_secs(5)), "a silent client stayed");
    assert!(began.elapsed() < Duration::from_secs(3), "{:?}", began.elapsed());
    std::thread::sleep(Duration::from_millis(100));
    let mut client = RtdeClient::connect(&address.to_string(), PATIENCE).unwrap();
    client.setup_outputs(&["timestamp"], 125.0).unwrap();
    client.start().unwrap();
    let events = server.take_events().join("\n");
    assert!(events.contains("refused (2 clients connected already)"), "{events}");
    assert!(events.contains("silent for 0.4 s before starting its stream"), "{events}");

    let output =
        crate::delivery::twinbots().args(["ur-sim", "--listen", "0.0.0.0:0", "--seconds", "1"]).output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("--insecure"), "{stderr}");
}
