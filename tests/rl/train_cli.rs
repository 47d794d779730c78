//! `twinbots train` end to end, as a user runs it: a short run leaves a complete run directory;
//! an unknown robot is a clear error listing the known ones.

use std::process::Command;

fn twinbots() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twinbots"))
}

#[test]
fn short_training_run_writes_its_run_directory() {
    let out = std::env::temp_dir().join(format!("twinbots-train-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let status = twinbots()
        .args(["train", "cartpole", "--timesteps", "1024", "--arenas", "2", "--checkpoint-every", "4", "--out"])
        .arg(&out)
        .status()
        .unwrap();
    assert!(status.success());
    let csv = std::fs::read_to_string(out.join("progress.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[0].starts_with("update,timesteps,episodes,mean_reward"));
    // 1024 steps over 2 arenas with 32-step rollouts: 16 updates.
    assert_eq!(rows.len(), 1 + 16, "{csv}");
    assert!(out.join("model/model.safetensors").is_file() && out.join("model/model.json").is_file());
    assert!(out.join("config.toml").is_file() && out.join("summary.json").is_file());
    let checkpoints = std::fs::read_dir(out.join("checkpoints")).unwrap().count();
    assert_eq!(checkpoints, 4, "every 4th of 16 updates");
    let model = twinbots_rl::Ppo::load(out.join("model")).unwrap();
    assert_eq!(model.timesteps, 1024);
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn unknown_robot_lists_the_known_ones() {
    let output = twinbots().args(["train", "nosuchbot"]).output().unwrap();
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("unknown robot 'nosuchbot'") && err.contains("cartpole"), "{err}");
}
