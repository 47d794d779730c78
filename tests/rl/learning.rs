//! The twins still learn (issue 32): a short run of each, as a user runs it, against a threshold
//! set from six seeds (0 here, 1–5 in the sweep of docs/benchmarks.md, "Learning in CI"), with
//! room for seed noise but not for a learner that stopped learning. Seed 0 runs here.

use std::path::Path;
use std::process::Command;

/// `twinbots train <args> --out DIR`: its summary.json and eval.json.
fn trained(name: &str, args: &[&str]) -> (serde_json::Value, serde_json::Value) {
    let out = std::env::temp_dir().join(format!("twinbots-learning-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let output =
        Command::new(env!("CARGO_BIN_EXE_twinbots")).arg("train").args(args).arg("--out").arg(&out).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let read = |file: &str| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(Path::new(&out).join(file)).unwrap()).unwrap()
    };
    let files = (read("summary.json"), read("eval.json"));
    std::fs::remove_dir_all(&out).ok();
    files
}

/// The README's main job: seeds 0–4 solved at 210,688–249,856 steps (seed 0: 249,856; 2026-11-28).
#[test]
fn cartpole_ppo_solves_within_300k_steps() {
    let (summary, _) = trained("cartpole", &["cartpole"]);
    assert_eq!(summary["solved"], true, "{summary}");
    let at = summary["solved_at_timesteps"].as_u64().unwrap();
    assert!(at <= 300_000, "solved only after {at} steps: {summary}");
}

/// 150 k steps of the Pioneer's 291 k to solve: seeds 0–5 reach a mean episode reward of
/// 17.3–204.3 over the last 100 episodes (seed 0: 29.0), and the same run that never learns
/// (`[ppo] learning_rate = 1e-12`, seed 0) 8.96 (2026-12-06, 7199e30). The threshold sits midway
/// between the two: 4 above a learner that stopped, 4 below the worst seed. (At 100 k steps the
/// seeds' worst was 13.8 against 9.0: too thin a margin to mean much.)
#[test]
fn pioneer_ppo_learns_within_150k_steps() {
    let (summary, _) = trained("pioneer", &["pioneer3at", "--timesteps", "150000"]);
    let mean = summary["mean_reward_last_100"].as_f64().unwrap();
    assert!(mean >= PIONEER_THRESHOLD, "mean reward of the last 100 episodes {mean} < {PIONEER_THRESHOLD}: {summary}");
}

const PIONEER_THRESHOLD: f64 = 13.0;

/// 10 k steps of SAC + HER (of the 50–95 k it solves in): seeds 0–5 score −18.2 to −36.5 in the
/// final evaluation (200 reaches; seed 0 −31.0), and −18.3 to −29.3 with candle's graph for
/// the gradients (8d12876; measured 2026-11-28); the same run without a gradient step (1 k
/// steps) −63.2. (Before the stop forfeited the arrival bonus, seeds 1–5 scored −6.5 to −19.6.)
#[test]
fn ur5e_sac_learns_to_reach_within_10k_steps() {
    let (_, evaluation) = trained("ur5e-sac", &["ur5e", "--algo", "sac", "--timesteps", "10000"]);
    let score = evaluation["mean_score"].as_f64().unwrap();
    assert!(score >= UR5E_SAC_THRESHOLD, "final evaluation score {score} < {UR5E_SAC_THRESHOLD}: {evaluation}");
}

const UR5E_SAC_THRESHOLD: f64 = -40.0;
