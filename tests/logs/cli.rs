//! The CLI's log commands as a user meets them: their files, and a clear error naming the file
//! and the problem for every kind of bad input, with nothing written.

use std::path::{Path, PathBuf};
use std::process::Command;

use twinbots_log::{RobotLog, csv_file, mcap_file};
use twinbots_sysid::excitation::Excitation;
use twinbots_sysid::{Recording, Rig, SensorNoise, record};

pub(crate) fn twinbots(args: &[&str]) -> (bool, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_twinbots")).args(args).output().unwrap();
    (out.status.success(), String::from_utf8_lossy(&out.stdout).into(), String::from_utf8_lossy(&out.stderr).into())
}

pub(crate) fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-logs-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn ur5e_log(seconds: f64) -> RobotLog {
    let rig = Rig::of(&ur5e::robot()).unwrap();
    record(
        &rig,
        &Default::default(),
        &Recording { excitation: Excitation::Multisine, seconds, seed: 7, noise: SensorNoise::default() },
    )
    .unwrap()
}

/// Writes a log as it is, unchecked (so a test can write what the writer would refuse).
fn write_raw(log: &RobotLog, path: &Path) {
    if path.extension().unwrap() == "csv" {
        std::fs::write(path, csv_file::to_string(log)).unwrap();
    } else {
        std::fs::write(path, mcap_file::to_bytes(log).unwrap()).unwrap();
    }
}

#[test]
fn list_params_prints_name_default_unit() {
    let (ok, out, err) = twinbots(&["identify", "ur5e", "--list-params"]);
    assert!(ok, "{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert!(lines.len() >= 19, "{out}");
    for line in &lines {
        let fields: Vec<&str> = line.split(' ').collect();
        assert_eq!(fields.len(), 3, "'{line}' is not 'name default unit'");
        fields[1].parse::<f64>().unwrap_or_else(|_| panic!("'{}' of '{line}' is not a number", fields[1]));
    }
    for name in ["elbow_joint.damping 0 N*m*s/rad", "wrist_3_joint.armature 0 kg*m^2", "command_delay 0 s"] {
        assert!(lines.contains(&name), "no '{name}' in\n{out}");
    }
    let (ok, _, err) = twinbots(&["identify", "r2d2", "--list-params"]);
    assert!(!ok && err.contains("r2d2") && err.contains("ur5e"), "{err}");
}

#[test]
fn record_replay_identify_write_their_files() {
    let dir = scratch("files");
    let truth = dir.join("truth.toml");
    std::fs::write(&truth, "[parameters]\ncommand_delay = 0.012\nelbow_joint.damping = 1.8\n[note]\nwhy = 'a test'\n")
        .unwrap();
    let log = dir.join("fit.mcap");
    let (ok, _, err) = twinbots(&[
        "record",
        "ur5e",
        "--truth",
        truth.to_str().unwrap(),
        "--seconds",
        "2",
        "--out",
        log.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let replay = dir.join("replay");
    let (ok, nominal, err) = twinbots(&["replay", "ur5e", log.to_str().unwrap(), "--out", replay.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(nominal.contains("elbow_joint") && nominal.contains("pos RMSE"), "{nominal}");
    for file in ["replay.png", "twin.mcap", "replay.json"] {
        assert!(replay.join(file).is_file(), "no {file}");
    }
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(replay.join("replay.json")).unwrap()).unwrap();
    assert_eq!(report["joints"].as_array().unwrap().len(), 6);
    // The twin's own log reads back as a log of the robot.
    let twin = twinbots_log::read(&replay.join("twin.mcap")).unwrap();
    assert_eq!(twin.meta.robot, "ur5e");
    // Its report piped into a reader that has left: the files stand, whole, and the
    // command ends as Unix tools do, without a panic.
    let piped = dir.join("piped");
    let command = format!(
        "'{}' replay ur5e '{}' --out '{}' 2>'{}' | true",
        env!("CARGO_BIN_EXE_twinbots"),
        log.display(),
        piped.display(),
        dir.join("piped.err").display()
    );
    let status = Command::new("sh").args(["-c", &command]).stdout(std::process::Stdio::null()).status().unwrap();
    let err = std::fs::read_to_string(dir.join("piped.err")).unwrap();
    assert!(status.success() && !err.contains("panicked"), "{err}");
    assert_eq!(twinbots_log::read(&piped.join("twin.mcap")).unwrap().states.len(), twin.states.len());
    assert!(piped.join("replay.json").is_file() && piped.join("replay.png").is_file());
    let cal = dir.join("cal");
    let (ok, out, err) = twinbots(&[
        "identify",
        "ur5e",
        log.to_str().unwrap(),
        "--params",
        "command_delay",
        "--generations",
        "4",
        "--out",
        cal.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("command_delay"), "{out}");
    let text = std::fs::read_to_string(cal.join("calibration.toml")).unwrap();
    let params = twinbots_task::calibration::Calibration::parse(&text).unwrap().parameters;
    let delay = params.get("command_delay").unwrap();
    assert!((delay - 0.012).abs() < 0.004, "fitted delay {delay}\n{text}");
    assert!(cal.join("convergence.png").is_file());
    // The calibrated replay tracks better than the nominal one.
    let (ok, out_cal, err) = twinbots(&[
        "replay",
        "ur5e",
        log.to_str().unwrap(),
        "--calibration",
        cal.join("calibration.toml").to_str().unwrap(),
        "--out",
        replay.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let rmse = |s: &str| -> f64 { s.lines().next().unwrap().rsplit(' ').next().unwrap().parse().unwrap() };
    assert!(rmse(&out_cal) < rmse(&nominal), "calibrated {out_cal}\nnominal {nominal}");
}

#[test]
fn bad_logs_and_parameters_are_clear_errors_and_write_nothing() {
    let dir = scratch("bad");
    let good = ur5e_log(0.5);
    let mut cases: Vec<(&str, PathBuf, &str)> = Vec::new();

    let cartpole = dir.join("cartpole.mcap");
    let rig = Rig::of(&cartpole::robot()).unwrap();
    let log = record(
        &rig,
        &Default::default(),
        &Recording { excitation: Excitation::Chirp, seconds: 0.5, seed: 1, noise: SensorNoise::default() },
    )
    .unwrap();
    write_raw(&log, &cartpole);
    cases.push(("another robot's log", cartpole, "robot 'cartpole', not 'ur5e'"));

    let missing = dir.join("missing.csv");
    let mut log = good.clone();
    let elbow = log.joint_index("elbow_joint").unwrap();
    log.joints.remove(elbow);
    for s in &mut log.states {
        s.position.remove(elbow);
        s.velocity.remove(elbow);
        s.effort.remove(elbow);
    }
    log.commands.clear();
    write_raw(&log, &missing);
    cases.push(("a missing joint", missing, "lacks joint(s) elbow_joint"));

    let misnamed = dir.join("misnamed.mcap");
    let mut log = good.clone();
    log.joints[elbow] = "elbow".into();
    log.commands.clear();
    write_raw(&log, &misnamed);
    cases.push(("a misnamed joint", misnamed, "lacks joint(s) elbow_joint"));

    // A controller's export with two rows out of order (the CSV writer sorts, so by hand).
    let backwards = dir.join("backwards.csv");
    let text = csv_file::to_string(&good);
    let mut lines: Vec<&str> = text.lines().collect();
    let first_row = lines.iter().position(|l| l.starts_with("time,")).unwrap() + 1;
    lines.swap(first_row + 5, first_row + 10);
    std::fs::write(&backwards, lines.join("\n")).unwrap();
    cases.push(("times going backwards", backwards, "not increasing"));

    let nan = dir.join("nan.mcap");
    let mut log = good.clone();
    log.states[20].velocity[2] = f64::NAN;
    write_raw(&log, &nan);
    cases.push(("a NaN sample", nan, "velocity of 'elbow_joint' is NaN"));

    let truncated = dir.join("truncated.mcap");
    let bytes = mcap_file::to_bytes(&good).unwrap();
    std::fs::write(&truncated, &bytes[..bytes.len() * 2 / 3]).unwrap();
    cases.push(("a truncated MCAP", truncated, "truncated"));

    for (what, path, expected) in &cases {
        let out = dir.join("out");
        for command in ["identify", "replay"] {
            let (ok, _, err) = twinbots(&[command, "ur5e", path.to_str().unwrap(), "--out", out.to_str().unwrap()]);
            assert!(!ok, "{command} accepted {what}");
            let file = path.file_name().unwrap().to_str().unwrap();
            assert!(
                err.contains(file) && err.contains(expected),
                "{command}, {what}: '{err}' should name {file} and say '{expected}'"
            );
            assert!(!err.contains("panicked"), "{err}");
            assert!(!out.exists(), "{command} wrote {} for {what}", out.display());
        }
    }

    let log = dir.join("good.mcap");
    twinbots_log::write(&good, &log).unwrap();
    let out = dir.join("out");
    let (ok, _, err) = twinbots(&[
        "identify",
        "ur5e",
        log.to_str().unwrap(),
        "--params",
        "elbow_joint.stiffness",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(
        !ok && err.contains("unknown parameter 'elbow_joint.stiffness'") && err.contains("elbow_joint.damping"),
        "{err}"
    );
    assert!(!out.exists());
    let truth = dir.join("truth.toml");
    std::fs::write(&truth, "[parameters]\nelbow_joint.stiffnes = 3.0\n").unwrap();
    let (ok, _, err) = twinbots(&[
        "record",
        "ur5e",
        "--truth",
        truth.to_str().unwrap(),
        "--out",
        dir.join("never.mcap").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("truth.toml") && err.contains("unknown parameter 'elbow_joint.stiffnes'"), "{err}");
    assert!(!dir.join("never.mcap").exists());

    // Sizes a user can type are bounded, and values are checked against their kind's range.
    let never = dir.join("never.mcap");
    let (ok, _, err) = twinbots(&["record", "ur5e", "--seconds", "1e7", "--out", never.to_str().unwrap()]);
    assert!(!ok && err.contains("--seconds must be positive and at most 3600"), "{err}");
    let (ok, _, err) = twinbots(&[
        "identify",
        "ur5e",
        log.to_str().unwrap(),
        "--popsize",
        "100000000",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("--popsize must be at most 1000"), "{err}");
    for (value, expected) in [("1e300", "= 1e300 N*m*s/rad: outside [0, 10000]"), ("-2.0", "= -2 N*m*s/rad: outside")] {
        std::fs::write(&truth, format!("[parameters]\nelbow_joint.damping = {value}\n")).unwrap();
        let (ok, _, err) = twinbots(&[
            "replay",
            "ur5e",
            log.to_str().unwrap(),
            "--calibration",
            truth.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(!ok && err.contains("truth.toml") && err.contains(expected), "{err}");
        assert!(!err.contains("panicked"), "{err}");
    }
    assert!(!never.exists() && !out.exists());
}

#[test]
fn a_calibration_reaches_the_run_settings() {
    let dir = scratch("train");
    let cal = dir.join("calibration.toml");
    std::fs::write(&cal, "[parameters]\npole_joint.damping = 0.004\ncommand_delay = 0.01\n").unwrap();
    let (ok, out, err) = twinbots(&["train", "cartpole", "--calibration", cal.to_str().unwrap(), "--print-config"]);
    assert!(ok, "{err}");
    let settings: toml::Table = toml::from_str(&out).unwrap();
    let parameters = &settings["calibration"]["parameters"];
    assert_eq!(parameters["pole_joint.damping"].as_float(), Some(0.004), "{out}");
    assert_eq!(parameters["command_delay"].as_float(), Some(0.01), "{out}");
    // Randomization around the fit needs the fit's spread…
    let config = dir.join("config.toml");
    std::fs::write(&config, "[randomization]\ncalibration_spread = 2.0\n").unwrap();
    let train = |cal: &Path| {
        twinbots(&[
            "train",
            "cartpole",
            "--calibration",
            cal.to_str().unwrap(),
            "--config",
            config.to_str().unwrap(),
            "--print-config",
        ])
    };
    let (ok, _, err) = train(&cal);
    assert!(!ok && err.contains("calibration_spread = 2 needs a calibration with a [spread] table"), "{err}");
    // …which the run records with the calibration.
    std::fs::write(&cal, "[parameters]\npole_joint.damping = 0.004\n[spread]\npole_joint.damping = 0.001\n").unwrap();
    let (ok, out, err) = train(&cal);
    assert!(ok, "{err}");
    let settings: toml::Table = toml::from_str(&out).unwrap();
    assert_eq!(settings["calibration"]["spread"]["pole_joint.damping"].as_float(), Some(0.001), "{out}");
    std::fs::write(&cal, "[parameters]\npole_joint.damping = 0.004\n[spread]\ncommand_delay = 0.001\n").unwrap();
    let (ok, _, err) = train(&cal);
    assert!(!ok && err.contains("calibration.toml") && err.contains("[spread] names 'command_delay'"), "{err}");
    std::fs::write(&cal, "[parameters]\npole_joint.stiffness = 1.0\n").unwrap();
    let (ok, _, err) = twinbots(&["train", "cartpole", "--calibration", cal.to_str().unwrap(), "--print-config"]);
    assert!(
        !ok && err.contains("calibration.toml") && err.contains("unknown parameter 'pole_joint.stiffness'"),
        "{err}"
    );
    // `view` reads and checks the file before any window opens.
    let (ok, _, err) = twinbots(&["view", "cartpole", "--calibration", cal.to_str().unwrap()]);
    assert!(
        !ok && err.contains("calibration.toml") && err.contains("unknown parameter 'pole_joint.stiffness'"),
        "{err}"
    );
}

/// A briefly trained cart-pole run in `dir/run`.
fn trained_cartpole(dir: &Path) -> PathBuf {
    let run = dir.join("run");
    let (ok, _, err) = twinbots(&["train", "cartpole", "--timesteps", "512", "--out", run.to_str().unwrap()]);
    assert!(ok, "{err}");
    run
}

/// Wheel 1's position RMSE (rad) in `twinbots replay`'s report.
fn wheel_rmse(report: &str) -> f64 {
    let line = report
        .lines()
        .find(|l| l.starts_with("wheel1_joint"))
        .unwrap_or_else(|| panic!("no wheel1_joint line in\n{report}"));
    line.split_whitespace().nth(1).unwrap().parse().unwrap()
}

#[test]
fn eval_logs_an_episode_that_replays() {
    let dir = scratch("eval");
    let run = trained_cartpole(&dir);
    let log = dir.join("episode.mcap");
    let (ok, out, err) = twinbots(&["eval", run.to_str().unwrap(), "--episodes", "1", "--log", log.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(out.contains("logged"), "{out}");
    let read = twinbots_log::read(&log).unwrap();
    assert_eq!(read.meta.robot, "cartpole");
    assert_eq!(read.joints, ["wheel1_joint", "wheel2_joint", "wheel3_joint", "wheel4_joint", "pole_joint"]);
    assert!(
        read.states.len() > 5 && !read.commands.is_empty(),
        "{} states, {} commands",
        read.states.len(),
        read.commands.len()
    );
    assert!((read.meta.control_period - 0.032).abs() < 1e-9, "{}", read.meta.control_period);
    // The twin's own episode, replayed on its rig: the wheels follow their logged commands.
    let (ok, out, err) =
        twinbots(&["replay", "cartpole", log.to_str().unwrap(), "--out", dir.join("replay").to_str().unwrap()]);
    assert!(ok, "{err}");
    let wheel = wheel_rmse(&out);
    assert!(wheel < 0.05, "wheel 1 position RMSE {wheel} rad\n{out}");
}

#[test]
fn robot_logs_its_episodes_on_a_calibrated_twin() {
    let dir = scratch("robot");
    let run = trained_cartpole(&dir);
    let onnx = dir.join("policy.onnx");
    let (ok, _, err) = twinbots(&["export", run.to_str().unwrap(), "--onnx", onnx.to_str().unwrap()]);
    assert!(ok, "{err}");
    let cal = dir.join("calibration.toml");
    std::fs::write(&cal, "[parameters]\ncommand_delay = 0.008\n").unwrap();
    let log = dir.join("robot.csv");
    let (ok, _, err) =
        twinbots(&["robot", "cartpole", "--policy", onnx.to_str().unwrap(), "--episodes", "2", "--log", "robot.txt"]);
    assert!(!ok && err.contains("robot.txt") && err.contains(".mcap or a .csv"), "{err}");
    let (ok, out, err) = twinbots(&[
        "robot",
        "cartpole",
        "--policy",
        onnx.to_str().unwrap(),
        "--episodes",
        "2",
        "--calibration",
        cal.to_str().unwrap(),
        "--log",
        log.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert!(out.contains("logged robot 0's run"), "{out}");
    let read = twinbots_log::read(&log).unwrap();
    assert_eq!(read.meta.calibration, cal.display().to_string());
    assert!(read.states.len() > 5 && read.states[0].time == 0.0, "{} states", read.states.len());
    // Two episodes and the homing between them, continuous: replayed on the calibrated rig,
    // the wheels follow.
    let (ok, out, err) = twinbots(&[
        "replay",
        "cartpole",
        log.to_str().unwrap(),
        "--calibration",
        cal.to_str().unwrap(),
        "--out",
        dir.join("replay").to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let wheel = wheel_rmse(&out);
    assert!(wheel < 0.05, "wheel 1 position RMSE {wheel} rad\n{out}");
}

#[test]
fn outputs_that_cannot_be_written_are_named_in_the_error() {
    // A file where a directory should be: unwritable for root too (not a directory).
    let dir = scratch("unwritable");
    let blocker = dir.join("blocker");
    std::fs::write(&blocker, "a file").unwrap();
    let log = dir.join("ur5e.mcap");
    write_raw(&ur5e_log(1.0), &log);
    let (log, inside) = (log.to_str().unwrap(), blocker.join("out"));
    let out = inside.to_str().unwrap();
    let truth = dir.join("truth.toml");
    std::fs::write(&truth, "[parameters]\n").unwrap();
    let mcap = format!("{out}/log.mcap");
    let cases: [&[&str]; 4] = [
        &["replay", "ur5e", log, "--out", out],
        &["identify", "ur5e", log, "--out", out, "--generations", "1"],
        &["record", "ur5e", "--truth", truth.to_str().unwrap(), "--seconds", "0.5", "--out", &mcap],
        &["train", "cartpole", "--timesteps", "64", "--out", out],
    ];
    for args in cases {
        let (ok, _, err) = twinbots(args);
        assert!(!ok, "{args:?} succeeded");
        assert!(err.contains(out) && err.contains("Not a directory"), "{args:?}: {err}");
    }
}

/// A fit no better than the twin as it runs is refused: one generation from the prior cannot
/// reach the nominal twin that recorded the log, and nothing but the --out folder is left.
#[test]
fn a_fit_that_would_make_the_twin_worse_is_not_written() {
    let dir = scratch("no-better");
    let log = dir.join("nominal.mcap");
    write_raw(&ur5e_log(1.0), &log);
    let out = dir.join("cal");
    let (ok, stdout, err) =
        twinbots(&["identify", "ur5e", log.to_str().unwrap(), "--generations", "1", "--out", out.to_str().unwrap()]);
    assert!(!ok, "{stdout}");
    assert!(err.contains("no better than the twin as it runs") && err.contains("nothing written"), "{err}");
    assert!(stdout.contains("tracking error (χ² per step)"), "the fit's table is printed: {stdout}");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "something was written into {}", out.display());
}
