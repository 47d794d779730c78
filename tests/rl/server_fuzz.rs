//! The RobotServer's connection loop fuzzed over real sockets (the decoder fuzz in
//! `twinbots_link/tests` stops at the decoder): seeded random bytes, mutated valid frames,
//! truncated frames and absurd length prefixes, sent before the handshake, after it, and in an
//! episode. Every connection must get a reply (an error or the protocol's answer) or be closed
//! within a deadline — nothing hangs, nothing panics — and the server must still serve a robot
//! at the end. `TWINBOTS_SERVER_FUZZ_CASES` runs more than the suite's 240.

use std::io::Write;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use twinbots_learn::Flow;
use twinbots_link::protocol::{RobotMessage, ServerMessage};
use twinbots_server::server::ServerLimits;

use crate::server::{Robot, frame, server_with};

/// Valid messages to mutate (after a hello, the server takes start, step, abort and bye).
const SEEDS: &[&str] = &[
    r#"{"type":"hello","version":2,"robot":"cartpole","observation_space":{"Box":{"low":["-inf","-inf","-inf","-inf"],"high":["inf","inf","inf","inf"]}},"action_space":{"Discrete":{"n":2}}}"#,
    r#"{"type":"start","obs":[0.1,-0.2,0.03,0.0]}"#,
    r#"{"type":"step","obs":[0.1,-0.2,0.03,0.0],"reward":1.0,"terminated":false,"truncated":false}"#,
    r#"{"type":"abort"}"#,
    r#"{"type":"bye"}"#,
];
const TOKENS: &[&str] =
    &["1e39", "NaN", "null", "[]", "{}", "\"\"", "-1", "[0,0,0]", "\"step\"", "18446744073709551616"];

fn input(rng: &mut impl Rng) -> Vec<u8> {
    let seed = SEEDS[rng.random_range(0..SEEDS.len())].as_bytes().to_vec();
    match rng.random_range(0..6) {
        0 => (0..rng.random_range(0..64)).map(|_| rng.random()).collect(),
        1 => frame(&(0..rng.random_range(0..256)).map(|_| rng.random()).collect::<Vec<u8>>()),
        2 => {
            // Cut short: the length says more than comes.
            let f = frame(&seed);
            f[..rng.random_range(1..f.len())].to_vec()
        }
        3 => rng.random_range(1u32 << 20..u32::MAX).to_le_bytes().to_vec(),
        _ => {
            let mut p = String::from_utf8(seed).unwrap();
            for _ in 0..rng.random_range(1..4) {
                let colons: Vec<usize> = p.match_indices(':').map(|(i, _)| i + 1).collect();
                let at = colons[rng.random_range(0..colons.len())];
                let end = p[at..].find([',', '}']).map_or(p.len(), |e| at + e);
                p = format!("{}{}{}", &p[..at], TOKENS[rng.random_range(0..TOKENS.len())], &p[end..]);
            }
            let mut bytes = p.into_bytes();
            if rng.random_bool(0.3) && !bytes.is_empty() {
                let i = rng.random_range(0..bytes.len());
                bytes[i] = rng.random();
            }
            frame(&bytes)
        }
    }
}

#[test]
fn fuzzed_connections_get_a_reply_or_a_close_in_time_and_the_server_serves_on() {
    let limits = ServerLimits {
        read_timeout: Duration::from_millis(200),
        handshake_timeout: Duration::from_millis(200),
        ..Default::default()
    };
    let server =
        server_with(1_000_000, 256, limits, Box::new(|_: &_, _: &dyn twinbots_learn::Agent| Ok(Flow::Continue)));
    let cases: usize = std::env::var("TWINBOTS_SERVER_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(240);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(31);
    let (mut replies, mut closes) = (0, 0);
    let start = RobotMessage::Start { obs: vec![0.0; 4] };
    for case in 0..cases {
        // A third before the handshake, a third after it, a third in an episode.
        let mut robot = match case % 3 {
            0 => Robot::connect(server.addr),
            1 => Robot::hello(server.addr),
            _ => {
                let mut r = Robot::hello(server.addr);
                assert!(matches!(r.call(&start), ServerMessage::Action { .. }));
                r
            }
        };
        let bytes = input(&mut rng);
        let t = Instant::now();
        // The server may close at once (a write then fails): that is an answer too.
        let _ = robot.writer.write_all(&bytes);
        match twinbots_link::frame::read_message::<ServerMessage>(&mut robot.reader) {
            Ok(_) => replies += 1,
            Err(_) => closes += 1,
        }
        assert!(t.elapsed() < Duration::from_secs(2), "case {case}: no answer for {:?} to {bytes:?}", t.elapsed());
    }
    eprintln!("server fuzz: {cases} connections, {replies} replies, {closes} closed");
    assert!(replies > cases / 2, "{replies} replies of {cases}: the inputs reached the server");
    let mut robot = Robot::hello(server.addr);
    assert!(matches!(robot.call(&start), ServerMessage::Action { .. }), "the server still serves");
}
