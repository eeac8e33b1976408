"""Blender's own BVH importer reads the universal-rig BVH as mocapdb means it (skipped without Blender)."""
import shutil
import sys

import numpy as np
import pytest

from mocapdb.bvh import write_bvh
from mocapdb.skeleton import PELVIS, rest_positions_m, retarget, universal_bvh

from .conftest import ROOT

pytestmark = pytest.mark.skipif(shutil.which("blender") is None, reason="Blender not installed")


def test_blender_imports_universal_bvh_with_the_same_joint_positions(tmp_path):
    sys.path.insert(0, str(ROOT / "tools"))
    from blender_check import compare

    rng = np.random.default_rng(0)
    points = rest_positions_m() + rng.normal(scale=0.05, size=(20, 15, 3)) + [0.3, 1.0, -2.0]
    quats, pos = retarget(points)
    write_bvh(tmp_path / "track.bvh", universal_bvh(quats, pos[:, PELVIS], fps=30.0))
    assert compare(tmp_path / "track.bvh", [0, 7, 19]) < 1e-5  # metres
