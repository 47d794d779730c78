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
    let output = twinbots()
        .args(["train", "cartpole", "--timesteps", "1024", "--arenas", "2", "--checkpoint-every", "4", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(output.status.success());
    // stderr is a pipe, not a terminal: progress comes as lines, the last one at the end.
    let log = String::from_utf8_lossy(&output.stderr);
    let last = log.lines().last().unwrap_or_default();
    assert!(last.contains("steps 1024/1024: ") && last.contains("steps/s, mean reward"), "{log}");
    let csv = std::fs::read_to_string(out.join("progress.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[0].starts_with("update,timesteps,episodes,mean_reward"));
    // 1024 steps over 2 arenas with 32-step rollouts: 16 updates.
    assert_eq!(rows.len(), 1 + 16, "{csv}");
    assert!(out.join("model/model.safetensors").is_file() && out.join("model/model.json").is_file());
    assert!(out.join("config.toml").is_file() && out.join("summary.json").is_file());
    let checkpoints = std::fs::read_dir(out.join("checkpoints")).unwrap().count();
    assert_eq!(checkpoints, 4, "every 4th of 16 updates");
    // Where the time went: every part measured, together no more than the wall clock.
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let time = &summary["time_breakdown"];
    let part = |name: &str| time[name].as_f64().unwrap_or_else(|| panic!("no {name} in {summary}"));
    let parts = ["simulation_s", "inference_s", "update_s", "bridge_s", "logging_s", "other_s"].map(part);
    assert!(parts[..4].iter().all(|&s| s > 0.0), "{time}");
    let wall = summary["wall_clock_s_this_session"].as_f64().unwrap();
    assert!((parts.iter().sum::<f64>() - wall).abs() < 0.01 * wall + 1e-3, "{time} vs wall {wall}");
    let model = twinbots_learn::Ppo::load(out.join("model")).unwrap();
    assert_eq!(model.state.timesteps, 1024);
    // TensorBoard: a point of every training scalar per update, at the update's timesteps.
    let scalars = event_scalars(&out);
    let steps = |tag: &str| -> Vec<u64> { scalars.iter().filter(|(_, t, _)| t == tag).map(|(s, _, _)| *s).collect() };
    let every_update: Vec<u64> = (1..=16).map(|u| u * 64).collect();
    for tag in ["train/loss", "train/approx_kl", "train/clip_fraction", "train/value_loss", "time/fps"] {
        assert_eq!(steps(tag), every_update, "{tag}");
    }
    // Episode means from the first update that saw an episode end.
    assert!(!steps("rollout/ep_len_mean").is_empty() && steps("rollout/ep_len_mean").ends_with(&[1024]));
    assert!(steps("train/std").is_empty(), "σ is a Gaussian policy's");
    std::fs::remove_dir_all(&out).ok();
}

/// Every scalar in the TensorBoard event files of `dir`, as `(step, tag, value)`.
pub fn event_scalars(dir: &std::path::Path) -> Vec<(u64, String, f32)> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().contains("tfevents"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no event file in {}", dir.display());
    files.iter().flat_map(|f| twinbots_learn::tensorboard::read_scalars(&std::fs::read(f).unwrap()).unwrap()).collect()
}

#[test]
fn unknown_robot_lists_the_known_ones() {
    let output = twinbots().args(["train", "nosuchbot"]).output().unwrap();
    assert!(!output.status.success());
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(err.contains("unknown robot 'nosuchbot'") && err.contains("cartpole, pioneer3at"), "{err}");
}

#[test]
fn a_run_killed_with_sigkill_resumes_from_its_last_checkpoint() {
    let out = std::env::temp_dir().join(format!("twinbots-resume-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    // 2 arenas × 32-step rollouts = 64 steps per update; a checkpoint every 2 updates.
    let mut child = twinbots()
        .args(["train", "cartpole", "--timesteps", "6400", "--arenas", "2", "--checkpoint-every", "2", "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(60);
    let checkpoints = || std::fs::read_dir(out.join("checkpoints")).map_or(0, |d| d.count());
    while checkpoints() < 3 && std::time::Instant::now() < deadline {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(!out.join("model").exists(), "killed before it finished");
    let killed_rows = std::fs::read_to_string(out.join("progress.csv")).unwrap().lines().count();

    let output = twinbots().args(["train", "--resume"]).arg(&out).output().unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stdout).contains("resuming"));
    let progress = twinbots_learn::RunDir::new(&out).read_progress().unwrap();
    let steps: Vec<u64> = progress.iter().map(|row| row.timesteps).collect();
    let updates: Vec<u64> = progress.iter().map(|row| row.update as u64).collect();
    // Counters continue: one row per update, 64 steps apart, numbered 1, 2, 3, ... to the end.
    assert_eq!(steps.len(), 100, "6400 steps / 64 per update; {killed_rows} rows before the kill");
    assert!(steps.windows(2).all(|w| w[1] == w[0] + 64), "{steps:?}");
    assert!(updates.iter().enumerate().all(|(i, &u)| u == i as u64 + 1), "{updates:?}");
    let model = twinbots_learn::Ppo::load(out.join("model")).unwrap();
    assert_eq!((model.state.timesteps, model.state.updates), (6400, 100));
    assert!(model.state.episodes > 0);
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn a_ppo_table_changes_only_its_keys_and_nonsense_is_refused_before_anything_runs() {
    let dir = std::env::temp_dir().join(format!("twinbots-config-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = dir.join("config.toml");

    // One key of [ppo] replaces that key only: the cart-pole keeps its tuned n_steps and rate.
    std::fs::write(&config, "[ppo]\nn_epochs = 5\n").unwrap();
    let run = dir.join("run");
    let output = twinbots()
        .args(["train", "cartpole", "--timesteps", "64", "--arenas", "2", "--config"])
        .arg(&config)
        .arg("--out")
        .arg(&run)
        .output()
        .unwrap();
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let written = std::fs::read_to_string(run.join("config.toml")).unwrap();
    for line in ["n_epochs = 5", "n_steps = 32", "learning_rate = 0.001", "batch_size = 256"] {
        assert!(written.lines().any(|l| l == line), "{line:?} missing from {written}");
    }

    let refused = [
        ("[ppo]\nlearning_rate = nan\n", "ppo.learning_rate = NaN: must be a finite number > 0"),
        ("[ppo]\nlearning_rate = -1.0\n", "ppo.learning_rate = -1"),
        ("[ppo]\ngamma = 2.0\n", "ppo.gamma = 2: must be in (0, 1]"),
        ("[ppo]\nbatch_size = 0\n", "ppo.batch_size = 0"),
        ("[ppo]\nn_steps = 0\n", "ppo.n_steps = 0"),
        ("[ppo]\nhidden = []\n", "ppo.hidden = []"),
        ("[ppo]\nn_epoch = 3\n", "unknown field `n_epoch`"),
        ("[randomization]\nmass_scale = [1.0, inf]\n", "randomization.mass_scale = [1, inf]: must be finite"),
        ("[randomization]\nfriction = [0.0, inf]\n", "randomization.friction"),
        ("[randomization]\nsensor_noise = inf\n", "randomization.sensor_noise = inf"),
        ("timesteps = 0\n", "timesteps = 0: must be a whole number ≥ 1"),
    ];
    for (i, (text, expected)) in refused.iter().enumerate() {
        std::fs::write(&config, text).unwrap();
        let run = dir.join(format!("refused-{i}"));
        let output =
            twinbots().args(["train", "cartpole", "--config"]).arg(&config).arg("--out").arg(&run).output().unwrap();
        let err = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success() && err.contains(expected), "{text:?}: expected {expected:?} in {err}");
        assert!(!err.contains("panicked"), "{text:?}: {err}");
        assert!(!run.exists(), "{text:?}: a run directory was made");
    }
    // --print-config shows the merge, key by key: defaults ← file ← flags.
    std::fs::write(&config, "seed = 9\narenas = 4\n[ppo]\nn_epochs = 5\n").unwrap();
    let output = twinbots()
        .args(["train", "cartpole", "--arenas", "3", "--print-config", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    for line in ["seed = 9", "arenas = 3", "n_epochs = 5", "n_steps = 32", "learning_rate = 0.001"] {
        assert!(printed.lines().any(|l| l == line), "{line:?} missing from {printed}");
    }
    let output =
        twinbots().args(["train", "cartpole", "--arenas", "0", "--out"]).arg(dir.join("zero")).output().unwrap();
    assert!(String::from_utf8_lossy(&output.stderr).contains("arenas = 0: must be a whole number ≥ 1"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn an_error_found_before_training_leaves_no_run_directory() {
    let dir = std::env::temp_dir().join(format!("twinbots-late-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let her = dir.join("her.toml");
    std::fs::write(&her, "[sac]\nher_goals = 4\n").unwrap();
    let cases: [(&[&str], &str); 4] = [
        (&["ur5e", "--pattern", "2"], "ur5e (reach) does not support design pattern 2 (supported: 1, 3)"),
        (&["pioneer3at", "--pattern", "2"], "does not support design pattern 2"),
        (&["pioneer3at", "--pattern", "3"], "does not support design pattern 3"),
        (&["pioneer3at", "--algo", "sac", "--config", her.to_str().unwrap()], "this task is not goal-conditioned"),
    ];
    for (i, (args, why)) in cases.into_iter().enumerate() {
        let out = dir.join(format!("run{i}"));
        let output = twinbots().arg("train").args(args).arg("--out").arg(&out).output().unwrap();
        let err = String::from_utf8_lossy(&output.stderr);
        assert!(!output.status.success() && err.contains(why), "{args:?}: {err}");
        assert!(!out.exists(), "{args:?} left {} behind", out.display());
    }
    let left: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left, vec![std::ffi::OsString::from("her.toml")], "nothing else in {}", dir.display());
    std::fs::remove_dir_all(&dir).ok();
}

/// `twinbots compare`: three seeds' runs as median and quartiles, the learning curves as a
/// band (PNG); a folder that is no finished run is an error naming it.
#[test]
fn compare_gives_the_median_and_quartiles_over_seeds() {
    let out = std::env::temp_dir().join(format!("twinbots-compare-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let runs: Vec<_> = (0..3).map(|seed| out.join(format!("seed-{seed}"))).collect();
    for (seed, run) in runs.iter().enumerate() {
        let status = twinbots()
            .args(["train", "cartpole", "--timesteps", "1024", "--arenas", "2", "--seed", &seed.to_string(), "--out"])
            .arg(run)
            .output()
            .unwrap()
            .status;
        assert!(status.success());
    }
    let (json, png) = (out.join("compare.json"), out.join("curves.png"));
    let output =
        twinbots().arg("compare").args(&runs).arg("--json").arg(&json).arg("--png").arg(&png).output().unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(text.contains("cartpole: 3 runs, 0 solved") && text.contains("steps to solve: median never"), "{text}");
    let c: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let seeds: Vec<u64> = c["runs"].as_array().unwrap().iter().map(|r| r["seed"].as_u64().unwrap()).collect();
    assert_eq!(seeds, [0, 1, 2]);
    // The median wall clock is the middle one of the three runs' own.
    let mut walls: Vec<f64> = runs
        .iter()
        .map(|r| {
            let s: serde_json::Value =
                serde_json::from_str(&std::fs::read_to_string(r.join("summary.json")).unwrap()).unwrap();
            s["wall_clock_s_this_session"].as_f64().unwrap()
        })
        .collect();
    walls.sort_by(f64::total_cmp);
    assert_eq!(c["wall_clock_s"]["median"].as_f64(), Some(walls[1]), "{c}");
    assert!(c["steps_to_solve"]["median"].is_null(), "unsolved runs take ∞ steps (null): {c}");
    assert_eq!(&std::fs::read(&png).unwrap()[..8], b"\x89PNG\r\n\x1a\n");
    // Not a run: an error naming the folder.
    let output = twinbots().arg("compare").arg(&runs[0]).arg(&out).output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && err.contains(&out.display().to_string()), "{err}");
    std::fs::remove_dir_all(&out).ok();
}

/// Behaviour cloning from the command line: `demos` writes the cart-pole's classical episodes,
/// `train --demos` clones them, and a run extended with `--resume … --timesteps` ends with the
/// model and evaluation of one run of the whole budget, bit for bit (the minibatch stream and
/// Adam's moments go with the model; the dataset is read again from its path).
#[test]
fn a_cloned_run_extended_later_is_the_run_made_at_once() {
    let root = std::env::temp_dir().join(format!("twinbots-bc-cli-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(&root).unwrap();
    let demos = root.join("demos");
    let run = |args: &[&str]| {
        let output = twinbots().args(args).output().unwrap();
        assert!(output.status.success(), "{args:?}: {}", String::from_utf8_lossy(&output.stderr));
        String::from_utf8_lossy(&output.stdout).to_string()
    };
    run(&["demos", "cartpole", "--episodes", "3", "--out", demos.to_str().unwrap()]);
    let train = |out: &str, steps: &str| {
        let out = root.join(out);
        let config = root.join("eval.toml");
        std::fs::write(&config, "eval_episodes = 2\n").unwrap();
        let (demos, config) = (demos.to_str().unwrap(), config.to_str().unwrap());
        let args = ["train", "cartpole", "--demos", demos, "--timesteps", steps, "--config", config, "--out"];
        run(&[&args[..], &[out.to_str().unwrap()]].concat());
        out
    };
    let whole = train("whole", "51200");
    let half = train("half", "25600");
    let stdout = run(&["train", "--resume", half.to_str().unwrap(), "--timesteps", "25600"]);
    assert!(stdout.contains("trained: 51200 steps"), "{stdout}");
    let bytes = |dir: &std::path::Path, file: &str| std::fs::read(dir.join(file)).unwrap();
    assert_eq!(bytes(&whole, "model/model.safetensors"), bytes(&half, "model/model.safetensors"));
    assert_eq!(bytes(&whole, "eval.json"), bytes(&half, "eval.json"));
    // Its loss is its learning curve: a row every 100 gradient steps of 256 frames.
    let progress = std::fs::read_to_string(half.join("progress.csv")).unwrap();
    assert!(progress.lines().next().unwrap().contains(",loss,"), "{progress}");
    assert_eq!(progress.lines().count(), 1 + 2, "{progress}");
    std::fs::remove_dir_all(&root).unwrap();
}

/// The benchmarks that need neither a GPU nor a robot bundle run and print their tables.
#[test]
fn the_benchmarks_run() {
    for (args, said) in [
        (&["bench", "physics", "--arenas", "1,2", "--steps", "20"][..], "arena steps/s"),
        (&["bench", "rl", "--arenas", "2", "--steps", "20"][..], "PPO update of 2048 samples"),
        (&["bench", "server", "--arenas", "1", "--steps", "20"][..], "round trip"),
        (&["bench", "live", "--rounds", "1", "--steps", "30000", "--every-step"][..], "with a viewer"),
    ] {
        let output = twinbots().args(args).output().unwrap();
        let stdout = String::from_utf8_lossy(&output.stdout);
        assert!(
            output.status.success() && stdout.contains(said),
            "{args:?}: {stdout}{}",
            String::from_utf8_lossy(&output.stderr)
        );
        if args[1] == "live" {
            // The viewer did watch: some of the run's messages reached it.
            let received =
                stdout.split("s, ").nth(1).and_then(|r| r.split(' ').next()).and_then(|n| n.parse::<u64>().ok());
            assert!(received.is_some_and(|n| n > 100), "{stdout}");
        }
    }
}

#[test]
fn a_report_piped_into_a_reader_that_leaves_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    // The reader closes its end at once (as `head` does once it has its lines): the report's
    // next write finds the pipe closed.
    for args in [&["robots"][..], &["algos"][..]] {
        let mut child = twinbots()
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        drop(child.stdout.take());
        let out = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!stderr.contains("panicked") && !stderr.contains("Broken pipe"), "{args:?}: {stderr}");
        assert!(out.status.success() || out.status.signal() == Some(libc::SIGPIPE), "{args:?}: {:?}", out.status);
    }
}
