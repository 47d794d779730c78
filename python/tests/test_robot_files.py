"""Arms from robot files alone (`assets/robots/*.toml`: a vendor's URDF from `example-robot-data`
plus a few keys, no Rust): the twin standing at home reads the gravity torques Pinocchio computes
for the pose it holds (within 4 % of the largest, the UR5e twin's bound), and `train`, `eval` and
`export` take a robot file as they take a built-in robot."""

import json
import os
import re
import shutil
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

REPO = Path(__file__).resolve().parents[2]
SHARE = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"
ROBOTS = SHARE / "example-robot-data" / "robots"

# robot file, its URDF inside example-robot-data
ARMS = [
    ("panda", "panda_description/urdf/panda.urdf"),
    ("ur10", "ur_description/urdf/ur10_robot.urdf"),
    ("xarm7", "xarm_description/urdf/xarm7.urdf"),
]

HOLDING = re.compile(r"^\s*holding (\S+) at (\S+): effort (\S+)$")


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


def run(*args, timeout=300):
    """The CLI with `package://example-robot-data/…` found through ROS_PACKAGE_PATH, as a user
    who installed the package would set it."""
    env = dict(os.environ, ROS_PACKAGE_PATH=str(SHARE))
    done = subprocess.run([twinbots_bin(), *args], capture_output=True, text=True, timeout=timeout, env=env, cwd=REPO)
    assert done.returncode == 0, done.stderr + done.stdout
    return done.stdout


@pytest.mark.parametrize("name,urdf", ARMS)
def test_efforts_at_rest_equal_pinocchios_gravity_torques(name, urdf):
    if not (ROBOTS / urdf).is_file():
        pytest.skip(f"example-robot-data has no {urdf}")
    out = run("urdf", f"assets/robots/{name}.toml", "--seconds", "3")
    held = {m[1]: (float(m[2]), float(m[3])) for m in map(HOLDING.match, out.splitlines()) if m}
    model = pin.buildModelFromUrdf(str(ROBOTS / urdf))
    data = model.createData()
    q = pin.neutral(model)
    for joint, (position, _) in held.items():
        q[model.joints[model.getJointId(joint)].idx_q] = position
    gravity = pin.computeGeneralizedGravity(model, data, q)
    arm = [j for j in model.names[1:] if "finger" not in j]
    expected = np.array([gravity[model.joints[model.getJointId(j)].idx_v] for j in arm])
    measured = np.array([held[j][1] for j in arm])
    # Within 4 % of the joint's own torque, or of a tenth of the largest for a joint that carries
    # little (as test_kinematics.py judges a bare URDF standing at zero).
    bound = 0.04 * np.maximum(np.abs(expected), 0.1 * np.max(np.abs(expected)))
    print(dict(zip(arm, zip(measured.round(4), expected.round(4)))))
    assert np.all(np.abs(measured - expected) <= bound), f"{name}: {measured.round(4)} against {expected.round(4)}"


def test_a_robot_file_trains_evaluates_and_exports(tmp_path):
    if not (ROBOTS / ARMS[0][1]).is_file():
        pytest.skip("example-robot-data has no Panda")
    run_dir = tmp_path / "panda"
    out = run("train", "assets/robots/panda.toml", "--timesteps", "1500", "--out", str(run_dir))
    assert "evaluation of the final model, reach" in out, out
    figures = json.loads((run_dir / "eval.json").read_text())
    assert 0.0 <= figures["success_rate"] <= 1.0, figures
    assert "final_error_mm" in json.dumps(figures), figures
    run("eval", str(run_dir), "--episodes", "4")
    onnx = tmp_path / "panda.onnx"
    run("export", str(run_dir), "--onnx", str(onnx))
    assert onnx.stat().st_size > 1000


@pytest.mark.parametrize("name,urdf", [("ur10-cell", ARMS[1][1]), ("panda-cell", ARMS[0][1])])
def test_an_arm_in_its_cell_picks_and_places_with_its_classical_controller(tmp_path, name, urdf):
    """`assets/robots/ur10-cell.toml` and `panda-cell.toml`: the arm on the table of its cell
    (`assets/cells/`) with a vacuum cup at its tool runs the cell program (the reach's classical
    controller between the stations, the controller's straight moves onto the part and into the
    pocket) and places the part; its demonstrations are a LeRobot dataset."""
    if not (ROBOTS / urdf).is_file():
        pytest.skip(f"example-robot-data has no {urdf}")
    dataset = tmp_path / "d"
    out = run("demos", f"assets/robots/{name}.toml", "--task", "pick-place", "--episodes", "8", "--out", str(dataset))
    placed = int(re.search(r"\((\d+) of 8 episodes run met the goal\)", out)[1])
    assert placed >= 7, out
    info = json.loads((dataset / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 8, info


def test_the_ur10_in_its_cell_studies_and_meets_learned_pick_and_place_goals(tmp_path):
    """The UR10 cell beyond its program: the scripted baseline of its learned pick-and-place
    (the UR5e's task over the work area between its fixtures) meets the goals it draws, and a
    cell study of the robot file sweeps its own cell's layouts."""
    if not (ROBOTS / ARMS[1][1]).is_file():
        pytest.skip(f"example-robot-data has no {ARMS[1][1]}")
    dataset = tmp_path / "d"
    out = run("demos", "assets/robots/ur10-cell.toml", "--task", "pick-place-learned", "--episodes", "20",
              "--out", str(dataset))
    met = int(re.search(r"\((\d+) of 20 episodes run met the goal\)", out)[1])
    assert met >= 19, out  # 200 of 200 measured
    study = tmp_path / "study.toml"
    study.write_text("episodes = 1\n"
                     '[[layout]]\nname = "default"\n[[layout]]\nname = "pick-far"\n'
                     "robot = [-0.12, -0.42]\npick = [1.03, 0.62]\n")
    run("study", "assets/robots/ur10-cell.toml", str(study), "--out", str(tmp_path / "s"))
    rows = (tmp_path / "s" / "summary.csv").read_text().splitlines()
    header = rows[0].split(",")
    by_layout = {r.split(",")[header.index("layout")]: dict(zip(header, r.split(","))) for r in rows[1:]}
    assert by_layout["default"]["success_rate"] == "1.0000", rows
    assert (by_layout["pick-far"]["success_rate"], by_layout["pick-far"]["reach_failures"]) == ("0.0000", "1"), rows


def test_a_listing_read_only_in_part_ends_quietly():
    """`twinbots robots --json | head`: a reader that closes the pipe before the listing is
    written ends it with status 0 and no panic (Rust's standard output would panic on EPIPE)."""
    for args in (["robots"], ["robots", "--json"]):
        process = subprocess.Popen([twinbots_bin(), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        process.stdout.close()
        _, stderr = process.communicate(timeout=60)
        assert process.returncode == 0 and b"panicked" not in stderr, (args, stderr)


DATA = REPO.parent / "shared" / "data" / "ur5-real"


@pytest.mark.parametrize("recording", ["Movement_No1", "Movement_No2", "Movement_No3_Acc", "Movement_No4_Acc"])
def test_the_ur5_twin_follows_the_real_arms_targets(tmp_path, recording):
    """`replay assets/robots/ur5.toml RUN --servo`: the UR5 (CB) twin from its robot file, under
    its position servo at the CB's 125 Hz, on the recorded `target_q` of the real UR5 (the
    recordings of ../shared/data/ur5-real): its joints within 2 mrad RMS of the measured ones on
    every held-out run, the fast No3 and No4 among them, whose elbow was commanded 3.2 rad/s, past
    the 3.15 rad/s its URDF rates the drive for (held to the rating, the twin's elbow trailed by
    2.87 mrad RMS)."""
    if not DATA.is_dir():
        pytest.skip(f"{DATA} is not there")
    log = DATA / f"{recording}.csv.gz"
    out = tmp_path / "replay"
    run("replay", "assets/robots/ur5.toml", str(log), "--servo", "--efforts", "target_moment", "--out", str(out))
    report = json.loads((out / "replay.json").read_text())
    rmse = report["servo_position_rmse_rad"]
    assert len(rmse) == 6 and max(rmse) <= 2.0e-3, rmse
    # The drives' own efforts beside the controller's model torques: reported, per joint.
    effort = report["servo_effort_rmse"]
    assert len(effort) == 6 and all(0.0 < e < 1e3 for e in effort), effort


def test_the_computed_torque_twin_commands_the_arms_efforts(tmp_path):
    """`replay ur5.toml RUN --servo computed-torque` on the real UR5's Movement_No1: the twin's
    drives, by torque, command efforts within 4x of what the description's inverse dynamics
    predicts along the measured motion (+0.1 N*m), its joints within 1 mrad; the position servo's
    drives, holding their joints through the constraint solver, are 10x and more off on the elbow
    (44.3 N*m against 1.6 measured 2026-12-07)."""
    if not DATA.is_dir():
        pytest.skip(f"{DATA} is not there")
    log = str(DATA / "Movement_No1.csv.gz")
    reports = {}
    for servo in ["computed-torque", "position"]:
        out = tmp_path / servo
        run("replay", "assets/robots/ur5.toml", log, "--servo", servo, "--efforts", "target_moment", "--out", str(out))
        reports[servo] = json.loads((out / "replay.json").read_text())
    torque, position = reports["computed-torque"], reports["position"]
    assert torque["servo"] == "computed-torque"
    nominal = torque["rmse_nominal"]
    for j, (effort, model) in enumerate(zip(torque["servo_effort_rmse"], nominal)):
        assert effort <= 4.0 * model + 0.1, (j, effort, model)
    assert max(torque["servo_position_rmse_rad"]) <= 1e-3, torque["servo_position_rmse_rad"]
    assert position["servo_effort_rmse"][2] >= 10.0 * nominal[2], position["servo_effort_rmse"]


def test_a_robot_file_arm_records_on_its_test_stand(tmp_path):
    """`record assets/robots/ur10.toml`: a robot file's arm has a test stand as a built-in robot
    does: 3 s of multisine excitation, every physics step's joint states (4 ms) and a speed
    command per control period (8 ms) to each of the file's joints, read back with the `mcap`
    packages."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    log = tmp_path / "ur10.mcap"
    run("record", "assets/robots/ur10.toml", "--seconds", "3", "--out", str(log))
    with open(log, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        states = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/joint_states"])]
    with open(log, "rb") as f:
        commands = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/twinbots/joint_commands"])]
    assert len(states) == 751 and list(states[0].name)[:2] == ["shoulder_pan_joint", "shoulder_lift_joint"]
    assert len(commands) == 375 and all(c["mode"] == ["velocity"] * 6 for c in commands)
    moved = np.ptp(np.array([s.position for s in states]), axis=0)
    assert (moved > 0.05).all(), moved


def test_a_robot_file_arm_is_calibrated_on_its_test_stand(tmp_path):
    """`identify ur10.toml LOG --twin`: a robot file's twin calibrated as a built-in robot's, on
    its test stand, to a log of a stand-in with hidden physics (an 8 ms command delay, a stiffer
    elbow damping and shoulder friction): the delay found within a physics step (4 ms), the
    held-out position error cut by over half; `replay --twin` the held-out log on the
    calibrated stand."""
    truth = tmp_path / "truth.toml"
    truth.write_text("[parameters]\nelbow_joint.damping = 3.0\nshoulder_lift_joint.friction = 2.0\n"
                     "command_delay = 0.008\n")
    robot = "assets/robots/ur10.toml"
    fit, held_out = tmp_path / "fit.mcap", tmp_path / "held_out.mcap"
    run("record", robot, "--truth", str(truth), "--seconds", "10", "--out", str(fit))
    run("record", robot, "--truth", str(truth), "--seconds", "5", "--seed", "2", "--excitation", "chirp",
        "--out", str(held_out))
    out = tmp_path / "cal"
    run("identify", robot, str(fit), "--twin", "--validate", str(held_out), "--generations", "8", "--out", str(out))
    fitted = json.loads((out / "fit.json").read_text())
    delay = next(p for p in fitted["fit"]["parameters"] if p["name"] == "command_delay")
    assert abs(delay["value"] - 0.008) < 0.004, delay
    validation = fitted["validation"]
    assert validation["calibrated"] < 0.5 * validation["nominal"], validation
    replayed = tmp_path / "replay"
    run("replay", robot, str(held_out), "--twin", "--calibration", str(out / "calibration.toml"),
        "--out", str(replayed))
    report = json.loads((replayed / "replay.json").read_text())
    assert abs(report["position_rmse"] - validation["calibrated"]) < 1e-3, (report["position_rmse"], validation)
