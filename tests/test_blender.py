"""Blender reads mocapdb's BVH as mocapdb means it, and mocapdb reads Blender's export as Blender
means it (skipped without Blender: the bpy wheel in $MOCAPDB_BPY_PYTHON, or the blender program)."""
import sys

import numpy as np
import pytest

from mocapdb.core.formats.bvh import write_bvh
from mocapdb.core.outputs import universal_bvh
from mocapdb.core.skeleton import PELVIS, rest_positions_m, retarget

from .conftest import ROOT

sys.path.insert(0, str(ROOT / "tools"))
from blender_check import blender_available  # noqa: E402

pytestmark = pytest.mark.skipif(not blender_available(), reason="Blender not installed")


def test_blender_imports_universal_bvh_with_the_same_joint_positions(tmp_path):
    from blender_check import compare

    rng = np.random.default_rng(0)
    points = rest_positions_m() + rng.normal(scale=0.05, size=(20, 15, 3)) + [0.3, 1.0, -2.0]
    quats, pos = retarget(points)
    write_bvh(tmp_path / "track.bvh", universal_bvh(quats, pos[:, PELVIS], fps=30.0))
    assert compare(tmp_path / "track.bvh", [0, 7, 19]) < 1e-5  # metres


def test_blender_imports_the_humanoid_rig_on_its_floor(tmp_path):
    from blender_check import blender_pose, compare

    from mocapdb.core.exports import on_floor

    rng = np.random.default_rng(1)
    points = rest_positions_m() + rng.normal(scale=0.05, size=(12, 15, 3)) + [0.3, 1.0, -3.0]
    quats, pos = retarget(points)
    quats, root = on_floor(quats, pos[:, PELVIS], 1.0)
    write_bvh(tmp_path / "humanoid.bvh", universal_bvh(quats, root, 30.0, "cm", 1.1, rig="humanoid"))
    assert compare(tmp_path / "humanoid.bvh", [0, 5, 11]) < 1e-3  # centimetres
    bones = blender_pose(tmp_path / "humanoid.bvh", [0])["bones"]
    assert {"Hips", "Spine", "Neck", "Head", "LeftHand", "RightFoot", "LeftToeBase", "RightShoulder"} <= set(bones)


@pytest.mark.parametrize("rig", ["universal", "humanoid"])
def test_blender_finds_no_zero_length_bone(tmp_path, rig):
    from blender_check import INSIDE, run_in_blender

    rng = np.random.default_rng(2)
    quats, pos = retarget(rest_positions_m() + rng.normal(scale=0.05, size=(4, 15, 3)) + [0.3, 1.0, -3.0])
    write_bvh(tmp_path / "track.bvh", universal_bvh(quats, pos[:, PELVIS], 30.0, "cm", rig=rig))
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
