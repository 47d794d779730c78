//! The recordings of a real UR5 (`../shared/data/ur5-real/`, UR's RTDE recorder's CSV): they
//! replay through the twin, calibrate it, and its shadow flags the pushes. Skipped where the
//! recordings are not beside the clone.

use std::path::Path;

use crate::cli::{scratch, twinbots};

/// A UR recording as UR's RTDE recorder writes it (space-delimited, gzip) replays through the
/// UR5e twin; a truncated gzip is an error naming the file.
#[test]
fn a_ur_rtde_recording_replays_and_a_truncated_one_is_named() {
    let dir = scratch("rtde-csv");
    let real =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ur5-real/Movement_No10_Standstill_WDist.csv.gz");
    if !real.is_file() {
        eprintln!("skipped: {} is not there", real.display());
        return;
    }
    let (ok, stdout, err) =
        twinbots(&["replay", "ur5e", real.to_str().unwrap(), "--out", dir.join("r").to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(stdout.contains("s replayed; position RMSE over joints"), "{stdout}");
    let bytes = std::fs::read(&real).unwrap();
    let cut = dir.join("cut.csv.gz");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let (ok, _, err) = twinbots(&["replay", "ur5e", cut.to_str().unwrap(), "--out", dir.join("c").to_str().unwrap()]);
    assert!(!ok && err.contains("cut.csv.gz") && err.contains("gzip"), "{err}");
}

/// The real UR5 (CB2) from its robot file: `identify` fits its effort model to three of the
/// recordings in well under a second and predicts the three held out better on every joint (the
/// shoulder and elbow by 40 % or more) than the vendor's description; `replay` with the
/// calibration flags each of the five pushes of the standstill run and nothing in the undisturbed
/// held-out runs; `monitor --replay` flags the same as the recording streams in.
#[test]
fn a_real_ur5_calibrates_predicts_held_out_efforts_and_its_shadow_flags_the_pushes() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/ur5-real");
    if !data.is_dir() {
        eprintln!("skipped: {} is not there", data.display());
        return;
    }
    let dir = scratch("ur5-real");
    let run = |name: &str| data.join(format!("{name}.csv.gz")).display().to_string();
    let robot = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/robots/ur5.toml").display().to_string();
    let efforts = "current:10,10,10,10,10,10";
    let cal = dir.join("cal");
    let held_out = ["Movement_No1", "Movement_No2", "Movement_No3_Acc"];
    let mut args = vec!["identify".to_string(), robot.clone()];
    args.extend(
        ["Movement_No4_Acc", "Movement_No5_Acc_slow_no_disturbance", "Movement_No6_Acc_slow_Verify_Model"].map(run),
    );
    args.push("--validate".into());
    args.extend(held_out.map(run));
    args.extend(["--efforts".into(), efforts.into(), "--out".into(), cal.display().to_string()]);
    let (ok, stdout, err) = twinbots(&args.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(ok, "{err}");
    let fit: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(cal.join("fit.json")).unwrap()).unwrap();
    let logs = fit["logs"].as_array().unwrap();
    assert_eq!(logs.iter().filter(|l| l["held_out"] == true).count(), 3, "{stdout}");
    for log in logs.iter().filter(|l| l["held_out"] == true) {
        let before: Vec<f64> = serde_json::from_value(log["rmse_nominal"].clone()).unwrap();
        let after: Vec<f64> = serde_json::from_value(log["rmse_calibrated"].clone()).unwrap();
        for j in 0..6 {
            assert!(after[j] < before[j], "{}: joint {j}: {} against {}", log["log"], after[j], before[j]);
        }
        for j in [1, 2] {
            assert!(after[j] <= 0.6 * before[j], "{}: joint {j}: {} against {}", log["log"], after[j], before[j]);
        }
    }
    for file in ["calibration.toml", "efforts.png"] {
        assert!(cal.join(file).is_file(), "no {file}");
    }
    let calibration = cal.join("calibration.toml").display().to_string();
    let replay = |name: &str| {
        let out = dir.join(name);
        let (ok, stdout, err) = twinbots(&[
            "replay",
            &robot,
            &run(name),
            "--calibration",
            &calibration,
            "--efforts",
            efforts,
            "--out",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        let report: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join("replay.json")).unwrap()).unwrap();
        assert!(out.join("replay.png").is_file() && out.join("efforts.png").is_file(), "{stdout}");
        report["flagged"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| (f["start"].as_f64().unwrap(), f["end"].as_f64().unwrap()))
            .collect::<Vec<_>>()
    };
    for name in held_out {
        let flags = replay(name);
        assert!(flags.is_empty(), "{name}: {flags:?}");
    }
    // The pushes of the standstill run, where its plot shows them (s).
    let flags = replay("Movement_No10_Standstill_WDist");
    for push in [3.4, 5.43, 6.46, 8.3, 10.5] {
        assert!(flags.iter().any(|(a, b)| (a - 0.05..=b + 0.05).contains(&push)), "the push at {push} s: {flags:?}");
    }
    assert_eq!(flags.len(), 5, "{flags:?}");
    // `monitor --replay` judges the samples as they stream in and flags what `replay` flags on
    // the whole recording, bit for bit.
    let out = dir.join("monitor");
    let (ok, stdout, err) = twinbots(&[
        "monitor",
        &robot,
        "--replay",
        &run("Movement_No10_Standstill_WDist"),
        "--calibration",
        &calibration,
        "--efforts",
        efforts,
        "--speed",
        "0",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    assert_eq!(stdout.matches("ALARM effort").count(), 5, "{stdout}");
    let followed: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("monitor.json")).unwrap()).unwrap();
    let replayed: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("Movement_No10_Standstill_WDist").join("replay.json")).unwrap(),
    )
    .unwrap();
    assert_eq!(followed["flagged"], replayed["flagged"]);
    assert!(out.join("shadow.png").is_file());
    // A built-in robot has no effort shadow to follow a recording with; the calibration is needed.
    let (ok, _, err) = twinbots(&["monitor", "ur5e", "--replay", &run("Movement_No2"), "--out", out.to_str().unwrap()]);
    assert!(!ok && err.contains("no robot file"), "{err}");
    let (ok, _, err) = twinbots(&["monitor", &robot, "--replay", &run("Movement_No2"), "--out", out.to_str().unwrap()]);
    assert!(!ok && err.contains("needs --calibration"), "{err}");
    // Read another way than it was calibrated, a log is refused, naming the calibration.
    let (ok, _, err) = twinbots(&[
        "replay",
        &robot,
        &run("Movement_No2"),
        "--calibration",
        &calibration,
        "--efforts",
        "target_moment",
        "--out",
        dir.join("other").to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("calibration.toml") && err.contains("--efforts"), "{err}");
}
