"""Shared test fixtures: paths to the bundled sample and to the shared real data."""
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BVH = ROOT / "data" / "sample_bvh"
SHARED_DATA = ROOT.parent / "shared" / "data"
SHARED_BVH = SHARED_DATA / "cmu_bvh"
