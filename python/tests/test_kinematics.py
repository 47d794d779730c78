"""Kinematics of vendors' arms from their URDFs, against Pinocchio: `twinbots urdf FILE --base B
--tool T --fk q…` prints the tool link's pose in the base link's frame; at 1,000 random
configurations within the joints' limits, its position equals Pinocchio's within 1e-9 m and its
orientation within 1e-9 rad, for the Franka Panda, the UR10 (CB) and the xArm7 as
`example-robot-data` ships them."""

import os
import shutil
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

ROBOTS = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"

ARMS = [
    ("panda_description/urdf/panda.urdf", "panda_link0", "panda_hand_tcp", 7),
    ("ur_description/urdf/ur10_robot.urdf", "base_link", "tool0", 6),
    ("xarm_description/urdf/xarm7.urdf", "link_base", "link_eef", 7),
]


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


def chain_joints(model, base, tool):
    """Pinocchio's joints from the base link's frame to the tool link's, in order from the base."""
    stop = model.frames[model.getFrameId(base)].parentJoint
    joint, joints = model.frames[model.getFrameId(tool)].parentJoint, []
    while joint != stop:
        joints.append(joint)
        joint = model.parents[joint]
    return joints[::-1]


def configurations(model, joints, count, rng):
    """`count` random positions of `joints` within their limits ([-π, π] where unlimited)."""
    lo = np.array([model.lowerPositionLimit[model.joints[j].idx_q] for j in joints])
    hi = np.array([model.upperPositionLimit[model.joints[j].idx_q] for j in joints])
    unlimited = ~np.isfinite(lo) | ~np.isfinite(hi) | (hi - lo > 1e3)
    lo[unlimited], hi[unlimited] = -np.pi, np.pi
    return rng.uniform(lo, hi, size=(count, len(joints)))


def arm(urdf, base, tool, dof):
    """The URDF's path, Pinocchio's model and data of it, and the chain's joints (skips where
    `example-robot-data` lacks the arm)."""
    path = ROBOTS / urdf
    if not path.is_file():
        pytest.skip(f"example-robot-data has no {urdf}")
    model = pin.buildModelFromUrdf(str(path))
    joints = chain_joints(model, base, tool)
    assert len(joints) == dof, [model.names[j] for j in joints]
    return path, model, model.createData(), joints


def full_configuration(model, joints, q):
    """Pinocchio's configuration vector with `joints` at `q`, the rest neutral."""
    full = pin.neutral(model)
    for j, value in zip(joints, q, strict=True):
        joint = model.joints[j]
        if joint.nq == 2:  # continuous: (cos, sin)
            full[joint.idx_q : joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            full[joint.idx_q] = value
    return full


def pinocchio_pose(model, data, joints, q, base, tool):
    full = full_configuration(model, joints, q)
    pin.framesForwardKinematics(model, data, full)
    return data.oMf[model.getFrameId(base)].actInv(data.oMf[model.getFrameId(tool)])


@pytest.mark.parametrize(("urdf", "base", "tool", "dof"), ARMS, ids=[a[0].split("/")[-1] for a in ARMS])
def test_forward_kinematics_equal_pinocchios(urdf, base, tool, dof):
    path, model, data, joints = arm(urdf, base, tool, dof)
    qs = configurations(model, joints, 1000, np.random.default_rng(0))
    args = [f"--fk={','.join(repr(float(v)) for v in q)}" for q in qs]
    out = subprocess.run(
        [twinbots_bin(), "urdf", str(path), "--base", base, "--tool", tool, *args],
        capture_output=True, text=True, timeout=120,
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == len(qs), out.stdout[:500]
    worst_position, worst_angle = 0.0, 0.0
    for q, line in zip(qs, lines, strict=True):
        x, y, z, qx, qy, qz, qw = (float(v) for v in line.split())
        ours = pin.SE3(pin.Quaternion(qw, qx, qy, qz).toRotationMatrix(), np.array([x, y, z]))
        theirs = pinocchio_pose(model, data, joints, q, base, tool)
        worst_position = max(worst_position, np.linalg.norm(ours.translation - theirs.translation))
        worst_angle = max(worst_angle, np.linalg.norm(pin.log3(theirs.rotation.T @ ours.rotation)))
    print(f"{urdf}: worst position {worst_position:.2e} m, orientation {worst_angle:.2e} rad")
    assert worst_position < 1e-9, f"position off by {worst_position:.3e} m"
    assert worst_angle < 1e-9, f"orientation off by {worst_angle:.3e} rad"


def test_a_tool_that_is_not_below_the_base_and_a_wrong_count_are_named():
    path = ROBOTS / "ur_description/urdf/ur10_robot.urdf"
    if not path.is_file():
        pytest.skip("example-robot-data has no UR10")
    run = lambda *a: subprocess.run([twinbots_bin(), "urdf", str(path), *a], capture_output=True, text=True)  # noqa: E731
    out = run("--base", "forearm_link", "--tool", "shoulder_link", "--fk=0")
    assert out.returncode != 0 and "'shoulder_link' is not a descendant of the base link 'forearm_link'" in out.stderr
    out = run("--tool", "tool0", "--fk=0,0")
    assert out.returncode != 0 and "2 values for the 6 movable joints" in out.stderr, out.stderr


@pytest.mark.parametrize("urdf", ["panda_description/urdf/panda.urdf", "ur_description/urdf/ur10_robot.urdf"])
def test_efforts_at_rest_equal_pinocchios_gravity_torques(urdf):
    """`twinbots urdf` stands the arm, its drives holding 0; where each joint came to rest, the
    effort its drive reads equals the gravity torque Pinocchio's RNEA gives there, within 4 % of
    it (a joint that carries little: within 4 % of the largest)."""
    path = ROBOTS / urdf
    if not path.is_file():
        pytest.skip(f"example-robot-data has no {urdf}")
    share = ROBOTS.parent.parent
    out = subprocess.run([twinbots_bin(), "urdf", str(path), "--seconds", "4"], capture_output=True, text=True,
                         env={**os.environ, "ROS_PACKAGE_PATH": str(share)}, timeout=300)
    assert out.returncode == 0, out.stderr
    holding = {}
    for line in out.stdout.splitlines():
        words = line.split()
        if words[:1] == ["holding"]:
            holding[words[1]] = (float(words[3].rstrip(":")), float(words[5]))
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    q = pin.neutral(model)
    for name, (position, _) in holding.items():
        q[model.joints[model.getJointId(name)].idx_q] = position
    tau = pin.rnea(model, data, q, np.zeros(model.nv), np.zeros(model.nv))
    theirs = {name: tau[model.joints[model.getJointId(name)].idx_v] for name in holding}
    largest = max(abs(t) for t in theirs.values())
    assert largest > 1, theirs
    for name, (_, effort) in holding.items():
        diff = abs(effort - theirs[name])
        bound = 0.04 * max(abs(theirs[name]), 0.1 * largest)
        print(f"{name}: effort {effort:.4f}, Pinocchio {theirs[name]:.4f}")
        assert diff <= bound, f"{name}: effort {effort} vs Pinocchio's {theirs[name]}"


@pytest.mark.parametrize(("urdf", "base", "tool", "dof"), ARMS, ids=[a[0].split("/")[-1] for a in ARMS])
def test_inverse_dynamics_equal_pinocchios(urdf, base, tool, dof):
    """`twinbots urdf FILE --tool T --id 'q;qd;qdd'` prints the efforts of the chain's joints
    (recursive Newton–Euler from the URDF's inertials, the links below the tool carried as a load);
    at 200 random states (positions within the limits, speeds and accelerations within ±2) they
    equal Pinocchio's `rnea` within 1e-9 (relative to the largest effort)."""
    path, model, data, joints = arm(urdf, base, tool, dof)
    rng = np.random.default_rng(11)
    qs = configurations(model, joints, 200, rng)
    qds, qdds = rng.uniform(-2, 2, size=qs.shape), rng.uniform(-2, 2, size=qs.shape)

    def listed(v):
        return ",".join(repr(float(x)) for x in v)

    args = [f"--id={listed(q)};{listed(qd)};{listed(qdd)}" for q, qd, qdd in zip(qs, qds, qdds, strict=True)]
    out = subprocess.run([twinbots_bin(), "urdf", str(path), "--base", base, "--tool", tool, *args],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    rows = [list(map(float, line.split())) for line in out.stdout.splitlines()]
    assert len(rows) == len(qs)
    worst = 0.0
    for q, qd, qdd, ours in zip(qs, qds, qdds, rows, strict=True):
        full_q, full_v, full_a = full_configuration(model, joints, q), np.zeros(model.nv), np.zeros(model.nv)
        for k, j in enumerate(joints):
            full_v[model.joints[j].idx_v], full_a[model.joints[j].idx_v] = qd[k], qdd[k]
        tau = pin.rnea(model, data, full_q, full_v, full_a)
        theirs = np.array([tau[model.joints[j].idx_v] for j in joints])
        worst = max(worst, np.max(np.abs(np.array(ours) - theirs)) / max(1.0, np.max(np.abs(theirs))))
    print(f"{urdf}: worst relative difference {worst:.2e}")
    assert worst < 1e-9, f"efforts off by {worst:.3e} (relative)"
