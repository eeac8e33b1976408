"""Shared test fixtures: paths to the bundled sample and to the shared real data; skips for missing data.

A test whose data or tool is absent skips with a reason starting :data:`MISSING` (:func:`needs`,
:func:`skip_missing`). The summary counts those skips; under ``CI=true``, where ``../shared`` lies beside
the clone and ``.ci/run`` installs every tool, each of them fails instead (docs/install.md, "Tests that skip").
"""
import os
from pathlib import Path
from typing import NoReturn

import pytest

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BVH = ROOT / "data" / "sample_bvh"
SHARED_DATA = ROOT.parent / "shared" / "data"
SHARED_BVH = SHARED_DATA / "cmu_bvh"
SAMPLE_KEYPOINTS = ROOT / "data" / "sample_keypoints" / "pose2sim_cam01"
# the Pose2Sim balancing take (4 calibrated cameras' OpenPose output, calibration, triangulation): the
# accuracy gate's copy in the repository, so the tests on it always run
REAL_TAKE = ROOT / "data" / "gate" / "pose2sim_balancing"
MISSING = "missing: "


def needs(*paths: Path) -> pytest.MarkDecorator:
    """Skip (a failure under CI) unless every one of ``paths`` exists."""
    absent = [str(path) for path in paths if not path.exists()]
    return pytest.mark.skipif(bool(absent), reason=MISSING + ", ".join(absent))


def skip_missing(what: str) -> NoReturn:
    """Skip the running test for ``what`` (data or a tool) being absent: a failure under CI."""
    pytest.skip(MISSING + what)


def assert_matches_tflite(onnx_path: Path, tflite_path: Path, blobs: list, rel_tolerance: float = 1e-3) -> None:
    """A converted model's outputs on each input ``blob`` within ``rel_tolerance`` of the largest value of
    its TFLite original's (run by LiteRT; skips without it)."""
    import numpy as np
    litert = pytest.importorskip("ai_edge_litert.interpreter")
    import onnxruntime as ort

    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    reference = litert.Interpreter(model_path=str(tflite_path))
    reference.allocate_tensors()
    (entry,) = reference.get_input_details()
    for blob in blobs:
        reference.set_tensor(entry["index"], blob)
        reference.invoke()
        got = dict(zip([o.name for o in session.get_outputs()], session.run(None, {entry["name"]: blob})))
        for detail in reference.get_output_details():
            expected = reference.get_tensor(detail["index"])
            scale = float(np.abs(expected).max()) or 1.0
            assert got[detail["name"]].shape == expected.shape
            assert np.abs(got[detail["name"]] - expected).max() <= rel_tolerance * scale, detail["name"]


def in_ci() -> bool:
    return os.environ.get("CI", "").lower() == "true"


def _skip_reason(report: pytest.TestReport) -> str:
    longrepr = report.longrepr
    return longrepr[2].removeprefix("Skipped: ") if isinstance(longrepr, tuple) else str(longrepr)


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Under CI a skip for missing data or a missing tool is a failure: there it means a broken set-up."""
    report = (yield).get_result()
    if report.skipped and in_ci() and _skip_reason(report).startswith(MISSING):
        report.outcome = "failed"
        report.longrepr = f"skipped, {_skip_reason(report)}: under CI=true every test's data and tools must be here"


def pytest_terminal_summary(terminalreporter):
    """How many tests skipped for missing data or tools, and the first few reasons."""
    reasons = [_skip_reason(r) for r in terminalreporter.stats.get("skipped", [])
               if _skip_reason(r).startswith(MISSING)]
    if reasons:
        terminalreporter.write_line(f"{len(reasons)} test(s) skipped for missing data or tools (failures under "
                                    f"CI=true): {'; '.join(sorted(set(reasons))[:5])}")

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
