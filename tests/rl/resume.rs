//! Runs you can trust: a run killed with SIGKILL and resumed ends exactly as an uninterrupted
//! one (optimizer moments, random streams, observation statistics, episode history and the
//! envs' running episodes restored), and a damaged newest checkpoint is reported and passed over.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn twinbots() -> Command {
    Command::new(env!("CARGO_BIN_EXE_twinbots"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn train(args: &[&str], config: &Path, out: &Path) -> Command {
    let mut command = twinbots();
    command.arg("train").args(args).arg("--config").arg(config).arg("--out").arg(out);
    command
}

/// `progress.csv` without its wall-clock column (`steps_per_s`), which no two runs share.
/// Copies the directory `from` to `to`, recursively.
fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let path = entry.unwrap().path();
        let target = to.join(path.file_name().unwrap());
        if path.is_dir() {
            copy_dir(&path, &target);
        } else {
            std::fs::copy(&path, &target).unwrap();
        }
    }
}

fn progress_without_timing(run: &Path) -> String {
    let text = std::fs::read_to_string(run.join("progress.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let timing = header.iter().position(|&c| c == "steps_per_s").unwrap();
    text.lines()
        .map(|l| l.split(',').enumerate().filter(|(i, _)| *i != timing).map(|(_, c)| c).collect::<Vec<_>>().join(","))
        .collect::<Vec<_>>()
        .join("\n")
}

/// Trains `args` with `config` twice: once straight through, once killed (SIGKILL) after its
/// second checkpoint and resumed; the two runs must end byte for byte alike.
fn killed_and_resumed_run_matches_an_uninterrupted_one(name: &str, args: &[&str], config_text: &str) {
    let dir = temp_dir(name);
    let config = dir.join("config.toml");
    std::fs::write(&config, config_text).unwrap();
    let (straight, killed) = (dir.join("straight"), dir.join("killed"));

    let output = train(args, &config, &straight).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));

    // The run as a kill after its second checkpoint leaves it, made from the uninterrupted run's
    // own files (a poll that races the run to kill it depended on the machine's speed; the
    // real SIGKILL is `train_cli`'s test): the later checkpoints and everything written at the
    // end gone, progress.csv and the event file run on past the checkpoint, as a kill leaves them.
    copy_dir(&straight, &killed);
    let mut checkpoints: Vec<PathBuf> =
        std::fs::read_dir(killed.join("checkpoints")).unwrap().map(|e| e.unwrap().path()).collect();
    checkpoints.sort();
    assert!(checkpoints.len() >= 3, "{checkpoints:?}");
    for later in &checkpoints[2..] {
        std::fs::remove_dir_all(later).unwrap();
    }
    std::fs::remove_dir_all(killed.join("model")).unwrap();
    for end in ["eval.json", "summary.json", "learning_curve.png"] {
        let _ = std::fs::remove_file(killed.join(end));
    }
    let output = twinbots().args(["train", "--resume"]).arg(&killed).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stdout).contains("resuming"));

    assert_eq!(progress_without_timing(&killed), progress_without_timing(&straight), "progress.csv differs");
    let mut files = vec!["model/model.safetensors", "model/optimizer.safetensors", "model/model.json", "eval.json"];
    if config_text.contains("eval_every") {
        files.push("evaluations.csv");
    }
    if config_text.contains("algo = \"sac\"") {
        files.push("model/replay_buffer.safetensors");
    }
    for file in files {
        let read =
            |run: &Path| std::fs::read(run.join(file)).unwrap_or_else(|e| panic!("{}: {e}", run.join(file).display()));
        assert!(read(&killed) == read(&straight), "{file} differs between the resumed and the uninterrupted run");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_killed_and_resumed_run_ends_byte_for_byte_as_an_uninterrupted_one() {
    // Domain randomization and sensor noise draw from the arenas' streams every episode and
    // step; periodic evaluations draw their own episodes.
    let config = "timesteps = 4800\narenas = 3\nseed = 11\ncheckpoint_every = 3\neval_every = 10\neval_episodes = 2\n\
                  [randomization]\nmass_scale = [0.8, 1.2]\nsensor_noise = 0.01\naction_latency = 1\n";
    killed_and_resumed_run_matches_an_uninterrupted_one("resume-exact", &["cartpole"], config);
}

#[test]
fn a_killed_and_resumed_pattern_2_run_ends_byte_for_byte_as_an_uninterrupted_one() {
    // The SupervisorRobot and the SlaveRobot talk over radio with a step of latency each way.
    let config = "timesteps = 3200\narenas = 2\nseed = 5\ncheckpoint_every = 3\neval_episodes = 1\n";
    killed_and_resumed_run_matches_an_uninterrupted_one("resume-exact-p2", &["cartpole", "--pattern", "2"], config);
}

#[test]
fn a_killed_and_resumed_sac_run_ends_byte_for_byte_as_an_uninterrupted_one() {
    // SAC: the replay buffer, the three optimisers, the sampling stream and the envs' episodes
    // come back; small networks keep it quick.
    let config = "algo = \"sac\"\ntimesteps = 3200\narenas = 2\nseed = 3\ncheckpoint_every = 2\neval_every = 3\neval_episodes = 2\n\
                  [sac]\nhidden = [32, 32]\nlearning_starts = 200\nlog_interval = 200\nbatch_size = 64\nbuffer_size = 10000\n";
    killed_and_resumed_run_matches_an_uninterrupted_one("resume-exact-sac", &["pioneer3at"], config);
}

/// A 1,280-step cart-pole run in `dir/run`, checkpointed every 4th of its 20 updates: the run
/// and its five checkpoints, oldest first.
fn five_checkpoints(dir: &Path) -> (PathBuf, Vec<PathBuf>) {
    let run = dir.join("run");
    let output = twinbots()
        .args(["train", "cartpole", "--timesteps", "1280", "--arenas", "2", "--checkpoint-every", "4", "--out"])
        .arg(&run)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let mut checkpoints: Vec<PathBuf> =
        std::fs::read_dir(run.join("checkpoints")).unwrap().map(|e| e.unwrap().path()).collect();
    checkpoints.sort();
    (run, checkpoints)
}

#[test]
fn a_damaged_or_non_finite_newest_checkpoint_is_reported_and_the_one_before_it_used() {
    let dir = temp_dir("resume-damaged");
    let (run, checkpoints) = five_checkpoints(&dir);
    assert_eq!(checkpoints.len(), 5, "every 4th of 20 updates");
    // The newest: its metadata cut short. The one before: a weight turned NaN (0xffffffff).
    let newest = &checkpoints[4];
    let meta = std::fs::read(newest.join("model.json")).unwrap();
    std::fs::write(newest.join("model.json"), &meta[..meta.len() / 2]).unwrap();
    let poisoned = &checkpoints[3];
    let mut weights = std::fs::read(poisoned.join("model.safetensors")).unwrap();
    let n = weights.len();
    weights[n - 4..].copy_from_slice(&[0xff; 4]);
    std::fs::write(poisoned.join("model.safetensors"), weights).unwrap();
    // Before it: a weight of 3.4e38 (finite, but every update from it would be skipped), and
    // before that a checkpoint without its envs' episodes.
    let huge = &checkpoints[2];
    let mut weights = std::fs::read(huge.join("model.safetensors")).unwrap();
    let n = weights.len();
    weights[n - 4..].copy_from_slice(&f32::MAX.to_le_bytes());
    std::fs::write(huge.join("model.safetensors"), weights).unwrap();
    let incomplete = &checkpoints[1];
    std::fs::remove_file(incomplete.join("env_state.json")).unwrap();
    std::fs::remove_dir_all(run.join("model")).unwrap();
    // Without their checksums (as checkpoints saved before they were kept): what the loader's
    // own checks find (the checksums' test is below).
    for checkpoint in &checkpoints[1..] {
        std::fs::remove_file(checkpoint.join("checksums.json")).unwrap();
    }

    // `eval` of a run without a final model takes its newest checkpoint that loads.
    let output = twinbots().args(["eval"]).arg(&run).args(["--episodes", "1"]).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{err}");
    assert!(err.contains(&format!("checkpoint {} is unusable", newest.display())), "{err}");
    assert!(err.contains("non-finite values"), "{err}");

    // `--resume` likewise, and goes on from the oldest (256 steps) to the end.
    let output = twinbots().args(["train", "--resume"]).arg(&run).output().unwrap();
    let (out, err) = (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{err}");
    for (checkpoint, why) in [
        (poisoned, "non-finite values"),
        (huge, "holds 3.4028235e38, beyond ±1e4"),
        (incomplete, "env_state.json: missing"),
    ] {
        assert!(err.contains(&format!("checkpoint {} is unusable", checkpoint.display())), "{err}");
        assert!(err.contains(why), "{why:?} not in {err}");
    }
    assert!(out.contains("(256 steps"), "{out}");
    let model = twinbots_learn::Ppo::load(run.join("model")).unwrap();
    assert_eq!(model.state.timesteps, 1280);
    std::fs::remove_dir_all(&dir).ok();
}

/// A checkpoint's checksums catch what its values cannot: a flipped bit that leaves a weight
/// finite and small, and a missing optimizer file (which resumed with a fresh optimizer).
#[test]
fn a_checkpoint_not_as_saved_is_passed_over() {
    let dir = temp_dir("resume-checksums");
    let (run, checkpoints) = five_checkpoints(&dir);
    let flipped = &checkpoints[4];
    let mut weights = std::fs::read(flipped.join("model.safetensors")).unwrap();
    let n = weights.len();
    weights[n - 4] ^= 1; // the lowest mantissa bit of the last weight
    std::fs::write(flipped.join("model.safetensors"), weights).unwrap();
    let no_optimizer = &checkpoints[3];
    std::fs::remove_file(no_optimizer.join("optimizer.safetensors")).unwrap();
    let output = twinbots().args(["train", "--resume"]).arg(&run).output().unwrap();
    let (out, err) = (String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    assert!(output.status.success(), "{err}");
    assert!(err.contains(&format!("checkpoint {} is unusable", flipped.display())), "{err}");
    assert!(err.contains("its model.safetensors is not as saved"), "{err}");
    assert!(err.contains(&format!("checkpoint {} is unusable", no_optimizer.display())), "{err}");
    assert!(err.contains("its optimizer.safetensors is missing"), "{err}");
    assert!(out.contains("(768 steps"), "{out}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_killed_pattern_3_run_resumes_through_its_server_and_its_server_does_not_outlive_it() {
    let dir = temp_dir("resume-p3");
    let run = dir.join("run");
    let mut child = twinbots()
        .args([
            "train",
            "cartpole",
            "--pattern",
            "3",
            "--timesteps",
            "4096",
            "--arenas",
            "2",
            "--checkpoint-every",
            "2",
            "--out",
        ])
        .arg(&run)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(120);
    let checkpoints = || std::fs::read_dir(run.join("checkpoints")).map_or(0, |d| d.count());
    while checkpoints() < 3 && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    // The server (the learner, another process) notices and ends: the logs stop growing.
    let size = || std::fs::metadata(run.join("progress.csv")).map_or(0, |m| m.len());
    let mut last = size();
    loop {
        std::thread::sleep(Duration::from_millis(1500));
        let now = size();
        if now == last {
            break;
        }
        assert!(Instant::now() < deadline, "the server of a killed run goes on training");
        last = now;
    }
    assert!(!run.join("model").exists(), "killed before it finished");

    let output = twinbots().args(["train", "--resume"]).arg(&run).output().unwrap();
    assert!(
        output.status.success(),
        "{}\n{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    let progress = twinbots_learn::RunDir::new(&run).read_progress().unwrap();
    let updates: Vec<usize> = progress.iter().map(|row| row.update).collect();
    assert!(updates.iter().enumerate().all(|(i, &u)| u == i + 1), "{updates:?}");
    assert!(progress.windows(2).all(|w| w[1].timesteps > w[0].timesteps));
    let model = twinbots_learn::Ppo::load(run.join("model")).unwrap();
    assert!(
        model.state.timesteps >= 4096 && model.state.updates as usize == updates.len(),
        "{} steps, {} updates",
        model.state.timesteps,
        model.state.updates
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_finished_run_trains_more_with_resume_and_timesteps() {
    let dir = temp_dir("extend");
    let config = dir.join("config.toml");
    std::fs::write(&config, "timesteps = 512\n").unwrap();
    let run = dir.join("run");
    let output = train(&["cartpole"], &config, &run).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let updates = |run: &Path| std::fs::read_to_string(run.join("progress.csv")).unwrap().lines().count() - 1;
    let timesteps = |run: &Path| -> u64 {
        let summary: serde_json::Value =
            serde_json::from_slice(&std::fs::read(run.join("summary.json")).unwrap()).unwrap();
        summary["timesteps"].as_u64().unwrap_or_else(|| panic!("{summary}"))
    };
    let (before, steps) = (updates(&run), timesteps(&run));
    assert_eq!(steps, 512);
    // SB3's learn(256, reset_num_timesteps=False): 256 steps more, from the final model.
    let output = twinbots().args(["train", "--resume"]).arg(&run).args(["--timesteps", "256"]).output().unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(stdout.contains("for 256 more steps") && stdout.contains("(512 steps"), "{stdout}");
    assert_eq!(timesteps(&run), 768, "{stdout}");
    assert_eq!(updates(&run), before + 1, "one more update of 256 steps, the rows before it kept");
    let settings: toml::Table = toml::from_str(&std::fs::read_to_string(run.join("config.toml")).unwrap()).unwrap();
    assert_eq!(settings["timesteps"].as_integer(), Some(768), "config.toml records the new budget");
    // Other flags still do not go with --resume.
    let output =
        twinbots().args(["train", "--resume"]).arg(&run).args(["--timesteps", "256", "--seed", "3"]).output().unwrap();
    assert!(!output.status.success() && String::from_utf8_lossy(&output.stderr).contains("--seed"));
    std::fs::remove_dir_all(&dir).ok();
}
