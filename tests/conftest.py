"""Shared test fixtures: paths to the bundled sample and to the shared real data."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BVH = ROOT / "data" / "sample_bvh"
SHARED_DATA = ROOT.parent / "shared" / "data"
SHARED_BVH = SHARED_DATA / "cmu_bvh"
SAMPLE_KEYPOINTS = ROOT / "data" / "sample_keypoints" / "pose2sim_cam01"

@pytest.fixture(scope="session")
def small_db_path(tmp_path_factory):
    """A database of two bundled walking/running clips, built once per test session."""
    from mocapdb.builder.config import BuildConfig
    from mocapdb.builder.pipeline import build

    out = tmp_path_factory.mktemp("small_db") / "db"
    build([str(SAMPLE_BVH / "002_01.bvh"), str(SAMPLE_BVH / "002_03.bvh")], out,
          BuildConfig(clusters=30, landmarks=300, workers=1))
    return out


@pytest.fixture(scope="session")
def small_db(small_db_path):
    from mocapdb.core.formats.database_reader import load_database

    return load_database(small_db_path)
