"""Blender reads mocapdb's BVH as mocapdb means it, and mocapdb reads Blender's export as Blender
means it (skipped without Blender: the bpy wheel in $MOCAPDB_BPY_PYTHON, or the blender program)."""
import sys
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.formats.bvh import write_bvh
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import PELVIS, rest_positions_m, retarget

from .conftest import MISSING, ROOT

sys.path.insert(0, str(ROOT / "tools"))
from blender_check import blender_available  # noqa: E402

pytestmark = pytest.mark.skipif(not blender_available(),
                                reason=f"{MISSING}Blender (the bpy wheel in $MOCAPDB_BPY_PYTHON)")


def test_blender_imports_universal_bvh_with_the_same_joint_positions(tmp_path):
    from blender_check import compare

    rng = np.random.default_rng(0)
    points = rest_positions_m() + rng.normal(scale=0.05, size=(20, 15, 3)) + [0.3, 1.0, -2.0]
    quats, pos = retarget(points)
    write_bvh(tmp_path / "track.bvh", motion_bvh(Motion(quats, pos[:, PELVIS], 30.0)))
    assert compare(tmp_path / "track.bvh", [0, 7, 19]) < 1e-5  # metres


def test_blender_imports_the_humanoid_rig_on_its_floor(tmp_path):
    from blender_check import blender_pose, compare

    from mocapdb.core.motion_ops import on_floor

    rng = np.random.default_rng(1)
    points = rest_positions_m() + rng.normal(scale=0.05, size=(12, 15, 3)) + [0.3, 1.0, -3.0]
    quats, pos = retarget(points)
    motion = replace(on_floor(Motion(quats, pos[:, PELVIS], 30.0, "view")), scale=1.1)
    write_bvh(tmp_path / "humanoid.bvh", motion_bvh(motion, "cm", rig="humanoid"))
    assert compare(tmp_path / "humanoid.bvh", [0, 5, 11]) < 1e-3  # centimetres
    bones = blender_pose(tmp_path / "humanoid.bvh", [0])["bones"]
    assert {"Hips", "Spine", "Neck", "Head", "LeftHand", "RightFoot", "LeftToeBase", "RightShoulder"} <= set(bones)


def test_blender_turns_the_humanoid_feet_and_hands(tmp_path):
    """Feet and hands turned by their end rotations: Blender puts the toes and hand ends where mocapdb
    does, and the turned foot's toe bone (along the foot, across the turn's axis) points 40° from
    where it points unturned."""
    from blender_check import blender_pose, compare

    rng = np.random.default_rng(3)
    quats, pos = retarget(rest_positions_m() + rng.normal(scale=0.03, size=(6, 15, 3)) + [0.3, 1.0, -3.0])
    half = np.radians(40.0) / 2
    end_quats = np.tile([1.0, 0.0, 0.0, 0.0], (6, 5, 1))
    end_quats[:, 0] = [np.cos(half), 0.0, np.sin(half), 0.0]   # right foot: 40° about its up
    end_quats[:, 2] = [np.cos(half), np.sin(half), 0.0, 0.0]   # right hand
    for name, ends in (("still", None), ("turned", end_quats)):
        write_bvh(tmp_path / f"{name}.bvh", motion_bvh(Motion(quats, pos[:, PELVIS], 30.0, end_rotations=ends),
                                                       "cm", rig="humanoid"))
    assert compare(tmp_path / "turned.bvh", [0, 5]) < 1e-3  # centimetres
    toe = {name: np.subtract(*blender_pose(tmp_path / f"{name}.bvh", [0])["bones"]["RightToeBase"]["0"][::-1])
           for name in ("still", "turned")}
    cosine = toe["still"] @ toe["turned"] / np.linalg.norm(toe["still"]) / np.linalg.norm(toe["turned"])
    assert np.degrees(np.arccos(cosine)) == pytest.approx(40.0, abs=0.1)


def test_blender_imports_the_humanoid_fingers_where_mocapdb_puts_them(tmp_path):
    """The humanoid rig's 30 finger bones, curled and spread: Blender has every one, each bone's head where
    mocapdb's forward kinematics puts its joint."""
    from blender_check import blender_pose, compare

    from mocapdb.core.hand_rig import FINGER_JOINTS, RELAXED_DEG
    from mocapdb.runtime.hand_pose import finger_quaternions

    rng = np.random.default_rng(5)
    quats, pos = retarget(rest_positions_m() + rng.normal(scale=0.03, size=(4, 15, 3)) + [0.3, 1.0, -3.0])
    angles = RELAXED_DEG + rng.uniform(0.0, 40.0, size=(4, 2, 5, 5)) * [0.2, 1.0, 0.5, 1.0, 1.0]
    motion = Motion(quats, pos[:, PELVIS], 30.0, finger_rotations=finger_quaternions(angles))
    write_bvh(tmp_path / "fingers.bvh", motion_bvh(motion, "cm", rig="humanoid"))
    assert compare(tmp_path / "fingers.bvh", [0, 3]) < 1e-3  # centimetres
    assert set(FINGER_JOINTS) <= set(blender_pose(tmp_path / "fingers.bvh", [0])["bones"])


@pytest.mark.parametrize("rig", ["universal", "humanoid"])
def test_blender_finds_no_zero_length_bone(tmp_path, rig):
    from blender_check import INSIDE, run_in_blender

    rng = np.random.default_rng(2)
    quats, pos = retarget(rest_positions_m() + rng.normal(scale=0.05, size=(4, 15, 3)) + [0.3, 1.0, -3.0])
    write_bvh(tmp_path / "track.bvh", motion_bvh(Motion(quats, pos[:, PELVIS], 30.0), "cm", rig=rig))
    run = run_in_blender(INSIDE, [str(tmp_path / "track.bvh"), "[0]"])
    assert "MOCAPDB" in run.stdout, run.stderr[-2000:]  # imported
    assert "zero length" not in run.stdout + run.stderr  # the importer's warning for a bone without length


def test_a_blender_export_builds_the_same_database_clip(tmp_path):
    # Blender's exporter writes position channels on every joint (they replace the OFFSET).
    from blender_roundtrip import compare, round_trip

    source = ROOT / "data" / "sample_bvh" / "002_01.bvh"
    exported = tmp_path / "002_01_blender.bvh"
    round_trip(source, exported)
    assert "CHANNELS 6" in exported.read_text().split("JOINT", 2)[2]  # a non-root joint has positions
    result = compare(source, exported)
    assert result["frames"][0] == result["frames"][1]
    assert result["max_cm"] < 1.0 and result["pelvis_max_cm"] < 1.0
