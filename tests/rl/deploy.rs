//! A deploy bundle on a robot: the fixture's UR5e reach policy exported with `--bundle` and run
//! by `deploy` through RTDE against the stand-in, as in a dry run; a reckless policy kept off
//! the table and inside the joints' stops by the shadow; mismatched bundles and silent or late
//! robots turned into clear errors with the robot told to stop.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use twinbots_ops::bundle::Bundle;
use twinbots_ops::deploy::arm::{Arm, Measured, RtdeArm, TwinArm};
use twinbots_ops::deploy::{DeployOptions, deploy, deploy_policy};
use twinbots_ops::ur_sim::UrSimOptions;
use twinbots_rtde::RtdeClient;
use ur5e::deploy::lowest_point;

use crate::delivery::{failed, fixture_run, succeeded, twinbots};
use crate::robot_file_arm::six_joint_robot_file;
use crate::rtde::Standin;
use twinbots_arm::reach::resolved_rate;

fn bundle(test: &str) -> PathBuf {
    let run = fixture_run("ur5e-reach", test);
    let dir = run.join("bundle");
    succeeded(twinbots().arg("export").arg(&run).arg("--bundle").arg(&dir).output().unwrap());
    dir
}

/// Options for `episodes` with a 250 ms deadline: the test binaries share CI's 2 cores, so a
/// scheduler pause can hold one command past the default 20 ms (CI saw 28 ms once). The
/// deadline's enforcement is the late arm's test; the others check what the deadline is not about.
fn patient(episodes: usize) -> DeployOptions {
    DeployOptions { episodes, deadline: Duration::from_millis(250), ..Default::default() }
}

#[test]
fn deploy_reaches_through_rtde_as_in_the_dry_run() {
    let bundle = Bundle::read(&bundle("deploy-rtde")).unwrap();
    let options = DeployOptions { seed: 5, ..patient(8) };
    let standin = Standin::start(0.1);
    let mut arm = RtdeArm::connect(&standin.address(), Duration::from_secs(2)).unwrap();
    let through_rtde = deploy(&mut arm, &bundle, &options, |_| {}).unwrap();
    let mut twin = TwinArm::new(&UrSimOptions::default(), None).unwrap();
    let dry = deploy(&mut twin, &bundle, &options, |_| {}).unwrap();
    let successes = |r: &twinbots_ops::deploy::DeployReport| r.episodes.iter().filter(|e| e.success).count();
    assert!(successes(&through_rtde) >= 7, "{:#?}", through_rtde.episodes);
    assert!(successes(&dry) >= 7, "{:#?}", dry.episodes);
    assert!(successes(&through_rtde).abs_diff(successes(&dry)) <= 1);
    // The same targets (the seed's), and the median command well within the default 20 ms deadline.
    assert!(through_rtde.episodes.iter().zip(&dry.episodes).all(|(a, b)| a.target == b.target));
    assert!(through_rtde.latency_p50_us < 20_000.0 && through_rtde.commands > 8 * 10, "{through_rtde:#?}");
    assert_eq!(through_rtde.refused, 0);
}

/// A robot file's six-joint arm deploys as the UR5e does: `export --bundle` of its run carries
/// its joints, each joint's speed and its policy period; `deploy` drives it through RTDE on the
/// stand-in serving the same file as in the dry run. A resolved-rate policy over the
/// deployment's observation (the reach's own terms over the joints as RTDE reports them)
/// arrives, so that observation is the one the twin trains on. Another robot file is refused.
#[test]
fn a_robot_file_arm_deploys_through_rtde_as_in_the_dry_run() {
    use twinbots_ops::bundle::JointValues;
    use twinbots_sim::urdf::robot_file::RobotFile;
    let path = six_joint_robot_file("deploy");
    let run = path.with_file_name("run");
    succeeded(twinbots().arg("train").arg(&path).args(["--timesteps", "1000", "--out"]).arg(&run).output().unwrap());
    let dir = path.with_file_name("bundle");
    succeeded(twinbots().arg("export").arg(&run).arg("--bundle").arg(&dir).output().unwrap());
    let robot = path.to_str().unwrap();
    let bundle = Bundle::read_for(&dir, robot).unwrap();
    let file = RobotFile::read(&path).unwrap();
    let m = &bundle.manifest;
    assert_eq!(m.robot, robot);
    assert_eq!(m.joints.iter().map(|j| j.name.as_str()).collect::<Vec<_>>(), file.joints);
    assert_eq!(m.action.scale, JointValues::PerJoint(file.speed_limits.clone()));
    assert_eq!(m.control_period_s, 0.04);

    let policy = |obs: &[f32]| Ok(resolved_rate(&file, obs));
    let options = DeployOptions { seed: 3, ..patient(8) };
    let served = bundle.robot.served_arm().unwrap();
    let standin = Standin::serving(UrSimOptions { arm: served.clone(), watchdog: 0.1, ..Default::default() });
    let mut arm = RtdeArm::connect(&standin.address(), Duration::from_secs(2)).unwrap();
    let through_rtde = deploy_policy(&mut arm, &bundle, &policy, &options, |_| {}).unwrap();
    let mut twin = TwinArm::new(&UrSimOptions { arm: served, ..Default::default() }, None).unwrap();
    let dry = deploy_policy(&mut twin, &bundle, &policy, &options, |_| {}).unwrap();
    let successes = |r: &twinbots_ops::deploy::DeployReport| r.episodes.iter().filter(|e| e.success).count();
    assert!(successes(&through_rtde) >= 7, "{:#?}", through_rtde.episodes);
    assert!(successes(&dry) >= 7, "{:#?}", dry.episodes);
    assert!(through_rtde.episodes.iter().zip(&dry.episodes).all(|(a, b)| a.target == b.target));
    assert_eq!(through_rtde.refused, 0, "{through_rtde:#?}");

    // The shadow's acceleration limits: a UR's 40 rad/s² where the file gives none, else one
    // per joint; a list that does not fit the joints is named.
    assert_eq!(m.shadow.max_acceleration_rad_s2, JointValues::All(40.0));
    let manifest = dir.join("bundle.json");
    let written: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&manifest).unwrap()).unwrap();
    for (limits, expected) in
        [(vec![10.0, 20.0, 30.0, 40.0, 50.0, 60.0], None), (vec![1.0, 2.0], Some("2 values for 6 joints"))]
    {
        let mut edited = written.clone();
        edited["shadow"]["max_acceleration_rad_s2"] = serde_json::json!(limits);
        std::fs::write(&manifest, serde_json::to_string_pretty(&edited).unwrap()).unwrap();
        match (Bundle::read_for(&dir, robot), expected) {
            (Ok(b), None) => assert_eq!(twinbots_ops::deploy::shadow_of(&b).max_acceleration.to_vec(), limits),
            (Err(e), Some(expected)) => {
                let e = e.to_string();
                assert!(e.contains("bundle.json: shadow.max_acceleration_rad_s2") && e.contains(expected), "{e}")
            }
            (got, _) => panic!("{limits:?}: {:?}", got.map(|_| ())),
        }
    }
    std::fs::write(&manifest, serde_json::to_string_pretty(&written).unwrap()).unwrap();

    // The same arm under another file's name is another robot.
    let other = path.with_file_name("other.toml");
    std::fs::copy(&path, &other).unwrap();
    let err = Bundle::read_for(&dir, other.to_str().unwrap()).err().expect("another robot").to_string();
    assert!(err.contains("is for the robot") && err.contains("other.toml"), "{err}");
}

#[test]
fn the_shadow_keeps_a_reckless_policy_off_the_table_and_inside_the_stops() {
    let bundle = Bundle::read(&bundle("deploy-shadow")).unwrap();
    let standin = Standin::start(0.1);
    // An independent watcher of what the stand-in does, at its full rate.
    let mut watcher = RtdeClient::connect(&standin.address(), Duration::from_secs(2)).unwrap();
    watcher.setup_outputs(&["actual_q", "target_qd"], 500.0).unwrap();
    watcher.start().unwrap();
    let seen = Arc::new(Mutex::new((f64::INFINITY, 0.0f64, 0.0f64)));
    let record = seen.clone();
    let watching = std::thread::spawn(move || {
        while let Ok(p) = watcher.receive() {
            let q = p.vector6("actual_q").unwrap();
            let qd = p.vector6("target_qd").unwrap();
            let mut s = record.lock().unwrap();
            s.0 = s.0.min(lowest_point(&q).1);
            s.1 = s.1.max(q[2].abs());
            s.2 = s.2.max(qd.iter().fold(0.0, |m, v| m.max(v.abs())));
        }
    });
    // Full speed down with the shoulder and the elbow, every step: into the table.
    let dive = |_: &[f32]| Ok(vec![0.0, 1.0, 1.0, 0.0, 0.0]);
    let mut arm = RtdeArm::connect(&standin.address(), Duration::from_secs(2)).unwrap();
    let report = deploy_policy(&mut arm, &bundle, &dive, &patient(1), |_| {}).unwrap();
    assert!(report.refused > 0, "the shadow refused the dive: {report:#?}");
    // Bend the elbow all the way, every step: into its stop.
    let bend = |_: &[f32]| Ok(vec![0.0, 0.0, -1.0, 0.0, 0.0]);
    let report = deploy_policy(&mut arm, &bundle, &bend, &patient(1), |_| {}).unwrap();
    assert!(report.refused > 0, "the shadow refused the elbow's stop: {report:#?}");
    drop(arm);
    std::thread::sleep(Duration::from_millis(100));
    let (lowest, elbow, fastest) = *seen.lock().unwrap();
    drop(standin);
    let _ = watching.join();
    assert!(lowest >= 0.0, "a point of the arm went {lowest} m into the table");
    assert!(elbow < std::f64::consts::PI, "the elbow reached {elbow} rad, past its ±π stop");
    assert!(fastest <= std::f64::consts::PI + 1e-6, "a joint was commanded {fastest} rad/s");
    assert!(lowest < 0.1 && elbow > 2.5, "the policies did drive towards the limits: lowest {lowest}, elbow {elbow}");
}

#[test]
fn deploy_refuses_mismatched_bundles_and_stops_a_late_or_silent_robot() {
    let dir = bundle("deploy-bad");
    // Another robot, another joint order, another control period: refused, naming the mismatch.
    let err = failed(twinbots().args(["deploy", "cartpole", "--dry-run", "--bundle"]).arg(&dir).output().unwrap());
    assert!(err.contains("robot 'cartpole' has no controller link"), "{err}");
    let edit = |name: &str, from: &str, to: &str| -> PathBuf {
        let copy = dir.with_file_name(name);
        let _ = std::fs::remove_dir_all(&copy);
        std::fs::create_dir_all(&copy).unwrap();
        for f in ["bundle.json", "policy.onnx"] {
            std::fs::copy(dir.join(f), copy.join(f)).unwrap();
        }
        let text = std::fs::read_to_string(copy.join("bundle.json")).unwrap();
        assert!(text.contains(from), "{text}");
        std::fs::write(copy.join("bundle.json"), text.replacen(from, to, 1)).unwrap();
        copy
    };
    let swapped = edit("swapped", "\"shoulder_pan_joint\"", "\"elbow_joint\"");
    let err = failed(twinbots().args(["deploy", "ur5e", "--dry-run", "--bundle"]).arg(&swapped).output().unwrap());
    assert!(err.contains("joints") && err.contains("names and order must match"), "{err}");
    let slower = edit("slower", "\"control_period_s\": 0.04", "\"control_period_s\": 0.08");
    let err = failed(twinbots().args(["deploy", "ur5e", "--dry-run", "--bundle"]).arg(&slower).output().unwrap());
    assert!(err.contains("acts every 0.08 s, this robot's task every 0.04 s"), "{err}");
    let err = failed(
        twinbots()
            .args(["deploy", "ur5e", "--dry-run", "--bundle"])
            .arg(Path::new("/nonexistent/bundle"))
            .output()
            .unwrap(),
    );
    assert!(err.contains("bundle.json") && err.contains("is /nonexistent/bundle a bundle"), "{err}");
    let err = failed(twinbots().args(["robot", "cartpole", "--policy"]).arg(&dir).output().unwrap());
    assert!(err.contains("is for the robot 'ur5e', not 'cartpole'"), "{err}");
    let err = failed(twinbots().args(["robot", "ur5e", "--policy"]).arg(&slower).output().unwrap());
    assert!(err.contains("acts every 0.08 s"), "{err}");
    let ok = succeeded(
        twinbots()
            .args(["deploy", "ur5e", "--dry-run", "--episodes", "2", "--deadline-ms", "250", "--bundle"])
            .arg(&dir)
            .output()
            .unwrap(),
    );
    assert!(ok.contains("success") && ok.contains("of 2"), "{ok}");

    // Reports that come 30 ms late: the first command misses its 20 ms deadline, the robot is
    // told to stop, and the error says why.
    let bundle = Bundle::read(&dir).unwrap();
    let mut late = TamperedArm {
        twin: TwinArm::new(&UrSimOptions::default(), None).unwrap(),
        reads: 0,
        from: 0,
        tamper: |m, _| m.received = Instant::now() - Duration::from_millis(30),
        told: Vec::new(),
    };
    let err = deploy(&mut late, &bundle, &DeployOptions::default(), |_| {}).unwrap_err().to_string();
    assert!(err.contains("missed the control deadline"), "{err}");
    assert_eq!(late.told.last(), Some(&"stop"));

    // A controller that stops reporting mid-run: the deployment ends with an error within its
    // patience, not a hang.
    let standin = Standin::start(0.1);
    let mut arm = RtdeArm::connect(&standin.address(), Duration::from_millis(300)).unwrap();
    let stopper = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(800));
        drop(standin);
    });
    let began = Instant::now();
    // (The error must be the silence, not a late command.)
    let err = deploy(&mut arm, &bundle, &patient(50), |_| {}).unwrap_err();
    stopper.join().unwrap();
    assert!(began.elapsed() < Duration::from_secs(5), "{:?}", began.elapsed());
    let text = format!("{err:#}");
    assert!(text.contains("RTDE"), "{text}");
}

/// The twin arm, watched: the closest its skeleton came to the shadow's obstacles.
struct WatchedArm {
    twin: TwinArm,
    shadow: twinbots_task::shadow::Shadow,
    closest: f64,
}

impl Arm for WatchedArm {
    fn read(&mut self) -> anyhow::Result<Measured> {
        let m = self.twin.read()?;
        if let Some((_, _, gap)) = self.shadow.closest_keepout(&m.q) {
            self.closest = self.closest.min(gap);
        }
        Ok(m)
    }
    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.twin.command(speeds)
    }
    fn stop(&mut self) -> anyhow::Result<()> {
        self.twin.stop()
    }
    fn describe(&self) -> String {
        "a watched arm".into()
    }
}

#[test]
fn a_bundle_carries_its_cell_and_the_shadow_keeps_the_arm_off_its_obstacles() {
    let dir = bundle("deploy-cell");
    // As `export` writes a run trained with `--cell`: a column where turning the pan 0.6 rad
    // from home brings the tool.
    let mut turned = ur5e::kinematics::HOME.map(|v| v as f64);
    turned[0] += 0.6;
    let tool = ur5e::deploy::skeleton(&turned).last().unwrap().1;
    let cell = ur5e::layout::DEFAULT.replacen(
        "# [[obstacle]]\n# centre = [-0.1, 0.45, 0.95]   # m, cell frame\n# size = [0.1, 0.1, 0.4]",
        &format!("[[obstacle]]\ncentre = [{}, {}, {}]\nsize = [0.1, 0.1, 0.4]", tool.x, tool.y, tool.z + 0.75),
        1,
    );
    std::fs::write(dir.join("cell.toml"), &cell).unwrap();
    let manifest = std::fs::read_to_string(dir.join("bundle.json")).unwrap();
    std::fs::write(
        dir.join("bundle.json"),
        manifest.replacen("\"timesteps\"", "\"cell\": \"cell.toml\",\n  \"timesteps\"", 1),
    )
    .unwrap();
    let bundle = Bundle::read(&dir).unwrap();
    assert_eq!(bundle.cell.obstacles.len(), 1);
    let shadow = twinbots_ops::deploy::shadow_of(&bundle);
    assert_eq!(shadow.keepouts.len(), 1);

    // Pan at full speed, every step: into the column.
    let turn = |_: &[f32]| Ok(vec![1.0, 0.0, 0.0, 0.0, 0.0]);
    let mut arm = WatchedArm {
        twin: TwinArm::new(&UrSimOptions::default(), None).unwrap(),
        shadow: shadow.clone(),
        closest: f64::INFINITY,
    };
    let report = deploy_policy(&mut arm, &bundle, &turn, &patient(1), |_| {}).unwrap();
    assert!(report.refused > 0, "the shadow refused the turn: {report:#?}");
    assert!(arm.closest > 0.0, "the arm touched the column");
    assert!(arm.closest < 0.15, "the policy did drive towards it: closest {:.3} m", arm.closest);

    // A manifest that names a cell file that is not there is refused, naming it.
    std::fs::remove_file(dir.join("cell.toml")).unwrap();
    let err = Bundle::read(&dir).err().expect("a bundle without its cell file").to_string();
    assert!(err.contains("cell.toml"), "{err}");
}

/// An arm whose reports, from the `from`-th on, are altered by `tamper`; it records what it was told.
struct TamperedArm {
    twin: TwinArm,
    reads: usize,
    from: usize,
    tamper: fn(&mut Measured, usize),
    told: Vec<&'static str>,
}

impl Arm for TamperedArm {
    fn read(&mut self) -> anyhow::Result<Measured> {
        let mut m = self.twin.read()?;
        self.reads += 1;
        if self.reads >= self.from {
            (self.tamper)(&mut m, self.reads - self.from);
        }
        Ok(m)
    }
    fn command(&mut self, speeds: &[f64; 6]) -> anyhow::Result<()> {
        self.told.push("command");
        self.twin.command(speeds)
    }
    fn stop(&mut self) -> anyhow::Result<()> {
        self.told.push("stop");
        self.twin.stop()
    }
    fn describe(&self) -> String {
        "a tampered arm".into()
    }
}

/// A controller clock that stands still, runs back or is NaN, a joint reported beyond its range
/// and a control program in a protective stop each end the deployment at once: the robot told
/// to stop, the cause named (a frozen clock hung `deploy` for 619 s, homing on).
#[test]
fn a_frozen_clock_a_joint_out_of_range_or_a_stopped_program_stops_the_robot() {
    let dir = bundle("deploy-fail-safe");
    let bundle = Bundle::read(&dir).unwrap();
    let cases: [(fn(&mut Measured, usize), &str); 5] = [
        (|m, _| m.time = 100.0, "stood still or ran back"),
        (|m, k| m.time = 100.0 - k as f64, "stood still or ran back"),
        (|m, _| m.time = f64::NAN, "reported time NaN"),
        (|m, _| m.q[2] = 4.0, "elbow_joint at 4.000 rad, beyond its range"),
        (|m, _| m.program = 4, "protective stop"),
    ];
    for (tamper, expected) in cases {
        let mut arm = TamperedArm {
            twin: TwinArm::new(&UrSimOptions::default(), None).unwrap(),
            reads: 0,
            from: 50,
            tamper,
            told: Vec::new(),
        };
        let began = Instant::now();
        let err = deploy(&mut arm, &bundle, &patient(3), |_| {}).unwrap_err().to_string();
        assert!(err.contains(expected) && err.contains("told to stop"), "{expected}: {err}");
        assert_eq!(arm.told.last(), Some(&"stop"), "{expected}");
        assert!(arm.reads < 60, "{expected}: {} reads before it stopped", arm.reads);
        assert!(began.elapsed() < Duration::from_secs(5), "{expected}: {:?}", began.elapsed());
    }
}

/// SIGTERM (as Ctrl-C) on `deploy` through RTDE: it tells the robot to stop (its program goes
/// idle, not to the watchdog's stop a killed client leaves), names the signal and fails.
#[test]
fn a_terminated_deployment_stops_the_robot_first() {
    use std::io::BufRead;
    use twinbots_ops::ur_sim::program::{ProgramState, STATE};
    let dir = bundle("deploy-sigterm");
    let standin = Standin::start(0.1);
    let mut child = twinbots()
        .args(["deploy", "ur5e", "--rtde", &standin.address(), "--episodes", "1000", "--bundle"])
        .arg(&dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = std::io::BufReader::new(child.stdout.take().unwrap());
    let mut lines = stdout.lines().map_while(Result::ok);
    assert!(lines.any(|l| l.starts_with("deploying")), "deploy never started");
    std::thread::sleep(Duration::from_millis(500));
    // SAFETY: a signal to our own child, by its pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let output = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success() && stderr.contains("stopped by SIGTERM"), "{stderr}");
    let mut client = RtdeClient::connect(&standin.address(), Duration::from_secs(2)).unwrap();
    client.setup_outputs(&[STATE], 125.0).unwrap();
    client.start().unwrap();
    let state = client.receive().unwrap().get(STATE).and_then(twinbots_rtde::Value::as_i64).unwrap();
    assert_eq!(state, ProgramState::Idle as i64, "the program was not told to stop");
}
