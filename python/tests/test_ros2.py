"""`twinbots ros2`, the twin as a ROS 2 robot, met by a DDS peer that is not twinbots': Eclipse
Cyclone DDS (the `cyclonedds` package, the middleware ROS 2 ships as rmw_cyclonedds_cpp) with
the ROS 2 message types written here from their .msg files and rmw's naming (topic
`rt/joint_states`, type `sensor_msgs::msg::dds_::JointState_`), as docs/ros2.md tells a
user to. Discovery runs over loopback (unicast peers), so no multicast or network is needed."""

import json
import math
import os
import random
import shutil
import subprocess
import sysconfig
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

cyclonedds = pytest.importorskip("cyclonedds")
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import Domain, DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import float64, int32, sequence, uint32  # noqa: E402
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
# Where example-robot-data puts its robots' descriptions (`package://example-robot-data/…`).
SHARE = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Duration(IdlStruct, typename="builtin_interfaces::msg::dds_::Duration_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str
    size: uint32
    stride: uint32


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension]
    data_offset: uint32


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout
    data: sequence[float64]


@dataclass
class JointTrajectoryPoint(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectoryPoint_"):
    positions: sequence[float64]
    velocities: sequence[float64]
    accelerations: sequence[float64]
    effort: sequence[float64]
    time_from_start: Duration


@dataclass
class JointTrajectory(IdlStruct, typename="trajectory_msgs::msg::dds_::JointTrajectory_"):
    header: Header
    joint_names: sequence[str]
    points: sequence[JointTrajectoryPoint]


UR5E_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
               "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]

# Cyclone on loopback only, finding peers by unicast (no multicast): ROS 2's localhost setup.
LOOPBACK = """<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/>
</Interfaces><AllowMulticast>false</AllowMulticast></General><Discovery>
<ParticipantIndex>auto</ParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>
</Discovery></Domain></CycloneDDS>"""

RELIABLE = Qos(Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.History.KeepLast(10))


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


class Twin:
    """`twinbots ros2 ur5e` on its own DDS domain, its output collected."""

    def __init__(self):
        # A domain of its own: other DDS traffic on this machine stays out of the test.
        self.domain = random.Random().randrange(100, 230)
        self.process = subprocess.Popen(
            [twinbots_bin(), "ros2", "ur5e", "--domain", str(self.domain), "--seconds", "90"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        self.lines = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line)

    def output(self):
        return "".join(self.lines)

    def close(self):
        self.process.kill()
        self.process.wait()


class Peer:
    def __init__(self, domain):
        self.domain = Domain(domain, LOOPBACK)
        self.dp = DomainParticipant(domain)

    def reader(self, topic, kind):
        return DataReader(self.dp, Topic(self.dp, topic, kind), qos=RELIABLE)

    def writer(self, topic, kind):
        return DataWriter(self.dp, Topic(self.dp, topic, kind), qos=RELIABLE)


def latest(reader, seconds, until=lambda m: True):
    """The newest sample within `seconds` for which `until` holds (None if none)."""
    deadline = time.time() + seconds
    while time.time() < deadline:
        samples = reader.take(N=100)
        for s in reversed(samples):
            if until(s):
                return s
        time.sleep(0.02)
    return None


@pytest.fixture
def twin():
    t = Twin()
    yield t
    t.close()


def close_to(state, target, tolerance):
    return all(abs(q - t) < tolerance for q, t in zip(state.position, target))


def test_a_cyclonedds_peer_reads_joint_states_and_frames_and_moves_the_twin(twin):
    peer = Peer(twin.domain)
    states = peer.reader("rt/joint_states", JointState)
    frames = peer.reader("rt/tf", TFMessage)
    forward = peer.writer("rt/forward_position_controller/commands", Float64MultiArray)
    trajectory = peer.writer("rt/joint_trajectory_controller/joint_trajectory", JointTrajectory)

    first = latest(states, 20)
    assert first is not None, f"no joint states within 20 s\n{twin.output()}"
    assert list(first.name) == UR5E_JOINTS
    assert len(first.position) == len(first.velocity) == len(first.effort) == 6
    assert all(math.isfinite(v) for v in first.position + first.velocity + first.effort)
    stamp = first.header.stamp.sec + first.header.stamp.nanosec * 1e-9
    assert abs(stamp - time.time()) < 5.0, "stamps are the wall clock"
    # Holding where it started: at rest, the drives carrying the arm against gravity.
    rest = latest(states, 5)
    assert max(abs(v) for v in rest.velocity) < 0.05, rest.velocity
    assert abs(rest.effort[1]) > 1.0, "the shoulder lift holds the arm up"

    # /tf: every joint's child link in its parent's, the base where it stands in the cell.
    tf = latest(frames, 10)
    assert tf is not None, f"no /tf\n{twin.output()}"
    pairs = {(t.header.frame_id, t.child_frame_id) for t in tf.transforms}
    assert ("base_link", "shoulder_link") in pairs and ("wrist_2_link", "wrist_3_link") in pairs, pairs
    assert ("world", "base_link") in pairs, pairs
    # The fixed frames on /tf_static, kept for a subscriber that comes late (transient local).
    fixed = DataReader(peer.dp, Topic(peer.dp, "rt/tf_static", TFMessage), qos=Qos(
        Policy.Reliability.Reliable(max_blocking_time=100_000_000), Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1)))
    tf_static = latest(fixed, 10)
    assert tf_static is not None, f"no /tf_static\n{twin.output()}"
    assert ("wrist_3_link", "tool0") in {(t.header.frame_id, t.child_frame_id) for t in tf_static.transforms}

    # A forward position command moves every joint there.
    start = list(rest.position)
    target = [a + d for a, d in zip(start, [0.3, -0.2, 0.25, 0.2, 0.3, -0.4])]
    reached = None
    deadline = time.time() + 15
    while reached is None and time.time() < deadline:
        forward.write(Float64MultiArray(MultiArrayLayout([], 0), target))
        reached = latest(states, 0.5, lambda s: close_to(s, target, 0.01))
    assert reached is not None, f"the twin did not reach {target}\n{twin.output()}"
    # ... and /tf agrees with /joint_states: the pan joint turns about the base's z axis.
    def pan(m):
        return next((t.transform.rotation for t in m.transforms if t.child_frame_id == "shoulder_link"), None)
    turned = latest(frames, 5, lambda m: pan(m) is not None)
    r = pan(turned)
    assert abs(r.z - math.sin(target[0] / 2)) < 0.01 and abs(r.w - math.cos(target[0] / 2)) < 0.01, r
    assert abs(r.x) < 1e-6 and abs(r.y) < 1e-6, r

    # A joint trajectory (two joints, named out of order) is followed to its last point;
    # the others hold.
    goal = {"elbow_joint": target[2] - 0.4, "shoulder_pan_joint": target[0] - 0.5}
    message = JointTrajectory(
        Header(Time(0, 0), ""), list(goal),
        [JointTrajectoryPoint([target[2] - 0.2, target[0] - 0.25], [], [], [], Duration(1, 0)),
         JointTrajectoryPoint(list(goal.values()), [], [], [], Duration(2, 0))])
    trajectory.write(message)
    expected = list(target)
    expected[0], expected[2] = goal["shoulder_pan_joint"], goal["elbow_joint"]
    done = latest(states, 15, lambda s: close_to(s, expected, 0.01))
    assert done is not None, f"the twin did not follow the trajectory to {expected}\n{twin.output()}"

    # A malformed command (5 values for 6 joints) is refused with a reason; the twin serves on.
    forward.write(Float64MultiArray(MultiArrayLayout([], 0), [0.0] * 5))
    deadline = time.time() + 10
    while "command refused: 5 values for 6 joints" not in twin.output() and time.time() < deadline:
        time.sleep(0.1)
    assert "command refused: 5 values for 6 joints (shoulder_pan_joint" in twin.output(), twin.output()
    still = latest(states, 5)
    assert still is not None and close_to(still, expected, 0.01)
    assert twin.process.poll() is None


def follow_with_monitor(tmp_path, robot_args, robot="ur5e", monitor_args=()):
    """`twinbots ros2 ROBOT ROBOT_ARGS` as the robot (500 Hz states, as ur_robot_driver), and
    `twinbots monitor ROBOT --ros2` following it for 8 s of its clock while the peer moves the
    arm through its forward velocity controller. Returns monitor.json and the monitor's output.
    A robot file's `package://` URDF is found through ROS_PACKAGE_PATH, as a user sets it."""
    domain = random.Random().randrange(100, 230)
    env = dict(os.environ, ROS_PACKAGE_PATH=str(SHARE))
    robot_process = subprocess.Popen(
        [twinbots_bin(), "ros2", robot, "--domain", str(domain), "--rate", "500", "--seconds", "60", *robot_args],
        stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT, env=env, cwd=REPO)
    out = tmp_path / "monitor"
    monitor = subprocess.Popen(
        [twinbots_bin(), "monitor", robot, "--ros2", "--domain", str(domain), "--seconds", "8", "--out", str(out),
         *monitor_args],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=REPO)
    lines = []
    threading.Thread(target=lambda: lines.extend(monitor.stdout), daemon=True).start()
    try:
        peer = Peer(domain)
        velocity = peer.writer("rt/forward_velocity_controller/commands", Float64MultiArray)
        deadline = time.time() + 30
        while not any("following" in line for line in lines) and time.time() < deadline:
            time.sleep(0.05)
        assert any("following" in line for line in lines), "".join(lines)
        # The monitor's twin settles and warms up (1.5 s of the robot's clock), then the arm
        # moves: a smooth out-and-back of three joints over 3 s, sent at 100 Hz, then rest.
        time.sleep(2.0)
        start = time.time()
        while (t := time.time() - start) < 3.0:
            s = math.sin(2 * math.pi * t / 3.0)
            velocity.write(Float64MultiArray(MultiArrayLayout([], 0), [0.3 * s, -0.2 * s, 0.3 * s, 0.0, 0.0, 0.0]))
            time.sleep(0.01)
        for _ in range(5):
            velocity.write(Float64MultiArray(MultiArrayLayout([], 0), [0.0] * 6))
            time.sleep(0.01)
        assert monitor.wait(timeout=60) == 0, "".join(lines)
    finally:
        monitor.kill()
        robot_process.kill()
        robot_process.wait()
    return json.loads((out / "monitor.json").read_text()), "".join(lines), out


def test_the_monitor_follows_a_ros2_robot_and_stays_quiet_when_it_matches(tmp_path):
    report, output, out = follow_with_monitor(tmp_path, [])
    assert report["alarms"] == [], output
    assert report["reports"] > 2500, output  # 500 Hz for 8 s, some lost on a busy machine
    assert len(report["motions"]) >= 1 and report["motions"][0]["duration_s"] > 2.0, report["motions"]
    assert max(report["worst_rmse"]) < 0.005, report["worst_rmse"]
    assert (out / "robot.mcap").stat().st_size > 0 and (out / "divergence.png").stat().st_size > 0


def test_the_monitor_follows_a_robot_file_arm_on_ros2_by_its_joint_names(tmp_path):
    """The UR10 of `assets/robots/ur10.toml` (example-robot-data's URDF) on ROS 2: its joint
    states found by the robot file's joint names, followed as the UR5e's are (at the effort
    threshold of a heavier arm: the UR5e's 1.5 N·m is the start of the UR10's elbow motion, as
    the RTDE test found)."""
    if not (SHARE / "example-robot-data/robots/ur_description/urdf/ur10_robot.urdf").is_file():
        pytest.skip("example-robot-data is not installed")
    report, output, _ = follow_with_monitor(
        tmp_path, [], robot="assets/robots/ur10.toml", monitor_args=["--effort-threshold", "5"])
    assert report["alarms"] == [], output
    # The UR10's twin steps every 4 ms: a state a step, whatever the rate asked.
    assert report["reports"] > 1000, output
    assert len(report["motions"]) >= 1 and report["motions"][0]["duration_s"] > 2.0, report["motions"]
    assert max(report["worst_rmse"]) < 0.005, report["worst_rmse"]


def test_the_monitor_notices_an_unmodelled_payload_on_a_ros2_robot(tmp_path):
    report, output, _ = follow_with_monitor(tmp_path, ["--payload", "1.0"])
    divergence = [a for a in report["alarms"] if a["kind"] == "divergence"]
    assert divergence, output
    motion = report["motions"][0]["start"] if report["motions"] else float("inf")
    assert divergence[0]["time"] <= motion + 1.0, (divergence[0], report["motions"])
