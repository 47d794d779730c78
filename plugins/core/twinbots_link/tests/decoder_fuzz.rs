//! Fuzzing the server's side of the wire: frame reading, decoding and the boundary checks
//! (`check_hello`, `check_request`) get generated and mutated inputs (random bytes, mutated
//! valid frames, huge length prefixes, truncated frames, deep JSON, wrong types, non-finite
//! numbers) from a seeded generator (stable Rust, reproducible). None may panic, and whatever
//! the checks accept must be finite, of the task's length and within its reward range.
//!
//! The suite runs 20 000 inputs; `TWINBOTS_FUZZ_CASES=1000000 cargo test --release -p
//! twinbots_server --test decoder_fuzz -- --nocapture` runs a million (and prints the count).
//! `TWINBOTS_FUZZ_SEED` picks another seed.

use std::io::Cursor;
use std::panic::{AssertUnwindSafe, catch_unwind};

use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use twinbots_api::Space;
use twinbots_link::checks::{Admission, check_hello, check_request};
use twinbots_link::frame::{FrameError, read_frame, read_message};
use twinbots_link::protocol::{MAX_FRAME, RewardRange, RobotMessage, TaskInterface};

fn task() -> TaskInterface {
    TaskInterface {
        robot: "cartpole".into(),
        task: "cartpole".into(),
        observation_space: Space::uniform_box(4, f32::NEG_INFINITY, f32::INFINITY),
        observation_names: ["x", "v", "a", "r"].map(String::from).to_vec(),
        observation_plausible: Some(Space::uniform_box(4, -100.0, 100.0)),
        action_space: Space::Discrete { n: 2 },
        reward_range: RewardRange { low: -2.0, high: 1.0 },
        reward_terms: vec!["alive".into()],
        control_period_s: Some(0.032),
        termination_terms: vec!["fallen".into()],
    }
}

/// Valid messages to mutate.
const SEEDS: &[&str] = &[
    r#"{"type":"hello","version":2,"robot":"cartpole","observation_space":{"Box":{"low":["-inf","-inf","-inf","-inf"],"high":["inf","inf","inf","inf"]}},"action_space":{"Discrete":{"n":2}},"token":"t"}"#,
    r#"{"type":"start","obs":[0.1,-0.2,0.03,0.0]}"#,
    r#"{"type":"step","obs":[0.1,-0.2,0.03,0.0],"reward":1.0,"terminated":false,"truncated":false}"#,
    r#"{"type":"step","obs":[1,2,3,4],"reward":-1.5,"terminated":true,"truncated":false,"success":true}"#,
    r#"{"type":"step","obs":[1,2,3,4],"reward":-1.5,"terminated":true,"truncated":false,"ended_by":"fallen"}"#,
    r#"{"type":"abort"}"#,
    r#"{"type":"bye"}"#,
];

/// Replacements that break types and numbers.
const TOKENS: &[&str] = &[
    "1e39",
    "-1e39",
    "1e400",
    "NaN",
    "Infinity",
    "-0",
    "null",
    "true",
    "\"inf\"",
    "[]",
    "{}",
    "\"\"",
    "3.4028236e38",
    "18446744073709551616",
    "-1",
    "0.5",
    "[1e39,0,0,0]",
    "[0,0,0]",
    "[0,0,0,0,0]",
    "\"step\"",
    "\"hello\"",
    "\u{0}",
];

struct Fuzzer {
    rng: ChaCha8Rng,
}

impl Fuzzer {
    fn below(&mut self, n: usize) -> usize {
        (self.rng.next_u64() % n as u64) as usize
    }

    fn bytes(&mut self, n: usize) -> Vec<u8> {
        let mut b = vec![0u8; n];
        self.rng.fill_bytes(&mut b);
        b
    }

    fn framed(payload: &[u8]) -> Vec<u8> {
        let mut f = (payload.len() as u32).to_le_bytes().to_vec();
        f.extend_from_slice(payload);
        f
    }

    /// A valid message with a few bytes flipped, inserted, removed, or a value replaced.
    fn mutated(&mut self) -> Vec<u8> {
        let mut p = SEEDS[self.below(SEEDS.len())].as_bytes().to_vec();
        for _ in 0..1 + self.below(4) {
            match self.below(5) {
                0 if !p.is_empty() => {
                    let i = self.below(p.len());
                    p[i] = self.rng.next_u32() as u8;
                }
                1 => {
                    let i = self.below(p.len() + 1);
                    p.insert(i, b"{}[]\",:0123456789e-.nt"[self.below(22)]);
                }
                2 if !p.is_empty() => {
                    let i = self.below(p.len());
                    p.remove(i);
                }
                _ => {
                    // Replace a number, a string or a value after a colon with a hostile token.
                    let text = String::from_utf8_lossy(&p).into_owned();
                    let colons: Vec<usize> = text.match_indices(':').map(|(i, _)| i + 1).collect();
                    if let Some(&at) = colons.get(self.below(colons.len().max(1))) {
                        let end = text[at..].find([',', '}']).map_or(text.len(), |e| at + e);
                        let token = TOKENS[self.below(TOKENS.len())];
                        p = format!("{}{}{}", &text[..at], token, &text[end..]).into_bytes();
                    }
                }
            }
        }
        p
    }

    fn deep(&mut self) -> Vec<u8> {
        let depth = 1 + self.below(5000);
        let (open, close) = if self.below(2) == 0 { ("[", "]") } else { ("{\"a\":", "}") };
        format!(r#"{{"type":"start","obs":{}0{}}}"#, open.repeat(depth), close.repeat(depth)).into_bytes()
    }

    /// One input: the bytes a client sends on a fresh stream.
    fn input(&mut self) -> Vec<u8> {
        match self.below(8) {
            0 => {
                let n = self.below(64);
                self.bytes(n)
            }
            1 => {
                let n = self.below(256);
                Self::framed(&self.bytes(n))
            }
            2 | 3 => Self::framed(&self.mutated()),
            4 => {
                // A huge or lying length prefix over a short body.
                let len = match self.below(3) {
                    0 => u32::MAX,
                    1 => MAX_FRAME as u32 + 1 + self.rng.next_u32() % (4 << 20),
                    _ => self.rng.next_u32(),
                };
                let mut f = len.to_le_bytes().to_vec();
                let n = self.below(32);
                f.extend(self.bytes(n));
                f
            }
            5 => {
                // A valid frame cut short.
                let f = Self::framed(SEEDS[self.below(SEEDS.len())].as_bytes());
                let cut = self.below(f.len());
                f[..cut].to_vec()
            }
            6 => Self::framed(&self.deep()),
            _ => {
                // Two frames back to back, the second mutated.
                let mut f = Self::framed(SEEDS[self.below(SEEDS.len())].as_bytes());
                f.extend(Self::framed(&self.mutated()));
                f
            }
        }
    }
}

/// Reads every frame the input holds, as a connection would, through all the checks.
fn exercise(input: &[u8], task: &TaskInterface) -> (usize, usize) {
    let admission = Admission { task, token: Some("t") };
    let (mut accepted, mut refused) = (0, 0);
    // As a first message…
    match read_frame(&mut Cursor::new(input)) {
        Ok(payload) => match check_hello(&payload, &admission) {
            Ok(RobotMessage::Hello { .. }) => accepted += 1,
            Ok(other) => panic!("check_hello accepted {other:?}"),
            Err(_) => refused += 1,
        },
        Err(_) => refused += 1,
    }
    // …and as requests after the handshake.
    let mut stream = Cursor::new(input);
    for _ in 0..4 {
        match read_message::<RobotMessage>(&mut stream) {
            Ok(message) => match check_request(&message, task) {
                Ok(()) => {
                    accepted += 1;
                    if let RobotMessage::Start { obs } | RobotMessage::Step { obs, .. } = &message {
                        assert!(obs.len() == 4 && obs.iter().all(|v| v.abs() <= 100.0), "accepted {message:?}");
                    }
                    if let RobotMessage::Step { reward, .. } = &message {
                        assert!(reward.is_finite() && (-2.0..=1.0 + 1e-5).contains(reward), "accepted {message:?}");
                    }
                }
                Err(_) => refused += 1,
            },
            Err(FrameError::Io(_)) | Err(FrameError::TimedOut) => break,
            Err(e) if e.fatal() => break,
            Err(_) => refused += 1,
        }
    }
    (accepted, refused)
}

#[test]
fn the_decoder_and_checks_survive_generated_and_mutated_inputs() {
    let cases: usize = std::env::var("TWINBOTS_FUZZ_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(20_000);
    let seed: u64 = std::env::var("TWINBOTS_FUZZ_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(15);
    let task = task();
    let mut fuzzer = Fuzzer { rng: ChaCha8Rng::seed_from_u64(seed) };
    let (mut panics, mut accepted, mut refused) = (0usize, 0usize, 0usize);
    let started = std::time::Instant::now();
    for case in 0..cases {
        let input = fuzzer.input();
        match catch_unwind(AssertUnwindSafe(|| exercise(&input, &task))) {
            Ok((a, r)) => (accepted, refused) = (accepted + a, refused + r),
            Err(_) => {
                panics += 1;
                eprintln!("case {case} panicked on {:?}", String::from_utf8_lossy(&input));
            }
        }
    }
    println!(
        "fuzz: {cases} inputs (seed {seed}) in {:.1} s: {accepted} messages accepted, {refused} refused, {panics} panics",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(panics, 0);
    assert!(accepted > cases / 20, "the mutations keep enough inputs valid to reach the checks");
}
