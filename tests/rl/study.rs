//! Policy test suites (`twinbots study`), as a user runs them: the shipped suites on the
//! classical controllers, a trained run and its ONNX export side by side; the files they write;
//! bad suites and controllers as clear errors.

use std::path::{Path, PathBuf};

use crate::delivery::{failed, fixture_run, succeeded, twinbots};

fn temp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("twinbots-study-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn study(args: &[&std::ffi::OsStr]) -> std::process::Output {
    twinbots().current_dir(env!("CARGO_MANIFEST_DIR")).arg("study").args(args).output().unwrap()
}

/// summary.csv as rows of (column → value).
fn summary(out: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let text = std::fs::read_to_string(out.join("summary.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<String> = lines.next().unwrap().split(',').map(String::from).collect();
    lines.map(|l| header.iter().cloned().zip(l.split(',').map(String::from)).collect()).collect()
}

#[test]
fn the_cartpole_suite_sets_a_run_and_its_onnx_export_beside_the_classical_controller() {
    let run = fixture_run("cartpole-balance", "study");
    let onnx = run.with_extension("onnx");
    succeeded(twinbots().arg("export").arg(&run).arg("--onnx").arg(&onnx).output().unwrap());
    let out = temp("cartpole");
    let controllers = format!("classic,{},{}", run.display(), onnx.display());
    let stdout = succeeded(study(&[
        "cartpole".as_ref(),
        "--controller".as_ref(),
        controllers.as_ref(),
        "--out".as_ref(),
        out.as_os_str(),
    ]));
    assert!(stdout.contains("30 runs"), "{stdout}");
    let rows = summary(&out);
    assert_eq!(rows.len(), 30, "10 tests × 3 controllers");
    let row = |controller: &str, test: &str| {
        rows.iter()
            .find(|r| r["controller"] == controller && r["test"] == test)
            .unwrap_or_else(|| panic!("{controller} {test}"))
    };
    // The classical controller recovers from a light kick and falls to a 0.5 N one: the push acts.
    assert_eq!(row("classic", "step-0.1N")["survived"], "true");
    assert_eq!(row("classic", "step-0.5N")["survived"], "false");
    assert_eq!(row("classic", "step-0.5N")["ended_by"], "pole_fallen");
    // The run and its export are one policy on one twin: the same figures.
    let (run_label, onnx_label) =
        (run.file_name().unwrap().to_str().unwrap(), onnx.file_name().unwrap().to_str().unwrap());
    for test in ["step-0.2N", "impulse-0.2N-at-4s", "payload-0.1kg"] {
        let (a, b) = (row(run_label, test), row(onnx_label, test));
        for column in ["survived", "peak", "overshoot", "settling_time_s", "steady_state_error"] {
            assert_eq!(a[column], b[column], "{test} {column}");
        }
    }
    // The trained policy holds the pole through the impulse the classical controller falls to.
    assert_eq!(row(run_label, "impulse-0.2N-at-2s")["survived"], "true");
    assert_eq!(row("classic", "impulse-0.2N-at-2s")["survived"], "false");

    // Per run: the time series (the push in its column for its two control steps) and metadata.
    let series = std::fs::read_to_string(out.join("classic/step-0.5N-seed0/timeseries.csv")).unwrap();
    let mut lines = series.lines();
    assert_eq!(lines.next().unwrap(), "time_s,cart_x,cart_velocity,pole_angle,pole_rate,action_0,push_n");
    let pushed: Vec<&str> = lines.filter(|l| l.ends_with(",0.5")).map(|l| l.split(',').next().unwrap()).collect();
    assert_eq!(pushed, ["2.016", "2.048"], "from the first control step at or after 2 s, for 2 steps of 32 ms");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("classic/step-0.5N-seed0/metadata.json")).unwrap())
            .unwrap();
    assert_eq!(meta["robot"], "cartpole");
    assert_eq!(meta["run"]["survived"], false);
    assert_eq!(meta["run"]["force_n"], 0.5);
    let plots: Vec<_> = std::fs::read_dir(out.join("plots")).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(plots.len(), 10, "a plot per test");
    for plot in &plots {
        assert!(image::open(plot).is_ok(), "{} is a PNG", plot.display());
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        report.contains("![step-0.5N](plots/step-0.5N.png)")
            && report.contains("| classic | step-0.5N | 0 | no (pole_fallen at"),
        "{report}"
    );

    // Same suite, same seeds: the same results.
    let again = temp("cartpole-again");
    succeeded(study(&[
        "cartpole".as_ref(),
        "--controller".as_ref(),
        controllers.as_ref(),
        "--out".as_ref(),
        again.as_os_str(),
    ]));
    assert_eq!(std::fs::read(out.join("summary.csv")).unwrap(), std::fs::read(again.join("summary.csv")).unwrap());
    for dir in [&out, &again, &run] {
        let _ = std::fs::remove_dir_all(dir);
    }
    let _ = std::fs::remove_file(&onnx);
}

#[test]
fn the_pioneer_suite_separates_kicks_its_controller_catches_from_those_it_cannot() {
    let out = temp("pioneer");
    succeeded(study(&["pioneer3at".as_ref(), "--out".as_ref(), out.as_os_str()]));
    let rows = summary(&out);
    let row = |test: &str| rows.iter().find(|r| r["test"] == test).unwrap();
    assert_eq!(row("step-1N")["survived"], "true");
    assert!(!row("step-1N")["settling_time_s"].is_empty(), "settles after a 1 N kick");
    assert_eq!(row("step-3N")["survived"], "false");
    for mass in ["0.4", "0.6", "0.8"] {
        let r = row(&format!("payload-{mass}kg"));
        assert_eq!(r["survived"], "true", "{mass} kg");
        assert_eq!(r["payload_kg"], mass);
    }
    // A heavier ball, a different swing: the payload reaches the physics.
    assert_ne!(row("payload-0.4kg")["peak"], row("payload-0.8kg")["peak"]);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn bad_suites_and_controllers_are_clear_errors() {
    let dir = temp("bad");
    std::fs::create_dir_all(&dir).unwrap();
    let shipped =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/studies/cartpole.toml")).unwrap();
    let ur5e_run = fixture_run("ur5e-reach", "study-bad");
    for (name, text, args, expected) in [
        (
            "link",
            shipped.replace("link = \"pole_tip\"", "link = \"nose\""),
            vec![],
            "link 'nose' is not one of the robot's: cart, pole, pole_tip, wheel1",
        ),
        (
            "signal",
            shipped.replace("signal = \"pole_angle\"", "signal = \"tilt\""),
            vec![],
            "signal = 'tilt': cartpole's observation has cart_x, cart_velocity, pole_angle, pole_rate",
        ),
        (
            "robot",
            shipped.replace("robot = \"cartpole\"", "robot = \"pioneer3at\""),
            vec![],
            "robot = 'pioneer3at', but the study runs cartpole",
        ),
        ("key", shipped.replace("window = 1.0", "windw = 1.0"), vec![], "unknown field `windw`"),
        (
            "seeds",
            shipped.replace("seeds = [0]", &format!("seeds = {:?}", (0..20_000).collect::<Vec<u64>>())),
            vec![],
            "10 tests × 20000 seeds = 200000 runs a controller: at most 1024",
        ),
        (
            "duration",
            shipped.replace("duration = 10.0", "duration = 1e7"),
            vec![],
            "duration = 10000000 s: a run lasts at most 600 s",
        ),
        (
            "at",
            shipped.replace("at = [2.0, 4.0]", "at = [2.0, 40.0]"),
            vec![],
            "impulse.at = 40 s: must lie in [0, duration = 10 s)",
        ),
        (
            "missing",
            shipped.clone(),
            vec!["--controller", "no/such/run"],
            "controller 'no/such/run': neither 'classic', a run directory nor an .onnx file",
        ),
        (
            "other-robot",
            shipped.clone(),
            vec!["--controller", ur5e_run.to_str().unwrap()],
            "a run of ur5e, not of cartpole",
        ),
    ] {
        let file = dir.join(format!("{name}.toml"));
        std::fs::write(&file, text).unwrap();
        let mut all: Vec<&std::ffi::OsStr> =
            vec!["cartpole".as_ref(), file.as_os_str(), "--out".as_ref(), dir.join("out").into_os_string().leak()];
        all.extend(args.iter().map(std::ffi::OsStr::new));
        let stderr = failed(study(&all));
        assert!(stderr.contains(expected), "{name}: {stderr}");
        assert!(
            stderr.contains(&format!("{name}.toml")) || name == "missing" || name == "other-robot",
            "{name}: names the file: {stderr}"
        );
    }
    let stderr = failed(study(&[
        "cartpole".as_ref(),
        "--controller".as_ref(),
        "classic".as_ref(),
        dir.join("none.toml").as_os_str(),
    ]));
    assert!(stderr.contains("none.toml: no such suite file"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(&ur5e_run);
}

#[test]
fn a_cell_study_finds_the_unreachable_layout_and_the_heavier_part() {
    let dir = temp("cell");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("study.toml");
    std::fs::write(
        &file,
        "robot = \"ur5e\"\nepisodes = 2\n[[layout]]\nname = \"default\"\n[[layout]]\nname = \"place-far\"\nplace = [-0.93, -0.50]\n\
         [factors]\npayload = [0.2, 1.5]\nfailure = [\"none\", \"failed-grasp\"]\n",
    )
    .unwrap();
    let out = dir.join("out");
    let stdout = succeeded(study(&["ur5e".as_ref(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
    assert!(stdout.contains("16 episodes"), "{stdout}");
    let rows = summary(&out);
    assert_eq!(rows.len(), 2 * 2 * 2, "layouts × payloads × failures");
    let row = |layout: &str, payload: &str, failure: &str| {
        rows.iter()
            .find(|r| r["layout"] == layout && r["payload_kg"] == payload && r["failure"] == failure)
            .unwrap_or_else(|| panic!("{layout} {payload} {failure}"))
    };
    for payload in ["0.2", "1.5"] {
        // The place fixture beyond the arm's reach: every cycle that gets that far is a reach
        // failure, and none succeeds; the default layout has none.
        assert_eq!(row("place-far", payload, "none")["reach_failures"], "2");
        assert_eq!(row("place-far", payload, "none")["success_rate"], "0.0000");
        assert_eq!(row("default", payload, "none")["reach_failures"], "0");
        assert_eq!(row("default", payload, "none")["success_rate"], "1.0000");
        // A grasp that fails never carries the part anywhere: no reach failure, no success.
        assert_eq!(row("place-far", payload, "failed-grasp")["reach_failures"], "0");
        assert_eq!(row("default", payload, "failed-grasp")["success_rate"], "0.0000");
    }
    let energy = |payload: &str| row("default", payload, "none")["energy_mean_j"].parse::<f64>().unwrap();
    assert!(
        energy("1.5") > energy("0.2") * 1.02,
        "a heavier part costs energy: {} vs {}",
        energy("1.5"),
        energy("0.2")
    );
    let results = std::fs::read_to_string(out.join("results.csv")).unwrap();
    assert_eq!(results.lines().count(), 1 + 16, "one row per episode");
    assert!(results.lines().next().unwrap().contains("approach_s,descend_s,grip_s"), "phase times per episode");
    assert!(results.lines().any(|l| l.contains(",false,grasp_missed,")), "a failed grasp's outcome");
    let phases = std::fs::read_to_string(out.join("phases.csv")).unwrap();
    assert!(phases.contains("classic,default,"), "{phases}");
    for plot in [
        "cycle-time-vs-layout.png",
        "cycle-time-vs-payload_kg.png",
        "success-classic.png",
        "reach-default.png",
        "reach-place-far.png",
        "phases.png",
    ] {
        assert!(image::open(out.join("plots").join(plot)).is_ok(), "{plot}");
    }
    let report = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(report.contains("| classic | place-far | 1 | 1.5 | 0 | none | 0 % |"), "{report}");

    // Command latency and a trained reach policy (the fixture run, PPO): one control step late,
    // it places the part seldom if at all (1 of 25 measured); the classical controller always.
    let run = fixture_run("ur5e-reach", "study-latency");
    std::fs::write(&file, "episodes = 3\n[factors]\nlatency = [0, 1]\n").unwrap();
    let late = dir.join("late");
    let controllers = format!("classic,{}", run.display());
    succeeded(study(&[
        "ur5e".as_ref(),
        file.as_os_str(),
        "--controller".as_ref(),
        controllers.as_ref(),
        "--out".as_ref(),
        late.as_os_str(),
    ]));
    let rows = summary(&late);
    let rate = |controller: &str, latency: &str| {
        rows.iter().find(|r| r["controller"] == controller && r["latency_steps"] == latency).unwrap()["success_rate"]
            .clone()
    };
    let label = run.file_name().unwrap().to_str().unwrap();
    let trained = |latency: &str| rate(label, latency).parse::<f64>().unwrap();
    assert!(trained("0") == 1.0 && trained("1") <= 1.0 / 3.0, "{rows:?}");
    assert_eq!((rate("classic", "0").as_str(), rate("classic", "1").as_str()), ("1.0000", "1.0000"));
    let _ = std::fs::remove_dir_all(&run);

    // Bad studies: an unknown factor, a layout off the table, named with the file.
    for (text, expected) in [
        ("[factors]\ntemperature = [20]\n", "unknown field `temperature`"),
        (
            "[[layout]]\nname = \"off\"\nplace = [-1.2, 0.0]\n",
            "layout[0] ('off'): place.position = [-1.2, 0.0]: the fixture's 12 cm plate leaves the table top",
        ),
    ] {
        std::fs::write(&file, text).unwrap();
        let stderr = failed(study(&["ur5e".as_ref(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
        assert!(stderr.contains("study.toml") && stderr.contains(expected), "{stderr}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A cell study of a robot file's arm (the six-joint arm of boxes, its cell and cup in the
/// file): the study's layouts change the file's own cell, a place fixture beyond the arm's
/// reach shows as reach failures, a failed grasp never places, and the speed slider slows
/// every cycle.
#[test]
fn a_cell_study_runs_a_robot_file_arm_in_the_studys_layouts() {
    let robot = crate::robot_file_arm::six_joint_cell_robot_file("study");
    let dir = temp("arm-cell");
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("study.toml");
    std::fs::write(
        &file,
        format!(
            "robot = \"{}\"\nepisodes = 2\n[[layout]]\nname = \"default\"\n[[layout]]\nname = \"place-far\"\nrobot = [-0.12, 0.42]\nplace = [0.72, -0.42]\n\
             [factors]\nspeed = [1.0, 0.5]\nfailure = [\"none\", \"failed-grasp\"]\n",
            robot.display()
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let stdout = succeeded(study(&[robot.as_os_str(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
    assert!(stdout.contains("16 episodes"), "{stdout}");
    let rows = summary(&out);
    assert_eq!(rows.len(), 2 * 2 * 2, "layouts × speeds × failures");
    let row = |layout: &str, speed: &str, failure: &str| {
        rows.iter()
            .find(|r| r["layout"] == layout && r["speed"] == speed && r["failure"] == failure)
            .unwrap_or_else(|| panic!("{layout} {speed} {failure}: {rows:?}"))
    };
    for speed in ["1", "0.5"] {
        assert_eq!(row("default", speed, "none")["success_rate"], "1.0000", "{rows:?}");
        assert_eq!(row("default", speed, "none")["reach_failures"], "0");
        assert_eq!(row("place-far", speed, "none")["success_rate"], "0.0000");
        assert_eq!(row("place-far", speed, "none")["reach_failures"], "2");
        assert_eq!(row("default", speed, "failed-grasp")["success_rate"], "0.0000");
    }
    let cycle = |speed: &str| row("default", speed, "none")["cycle_time_mean_s"].parse::<f64>().unwrap();
    assert!(cycle("0.5") > 1.3 * cycle("1"), "half speed, a longer cycle: {} vs {}", cycle("0.5"), cycle("1"));
    for plot in ["reach-default.png", "reach-place-far.png", "phases.png", "success-classic.png"] {
        assert!(image::open(out.join("plots").join(plot)).is_ok(), "{plot}");
    }

    // A study for another robot, and an arm without a cell, are refused with the file named.
    std::fs::write(&file, "robot = \"ur5e\"\n").unwrap();
    let stderr = failed(study(&[robot.as_os_str(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
    assert!(stderr.contains("study.toml: robot = 'ur5e', but the study runs"), "{stderr}");
    let bare = crate::robot_file_arm::six_joint_robot_file("study-bare");
    let stderr = failed(study(&[bare.as_os_str(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
    assert!(stderr.contains("arm6.toml: a cell study runs the pick-and-place program, which needs"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
    let _ = std::fs::remove_dir_all(robot.parent().unwrap());
    let _ = std::fs::remove_dir_all(bare.parent().unwrap());
}

/// A push beyond any cell (1e30 N on a 0.2 kg pole, which the solver dropped: the run reported
/// "survived") is refused, naming the key; a run whose observations leave the plausible ends
/// as not survived ("physics_blew_up", `twinbots_study::BLOWN_UP`).
#[test]
fn a_push_the_physics_cannot_take_is_refused() {
    let dir = temp("blow-up");
    std::fs::create_dir_all(&dir).unwrap();
    let suite = "robot = \"cartpole\"\nduration = 4.0\nsignal = \"pole_angle\"\nsetpoint = 0.0\nsettle_band = 0.05\nwindow = 1.0\nseeds = [0]\ncontrollers = [\"classic\"]\n[push]\nlink = \"pole_tip\"\ndirection = [1.0, 0.0, 0.0]\n[step_response]\nforces = [1e30]\nat = 1.0\ncontrol_steps = 2\n";
    let file = dir.join("blow-up.toml");
    std::fs::write(&file, suite).unwrap();
    let out = dir.join("out");
    let stderr = failed(study(&["cartpole".as_ref(), file.as_os_str(), "--out".as_ref(), out.as_os_str()]));
    assert!(stderr.contains("blow-up.toml") && stderr.contains("step_response.forces contains 1e30 N"), "{stderr}");
    let _ = std::fs::remove_dir_all(&dir);
}
