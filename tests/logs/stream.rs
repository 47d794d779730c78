//! Logs read as streams: a replay that reads its log as the twin steps gives the whole-log
//! replay's report and twin, and its memory does not grow with the log's length.

use std::path::Path;
use std::process::Command;

use twinbots_log::mcap_file::FileWriter;
use twinbots_log::{Entry, JointSample, LogStream, Mapping, RobotLog};
use twinbots_sysid::excitation::Excitation;
use twinbots_sysid::replay::replay_stream;
use twinbots_sysid::{Recording, Rig, SensorNoise, compare, perturbed_truth, prepare, record, run};

use crate::cli::scratch;

fn recorded(rig: &Rig, seconds: f64) -> RobotLog {
    let recording = Recording { excitation: Excitation::Multisine, seconds, seed: 11, noise: SensorNoise::default() };
    record(rig, &perturbed_truth(rig), &recording).unwrap()
}

/// The streamed replay (from memory and from an MCAP file) and the whole-log one (`prepare`,
/// `run`, `compare`) agree bit for bit: the report, and the twin's every sample.
#[test]
fn a_streamed_replay_is_the_whole_logs_replay() {
    let rig = Rig::of(&ur5e::robot()).unwrap();
    let log = recorded(&rig, 3.0);
    let params = rig.nominal.clone();
    let prepared = prepare(&rig, &log, "log").unwrap();
    let whole = run(&rig, &prepared.start_positions(&rig, &params), &prepared.program, std::slice::from_ref(&params))
        .pop()
        .unwrap();
    let bias = rig.biases(&params);
    let expected = serde_json::to_value(compare(&rig, &prepared, &whole, &bias, 0.01)).unwrap();
    let samples = whole.samples(rig.dt(), &bias);
    assert!(expected["joints"][1]["position_rmse"].as_f64().unwrap() > 0.0, "{expected}");

    let dir = scratch("stream");
    let file = dir.join("log.mcap");
    twinbots_log::write(&log, &file).unwrap();
    let mapping = Mapping::default();
    let streams = [LogStream::of_log("log".into(), log.clone()).unwrap(), twinbots_log::open(&file, &mapping).unwrap()];
    for mut stream in streams {
        let mut twin: Vec<JointSample> = Vec::new();
        let (report, _) = replay_stream(&rig, &params, &mut stream, 0.01, "twin", |s| {
            twin.push(s);
            Ok(())
        })
        .unwrap();
        let mut report = serde_json::to_value(report).unwrap();
        report["log"] = "log".into();
        assert_eq!(report, expected);
        assert_eq!(twin, samples);
    }
}

/// Writes `log` `times` times over, one after the other, as one MCAP log, a record at a time.
fn tiled(log: &RobotLog, times: usize, path: &Path) {
    let mut out = FileWriter::create(path, &log.meta, &log.joints).unwrap();
    let span = log.duration() + 0.004;
    for k in 0..times {
        let shift = k as f64 * span;
        for mut entry in log.entries() {
            match &mut entry {
                Entry::State(s) => s.time += shift,
                Entry::Command(c) => c.time += shift,
                Entry::Tool(t) => t.time += shift,
            }
            out.write(&entry).unwrap();
        }
    }
    out.finish().unwrap();
}

/// `twinbots replay`'s peak resident memory (KiB) on `log`, as the kernel counted it.
// Waited for by `wait4`, which gives the child's own resource usage; `Child::wait` does not.
#[allow(clippy::zombie_processes)]
fn replay_peak_kib(log: &Path, out: &Path) -> i64 {
    let child = Command::new(env!("CARGO_BIN_EXE_twinbots"))
        .args(["replay", "ur5e", log.to_str().unwrap(), "--out", out.to_str().unwrap()])
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut status = 0;
    // SAFETY: a zeroed rusage is a valid out-parameter; the pid is our own child, waited once.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert!(pid > 0 && libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0, "replay of {} failed", log.display());
    usage.ru_maxrss
}

/// A log ten times as long replays in the same memory: the reader holds a chunk, the replay a
/// second of samples, the figure a bounded envelope. (Read whole, the 200 s log alone is
/// tens of MB more: its file, its samples, their interpolation and the twin's.)
#[test]
fn a_long_log_replays_in_the_memory_of_a_short_one() {
    let rig = Rig::of(&ur5e::robot()).unwrap();
    let log = recorded(&rig, 20.0);
    let dir = scratch("stream-memory");
    let (short, long) = (dir.join("short.mcap"), dir.join("long.mcap"));
    tiled(&log, 1, &short);
    tiled(&log, 10, &long);
    let short_kib = replay_peak_kib(&short, &dir.join("short"));
    let long_kib = replay_peak_kib(&long, &dir.join("long"));
    let sizes = [&short, &long].map(|p| std::fs::metadata(p).unwrap().len() >> 20);
    eprintln!("replay peak RSS: {short_kib} KiB on {} MiB, {long_kib} KiB on {} MiB", sizes[0], sizes[1]);
    assert!(sizes[1] >= 10 * sizes[0].max(1) - 1, "{sizes:?}");
    assert!(long_kib - short_kib < 8 << 10, "{short_kib} KiB -> {long_kib} KiB");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("long").join("replay.json")).unwrap()).unwrap();
    assert!(report["seconds"].as_f64().unwrap() > 199.0, "{report}");
    let twin = twinbots_log::read(&dir.join("long").join("twin.mcap")).unwrap();
    assert_eq!(twin.states.len(), (report["seconds"].as_f64().unwrap() / rig.dt()).round() as usize + 1);
}

/// Commands may stand in the file behind their times (a bag logs a trajectory's points after
/// their stamps) by up to a second and still act at their step, as the whole-log replay has
/// them; further behind, the replay names the command instead of acting late.
#[test]
fn late_commands_act_at_their_step_within_the_lookahead_and_are_named_beyond() {
    let rig = Rig::of(&ur5e::robot()).unwrap();
    let log = recorded(&rig, 3.0);
    let params = rig.nominal.clone();
    let dir = scratch("stream-late");
    let replay = |delay: f64| {
        // Command 40 written after the states up to its time plus `delay`.
        let path = dir.join(format!("late-{delay}.mcap"));
        let mut out = FileWriter::create(&path, &log.meta, &log.joints).unwrap();
        let late = log.commands[40].clone();
        let mut held = Some(late.clone());
        for entry in log.entries() {
            if matches!(&entry, Entry::Command(c) if *c == late) {
                continue;
            }
            if entry.time() > late.time + delay
                && let Some(c) = held.take()
            {
                out.write(&Entry::Command(c)).unwrap();
            }
            out.write(&entry).unwrap();
        }
        out.finish().unwrap();
        let mut stream = twinbots_log::open(&path, &Mapping::default()).unwrap();
        replay_stream(&rig, &params, &mut stream, 0.01, "twin", |_| Ok(())).map(|(report, _)| report)
    };
    let mut on_time = LogStream::of_log("log".into(), log.clone()).unwrap();
    let (expected, _) = replay_stream(&rig, &params, &mut on_time, 0.01, "twin", |_| Ok(())).unwrap();
    let within = replay(0.5).unwrap();
    assert_eq!(serde_json::to_value(&within.joints).unwrap(), serde_json::to_value(&expected.joints).unwrap());
    let err = replay(1.5).unwrap_err().to_string();
    let named = format!("(t = {} s) comes after joint states over 1 s later", log.commands[40].time);
    assert!(err.contains("late-1.5.mcap") && err.contains(&named) && err.contains("at most 1 s behind"), "{err}");
}
