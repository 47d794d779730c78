"""A robot whose links are meshes made by another tool — trimesh's OBJ and binary glTF (GLB)
exporters — checked with `twinbots urdf`: the meshes are found through `package://` (the URDF's
own package, or TWINBOTS_PACKAGE_PATH) and relative paths, loaded (a link with a mass and no
inertia takes its mesh's), simulated standing and rendered; a missing mesh, a mesh with no
triangles and an unknown URI scheme are errors naming the file and the link."""

import os
import re
import shutil
import subprocess

import pytest

trimesh = pytest.importorskip("trimesh")

URDF = """<robot name="demo">
  <link name="base_link">
    <inertial><mass value="4"/><inertia ixx="0.03" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="0.06"/></inertial>
    <visual><geometry><mesh filename="{base}"/></geometry></visual>
    <collision><geometry><mesh filename="{base}"/></geometry></collision>
  </link>
  <link name="arm_link">
    <inertial><mass value="0.5"/></inertial>
    <visual><origin xyz="0 0 0.25"/><geometry><mesh filename="{arm}" scale="1 1 1"/></geometry></visual>
    <collision><origin xyz="0 0 0.25"/><geometry><mesh filename="{arm}"/></geometry></collision>
  </link>
  <joint name="turn" type="revolute">
    <parent link="base_link"/><child link="arm_link"/><origin xyz="0 0 0.05"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="20" velocity="2"/>
  </joint>
</robot>
"""


def twinbots_bin():
    binary = os.environ.get("TWINBOTS_BIN") or shutil.which("twinbots")
    if not binary:
        pytest.skip("no twinbots CLI (set TWINBOTS_BIN)")
    return binary


def package(tmp_path):
    """demo_description/{meshes,urdf} as a ROS package lays them out, meshes by trimesh."""
    root = tmp_path / "share" / "demo_description"
    (root / "meshes").mkdir(parents=True)
    (root / "urdf").mkdir()
    trimesh.creation.box(extents=[0.3, 0.3, 0.1]).export(root / "meshes" / "base.glb")
    trimesh.creation.cylinder(radius=0.04, height=0.5).export(root / "meshes" / "arm.obj")
    return root


def check(urdf, *args, env=None):
    return subprocess.run([twinbots_bin(), "urdf", str(urdf), *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=120)


def test_obj_and_glb_meshes_load_stand_and_render(tmp_path):
    root = package(tmp_path)
    urdf = root / "urdf" / "demo.urdf"
    urdf.write_text(URDF.format(base="package://demo_description/meshes/base.glb", arm="../meshes/arm.obj"))
    png = tmp_path / "demo.png"
    done = check(urdf, "--png", str(png))
    require_adapter = os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0")
    if done.returncode != 0 and "adapter" in done.stderr and not require_adapter:
        pytest.skip(f"no graphics adapter here: {done.stderr}")
    assert done.returncode == 0, done.stderr
    out = done.stdout
    assert "robot 'demo', 2 links, 1 joints (1 movable, 1 with motors), 4.500 kg" in out, out
    assert "arm_link (0.500 kg" in out and "1 collision, 1 visual" in out, out
    # The arm gives its mass only: its inertia is its mesh's as a uniform solid (a 0.5 kg
    # cylinder, r 4 cm, 50 cm: m(3r^2 + h^2)/12 across, m r^2/2 along; trimesh's is faceted).
    line = next(line for line in out.splitlines() if "arm_link (" in line)
    assert "from the collision geometry" in line, line
    ixx, iyy, izz = (float(v) for v in re.search(r"inertia diag (\S+) (\S+) (\S+)", line).groups())
    across, along = 0.5 * (3 * 0.04**2 + 0.5**2) / 12, 0.5 * 0.04**2 / 2
    assert abs(ixx - across) < 0.03 * across and abs(iyy - across) < 0.03 * across, line
    assert abs(izz - along) < 0.1 * along, line
    assert "turn (Revolute, range [-3.000, 3.000], motor: effort 20 velocity 2) -> arm_link" in out, out
    assert "no warnings" in out, out
    assert png.stat().st_size > 1000
    import numpy as np  # noqa: PLC0415
    from PIL import Image  # noqa: PLC0415 (pillow comes with SB3's matplotlib)

    pixels = np.asarray(Image.open(png).convert("RGB")).reshape(-1, 3).astype(int)
    # The meshes have no material: neutral grey, unlike the greenish floor and the blue sky.
    grey = (pixels[:, 0] == pixels[:, 1]) & (pixels[:, 1] == pixels[:, 2])
    assert grey.mean() > 0.05, f"the robot fills {grey.mean():.1%} of the picture"

    # The same robot outside its package: package:// found through TWINBOTS_PACKAGE_PATH.
    elsewhere = tmp_path / "elsewhere.urdf"
    elsewhere.write_text(URDF.format(base="package://demo_description/meshes/base.glb",
                                     arm="package://demo_description/meshes/arm.obj"))
    assert check(elsewhere).returncode != 0
    done = check(elsewhere, env={"TWINBOTS_PACKAGE_PATH": str(tmp_path / "share")})
    assert done.returncode == 0, done.stderr
    assert "arm_link (0.500 kg" in done.stdout


@pytest.mark.parametrize("arm, expected", [
    ("../meshes/missing.obj", "mesh '../meshes/missing.obj': not found at"),
    ("../meshes/empty.obj", "empty.obj holds no triangles"),
    ("https://example.com/arm.obj", "unknown URI scheme 'https://'"),
])
def test_bad_meshes_name_the_file_and_the_link(tmp_path, arm, expected):
    root = package(tmp_path)
    (root / "meshes" / "empty.obj").write_text("v 0 0 0\nv 1 0 0\n")
    urdf = root / "urdf" / "demo.urdf"
    urdf.write_text(URDF.format(base="package://demo_description/meshes/base.glb", arm=arm))
    done = check(urdf)
    assert done.returncode != 0
    assert str(urdf) in done.stderr and '<link name="arm_link">' in done.stderr and expected in done.stderr, done.stderr


def test_a_vendors_collada_visuals_load_and_render(tmp_path):
    """The UR10 as `example-robot-data` ships it: Collada visuals, STL collisions, found through
    `package://example-robot-data/...` and ROS_PACKAGE_PATH."""
    import sysconfig  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    share = Path(sysconfig.get_paths()["purelib"]) / "cmeel.prefix" / "share"
    urdf = share / "example-robot-data" / "robots" / "ur_description" / "urdf" / "ur10_robot.urdf"
    if not urdf.is_file():
        pytest.skip("example-robot-data is not installed")
    png = tmp_path / "ur10.png"
    done = check(urdf, "--png", str(png), env={"ROS_PACKAGE_PATH": str(share)})
    require_adapter = os.environ.get("TWINBOTS_REQUIRE_ADAPTER", "0") not in ("", "0")
    if done.returncode != 0 and "adapter" in done.stderr and not require_adapter:
        pytest.skip(f"no graphics adapter here: {done.stderr}")
    assert done.returncode == 0, done.stderr
    assert "(6 movable, 6 with motors)" in done.stdout, done.stdout
    assert "3 visual" in done.stdout or "1 visual" in done.stdout, done.stdout
    import numpy as np  # noqa: PLC0415
    from PIL import Image  # noqa: PLC0415

    pixels = np.asarray(Image.open(png).convert("RGB")).reshape(-1, 3).astype(int)
    grey = (pixels[:, 0] == pixels[:, 1]) & (pixels[:, 1] == pixels[:, 2])
    # At its zero pose the UR10 lies stretched out at its shoulder's height, its far links low
    # over the floor: 1.6 % of the picture (2026-12-06); an arm without its visuals leaves none.
    assert grey.mean() > 0.01, f"the arm fills {grey.mean():.1%} of the picture"
