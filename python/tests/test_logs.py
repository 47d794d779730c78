"""Robot logs against independent readers and writers: the `mcap` and `mcap-ros2-support`
packages read twinbots' MCAP logs as ROS 2 JointState messages, and a log they write in the
layout docs/logs.md describes replays and identifies."""

import json
import math
import os
import shutil
import subprocess

import pytest

mcap_reader = pytest.importorskip("mcap.reader")
mcap_ros2_reader = pytest.importorskip("mcap_ros2.reader")
mcap_ros2_writer = pytest.importorskip("mcap_ros2.writer")
from mcap.writer import CompressionType  # noqa: E402

UR5E_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]

# sensor_msgs/msg/JointState as a ros2msg schema (what rosbag2 stores), from docs/logs.md.
JOINT_STATE_MSGDEF = """std_msgs/Header header
string[] name
float64[] position
float64[] velocity
float64[] effort
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


def run(*args):
    out = subprocess.run([twinbots_bin(), *args], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_our_mcap_reads_as_ros2_joint_states(tmp_path):
    log = tmp_path / "ur5e.mcap"
    run("record", "ur5e", "--seconds", "1", "--out", str(log))
    messages = list(mcap_ros2_reader.read_ros2_messages(str(log), topics=["/joint_states"]))
    assert len(messages) == 251  # t = 0, then every 4 ms physics step for 1 s
    stamps = []
    for m in messages:
        msg = m.ros_msg
        assert list(msg.name) == UR5E_JOINTS
        assert len(msg.position) == len(msg.velocity) == len(msg.effort) == 6
        stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    assert stamps[-1] == pytest.approx(1.0, abs=1e-6)
    with open(log, "rb") as f:
        reader = mcap_reader.make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        assert meta["twinbots"]["robot"] == "ur5e"
        assert float(meta["twinbots"]["control_period"]) == pytest.approx(0.008)
        f.seek(0)
        commands = [json.loads(msg.data) for _, ch, msg in reader.iter_messages(topics=["/twinbots/joint_commands"])]
    assert len(commands) == 125  # every 8 ms
    assert commands[0]["name"] == UR5E_JOINTS and set(commands[0]["mode"]) == {"velocity"}


def test_log_written_by_the_mcap_packages_replays_and_identifies(tmp_path):
    # The robot's data: a stand-in UR5e with a 12 ms command delay, read back as plain numbers.
    truth = tmp_path / "truth.toml"
    truth.write_text("[parameters]\ncommand_delay = 0.012\n")
    source = tmp_path / "source.csv"
    run("record", "ur5e", "--truth", str(truth), "--seconds", "3", "--seed", "4", "--out", str(source))
    rows = [line for line in source.read_text().splitlines() if line and not line.startswith("#")]
    header = rows[0].split(",")
    col = {name: i for i, name in enumerate(header)}

    # Written as a ROS 2 driver's recording would be: absolute stamps, uncompressed chunks.
    start = 1_700_000_000
    log = tmp_path / "from_python.mcap"
    with open(log, "wb") as f:
        writer = mcap_ros2_writer.Writer(f, compression=CompressionType.NONE)
        schema = writer.register_msgdef("sensor_msgs/msg/JointState", JOINT_STATE_MSGDEF)
        # The commands channel is JSON (docs/logs.md); mcap_ros2's writer writes ROS 2 messages
        # only, so the JSON channel goes through the mcap writer underneath it.
        raw = writer._writer
        command_schema = raw.register_schema(name="twinbots/JointCommand", encoding="jsonschema", data=b"{}")
        commands = raw.register_channel(topic="/twinbots/joint_commands", message_encoding="json",
                                        schema_id=command_schema)
        writer.add_metadata("twinbots", {"robot": "ur5e", "source": "mcap-ros2-support test"})
        for seq, line in enumerate(rows[1:]):
            cells = line.split(",")
            t = float(cells[0])
            ns = int(round((start + t) * 1e9))
            if cells[col["elbow_joint.position"]]:
                writer.write_message(
                    "/joint_states",
                    schema,
                    {
                        "header": {
                            "stamp": {"sec": start + int(t), "nanosec": int(round((t - int(t)) * 1e9))},
                            "frame_id": "",
                        },
                        "name": UR5E_JOINTS,
                        "position": [float(cells[col[f"{j}.position"]]) for j in UR5E_JOINTS],
                        "velocity": [float(cells[col[f"{j}.velocity"]]) for j in UR5E_JOINTS],
                        "effort": [float(cells[col[f"{j}.effort"]]) for j in UR5E_JOINTS],
                    },
                    log_time=ns,
                    sequence=seq,
                )
            if cells[col["elbow_joint.command"]]:
                message = {
                    "time": start + t,
                    "name": UR5E_JOINTS,
                    "mode": ["velocity"] * 6,
                    "value": [float(cells[col[f"{j}.command"]]) for j in UR5E_JOINTS],
                }
                raw.add_message(channel_id=commands, log_time=ns, publish_time=ns, sequence=seq,
                                data=json.dumps(message).encode())
        writer.finish()

    replay = run("replay", "ur5e", str(log), "--out", str(tmp_path / "replay"))
    assert "elbow_joint" in replay
    out = tmp_path / "cal"
    run("identify", "ur5e", str(log), "--params", "command_delay", "--generations", "6", "--out", str(out))
    text = (out / "calibration.toml").read_text()
    delay = next(float(line.split("=")[1].split("#")[0])
                 for line in text.splitlines() if line.startswith('"command_delay"'))
    assert delay == pytest.approx(0.012, abs=0.004)


def test_make_vec_runs_a_calibrated_twin(tmp_path):
    import numpy as np

    import twinbots

    slow = tmp_path / "slow.toml"
    slow.write_text("[parameters]\ncommand_delay = 0.03\n")
    actions = np.full((1, 5), 0.8, dtype=np.float32)
    finals = []
    for calibration in (None, slow):
        env = twinbots.make_vec("ur5e", 1, seed=3, calibration=calibration)
        env.reset(seed=3)
        for _ in range(3):
            obs = env.step(actions)[0]
        finals.append(obs)
        env.close()
    # The same seed and actions: only the 30 ms command delay tells the runs apart.
    assert not np.allclose(finals[0], finals[1])
    bad = tmp_path / "bad.toml"
    bad.write_text("[parameters]\nelbow_joint.stiffness = 1.0\n")
    with pytest.raises(ValueError, match="unknown parameter 'elbow_joint.stiffness'"):
        twinbots.make_vec("ur5e", 1, calibration=bad)
    # Randomization around a fit needs the fit's spread; with it, each reset draws anew.
    with pytest.raises(ValueError, match=r"calibration_spread = 3 needs a calibration with a \[spread\]"):
        twinbots.make_vec("ur5e", 1, calibration=slow, config={"calibration_spread": 3.0})
    slow.write_text("[parameters]\ncommand_delay = 0.03\n[spread]\ncommand_delay = 0.01\n")
    env = twinbots.make_vec("ur5e", 1, seed=3, calibration=slow, config={"calibration_spread": 3.0})
    drawn = []
    for _ in range(2):
        env.reset(seed=3)
        for _ in range(3):
            obs = env.step(actions)[0]
        drawn.append(obs)
    env.close()
    assert np.array_equal(drawn[0], drawn[1]), "a seed fixes the draw"
    assert not np.allclose(drawn[0], finals[1]), "the same start, another delay than the fitted one"


def test_make_vec_logs_arena_zero(tmp_path):
    import numpy as np

    import twinbots

    log = tmp_path / "env.mcap"
    env = twinbots.make_vec("cartpole", 2, seed=5, log=log)
    env.reset(seed=5)
    steps = 0
    for _ in range(40):
        env.step(np.zeros(env.action_space.shape, dtype=env.action_space.dtype))
        steps += 1
    env.close()
    states = [m.ros_msg for m in mcap_ros2_reader.read_ros2_messages(str(log), topics=["/joint_states"])]
    # The running episode (or the last one that ended) of arena 0, every control step.
    assert 2 <= len(states) <= steps + 1
    assert "pole_joint" in states[0].name
    with pytest.raises(ValueError, match=r"\.mcap or a \.csv"):
        twinbots.make_vec("cartpole", 1, log=tmp_path / "env.txt")


def test_every_constructor_takes_the_same_twin_arguments(tmp_path):
    """`make`, `make_vec` and SB3's `make_vec_env` take the twin's arguments under the same names
    (the classes hold them; the functions forward), and each runs the calibrated twin."""
    import inspect

    import numpy as np

    import twinbots
    from twinbots.sb3 import TwinbotsSB3VecEnv, make_vec_env

    twin = {"seed", "task", "pattern", "config", "render_mode", "calibration", "log"}
    for cls in (twinbots.TwinbotsEnv, twinbots.TwinbotsVectorEnv, TwinbotsSB3VecEnv):
        assert twin <= set(inspect.signature(cls.__init__).parameters), cls
    slow = tmp_path / "slow.toml"
    slow.write_text("[parameters]\ncommand_delay = 0.03\n")
    action = np.full(5, 0.8, dtype=np.float32)

    def single(calibration):
        env = twinbots.make("ur5e", seed=3, calibration=calibration)
        env.reset(seed=3)
        for _ in range(3):
            obs = env.step(action)[0]
        env.close()
        return obs

    def sb3(calibration):
        env = make_vec_env("ur5e", 1, seed=3, calibration=calibration)
        env.reset()
        for _ in range(3):
            obs = env.step(action[None])[0]
        env.close()
        return obs

    for run in (single, sb3):
        assert not np.allclose(run(None), run(slow)), run.__name__


def test_looks_jsonl_reads_as_docs_randomization_md_describes(tmp_path):
    """`capture --config` records each look; read with Python's json, key by key as documented."""
    config = tmp_path / "run.toml"
    config.write_text("[randomization.visual]\ndistractors = [1, 2]\nspecular = [0.0, 0.5]\n")
    out = subprocess.run(
        [twinbots_bin(), "capture", "ur5e", "--frames", "2", "--every", "30", "--size", "64x48",
         "--config", str(config), "--out", str(tmp_path / "frames")],
        capture_output=True, text=True,
    )
    if out.returncode != 0 and "no graphics adapter" in out.stderr:
        if os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0"):
            raise AssertionError(out.stderr)
        pytest.skip("no graphics adapter here")
    assert out.returncode == 0, out.stderr
    lines = (tmp_path / "frames" / "looks.jsonl").read_text().splitlines()
    records = [json.loads(line) for line in lines]
    assert records[0]["frame"] == 0 and all(isinstance(r["frame"], int) for r in records)
    look = records[0]["look"]
    assert set(look) == {"lights", "ambient", "camera", "surfaces", "distractors"}
    assert 1 <= len(look["lights"]) <= 3
    for light in look["lights"]:
        assert len(light["direction"]) == 3 and light["direction"][2] < 0  # travelling down
        assert all(0.7 <= c <= 1.0 for c in light["color"]) and 0.3 <= light["intensity"] <= 0.9
    assert len(look["ambient"]) == 3 and 0.15 <= look["ambient"][0] <= 0.6
    camera = look["camera"]
    assert all(abs(d) <= 0.01 for d in camera["offset"]) and all(abs(r) <= 0.087 for r in camera["rotation"])
    assert abs(camera["fov"]) <= math.radians(5)
    assert "floor" in look["surfaces"] and "static/0" in look["surfaces"] and "shoulder_link/0" in look["surfaces"]
    for surface in look["surfaces"].values():
        assert all(0 <= c <= 1 for c in surface["color"]) and 0 <= surface["specular"] <= 0.5
        assert surface["texture"]["kind"] in ("plain", "checker", "noise", "gradient")
    assert 1 <= len(look["distractors"]) <= 2
    for box in look["distractors"]:
        assert all(0.015 <= h <= 0.05 for h in box["half_extents"]) and box["centre"][2] > 0
    frames = sorted((tmp_path / "frames").glob("frame_*.png"))
    assert len(frames) == 3 and all(f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in frames)
