//! The monitor: a twin that follows the robot notices a load it does not know within a second
//! of motion, and stays quiet beside a robot it matches.

use twinbots_ops::linked_arm::LinkedArm;
use twinbots_ops::monitor::{Monitor, MonitorOptions, Report};
use twinbots_ops::ur_sim::program::{COUNTER, MODE, MODE_SPEEDJ, TARGET};
use twinbots_ops::ur_sim::{CYCLE, UrSim, UrSimOptions};
use twinbots_rtde::Value;
use twinbots_rtde::server::{InputState, OutputState};

fn six(out: &OutputState, name: &str) -> [f64; 6] {
    out.get(name).as_vector6().unwrap()
}

pub fn report_of(out: &OutputState) -> Report {
    Report {
        time: out.get("timestamp").as_f64().unwrap(),
        q: six(out, "actual_q"),
        qd: six(out, "actual_qd"),
        command: six(out, "target_qd"),
        effort: six(out, "target_moment"),
    }
}

/// A pick-and-place-like cycle: rest, shoulder and elbow out, rest, back.
fn program(t: f64) -> [f64; 6] {
    let phase = t % 4.0;
    let s = if (0.5..1.5).contains(&phase) {
        0.6
    } else if (2.5..3.5).contains(&phase) {
        -0.6
    } else {
        0.0
    };
    [0.5 * s, s, -s, 0.3 * s, 0.0, 0.0]
}

/// Runs the robot (`robot`'s options) for `seconds` under the program with the monitor on the
/// nominal twin, which never sees every `skip`-th report (a busy link) and sees each report as
/// `tamper` leaves it; returns the alarms' times, kinds and messages and the worst windowed
/// effort RMSE (N·m).
fn follow_tampered(
    robot: &UrSimOptions,
    seconds: f64,
    skip: Option<usize>,
    tamper: fn(&mut Report),
) -> (Vec<(f64, String, String)>, f64) {
    follow_with(robot, MonitorOptions::default(), seconds, skip, tamper)
}

/// [`follow_tampered`] with the monitor's `options` (another arm's twin, say).
fn follow_with(
    robot: &UrSimOptions,
    options: MonitorOptions,
    seconds: f64,
    skip: Option<usize>,
    tamper: fn(&mut Report),
) -> (Vec<(f64, String, String)>, f64) {
    let mut sim = UrSim::new(robot).unwrap();
    let mut inputs = InputState::new();
    inputs.set(MODE, Value::Int32(MODE_SPEEDJ));
    let (first, _) = sim.cycle(&inputs);
    let mut monitor = Monitor::new(options, &report_of(&first)).unwrap();
    let mut alarms = Vec::new();
    for k in 0..(seconds / CYCLE) as usize {
        let t = k as f64 * CYCLE;
        inputs.set(COUNTER, Value::Int32(k as i32));
        for (name, v) in TARGET.iter().zip(program(t)) {
            inputs.set(name, Value::Double(v));
        }
        let (out, _) = sim.cycle(&inputs);
        if skip.is_some_and(|n| k % n == n - 1) {
            continue;
        }
        let mut report = report_of(&out);
        tamper(&mut report);
        for a in monitor.observe(&report) {
            alarms.push((a.time, a.kind.clone(), a.message.clone()));
        }
    }
    let worst = monitor.report().worst_effort_rmse.iter().cloned().fold(0.0, f64::max);
    (alarms, worst)
}

fn follow(robot: &UrSimOptions, seconds: f64, skip: Option<usize>) -> (Vec<(f64, String, String)>, f64) {
    follow_tampered(robot, seconds, skip, |_| {})
}

#[test]
fn the_monitor_notices_an_unmodelled_payload_within_a_second_of_motion() {
    let (alarms, worst) = follow(&UrSimOptions { payload: Some(1.0), ..Default::default() }, 4.0, None);
    let first = alarms
        .iter()
        .find(|(_, k, _)| k == "divergence")
        .unwrap_or_else(|| panic!("no divergence alarm: {alarms:?}, worst effort RMSE {worst}"));
    // The first motion starts at 0.5 s.
    assert!(first.0 < 1.5, "the alarm came at {} s", first.0);
    assert!(worst > 2.0, "a 1 kg load the twin does not know: worst effort RMSE {worst} N*m");
}

#[test]
fn the_monitor_stays_quiet_beside_a_matching_robot() {
    let (alarms, worst) = follow(&UrSimOptions::default(), 20.0, None);
    assert!(alarms.is_empty(), "{alarms:?}");
    assert!(worst < 0.5, "worst effort RMSE {worst} N*m beside a matching robot");
    // A report in 37 lost, in motion too: the twin takes the line between the commands around
    // each gap and stays quiet.
    let (alarms, worst) = follow(&UrSimOptions::default(), 20.0, Some(37));
    assert!(alarms.is_empty(), "{alarms:?} (worst effort RMSE {worst} N*m)");
}

/// A robot file's six-joint arm is followed as the UR5e is: its own twin (its URDF on its test
/// stand) on the same commands stays quiet beside a matching arm, and notices a 1 kg load it
/// does not know within a second of motion, naming the arm's own joints.
#[test]
fn the_monitor_follows_a_robot_file_arm() {
    let path = crate::robot_file_arm::six_joint_robot_file("monitor");
    let arm = LinkedArm::of(path.to_str().unwrap()).unwrap();
    let served = arm.served_arm().unwrap();
    let options = MonitorOptions { shadow: arm.shadow(&Default::default()), arm: served.clone(), ..Default::default() };
    let matching = UrSimOptions { arm: served.clone(), ..Default::default() };
    let (alarms, worst) = follow_with(&matching, options.clone(), 8.0, None, |_| {});
    assert!(alarms.is_empty(), "{alarms:?}");
    assert!(worst < 0.5, "worst effort RMSE {worst} N*m beside a matching arm");
    let loaded = UrSimOptions { payload: Some(1.0), ..matching };
    let (alarms, worst) = follow_with(&loaded, options, 4.0, None, |_| {});
    let first = alarms
        .iter()
        .find(|(_, k, _)| k == "divergence")
        .unwrap_or_else(|| panic!("no divergence alarm: {alarms:?}, worst effort RMSE {worst}"));
    assert!(first.0 < 1.5, "the alarm came at {} s", first.0);
    let named = served.joints.iter().any(|j| first.2.starts_with(j.as_str()));
    assert!(named, "the alarm names one of the arm's joints: {}", first.2);
}

/// Joints alarm independently: with the shoulder's alarm standing (its effort reads 5 N·m over
/// the twin's from 0.5 s), the base reported 1 rad off from 2.5 s raises an alarm of its own
/// (before, one standing alarm hid every later divergence).
#[test]
fn a_standing_alarm_on_one_joint_hides_no_other() {
    let (alarms, _) = follow_tampered(&UrSimOptions::default(), 4.0, None, |r| {
        if r.time >= 0.5 {
            r.effort[1] += 5.0;
        }
        if r.time >= 2.5 {
            r.q[0] += 1.0;
        }
    });
    let early: Vec<_> = alarms.iter().filter(|(t, _, _)| *t < 2.5).collect();
    assert!(early.len() == 1 && early[0].2.starts_with("shoulder_lift_joint"), "{alarms:?}");
    let base = alarms.iter().find(|(t, k, m)| *t >= 2.5 && k == "divergence" && m.starts_with("shoulder_pan_joint"));
    assert!(base.is_some_and(|(t, _, _)| *t < 3.0), "no alarm for the base: {alarms:?}");
}

/// `monitor` without `--seconds` ends on SIGTERM (as on Ctrl-C) and writes what it followed
/// first; before, a run ended that way wrote nothing.
#[test]
fn the_monitor_writes_what_it_followed_when_terminated() {
    use std::io::BufRead;
    let standin = crate::rtde::Standin::start(0.1);
    let out = std::env::temp_dir().join(format!("twinbots-monitor-sigterm-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let mut child = crate::delivery::twinbots()
        .args(["monitor", "ur5e", "--rtde", &standin.address(), "--out"])
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let (lines, said) = std::sync::mpsc::channel();
    let stdout = child.stdout.take().unwrap();
    let reader = std::thread::spawn(move || {
        for line in std::io::BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = lines.send(line);
        }
    });
    // Wait for it to follow, then a second of reports.
    loop {
        let line = said.recv_timeout(std::time::Duration::from_secs(120)).expect("monitor never started following");
        if line.contains("following") {
            break;
        }
    }
    std::thread::sleep(std::time::Duration::from_secs(1));
    // SAFETY: a signal to our own child, by its pid.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = child.wait().unwrap();
    reader.join().unwrap();
    let printed: Vec<String> = said.try_iter().collect();
    assert!(status.success(), "{status:?}: {printed:?}");
    assert!(printed.iter().any(|l| l.contains("stopped by SIGTERM")), "{printed:?}");
    for file in ["robot.mcap", "twin.mcap", "monitor.json", "divergence.png"] {
        assert!(out.join(file).is_file(), "no {file}: {printed:?}");
    }
    let _ = std::fs::remove_dir_all(&out);
}
