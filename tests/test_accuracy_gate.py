"""The accuracy gate's comparison logic on hand-made figures, its thresholds file and its CLI (the gate
itself runs in CI after the tests: .ci/run)."""
from __future__ import annotations

import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from mocapdb.evaluation.ends import GATE_ENDS_FIGURES, GATE_ENDS_VARIANTS
from mocapdb.evaluation.gate import (
    BODY_METRICS,
    GATE_BODIES,
    GATE_CLIPS,
    REAL_METRICS,
    REAL_RUNS,
    VARIANTS,
    compare,
    format_table,
    thresholds_from,
)

ROOT = Path(__file__).resolve().parent.parent
TOOL = ROOT / "tools" / "accuracy_gate.py"
LIMITS = {"bodies/a/refined/pa_mpjpe13_cm": {"measured": 5.0, "max": 5.2},
          "real take/b/mpjpe13_cm": {"measured": 10.0, "max": 10.35}}


def _tool():
    spec = importlib.util.spec_from_file_location("accuracy_gate", TOOL)
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_figures_at_or_under_their_thresholds_pass():
    checks = compare({"bodies/a/refined/pa_mpjpe13_cm": 5.2, "real take/b/mpjpe13_cm": 9.0}, LIMITS)
    assert [c.ok for c in checks] == [True, True]
    assert checks[0].line() == "PASS  bodies/a/refined/pa_mpjpe13_cm: 5.20 ≤ 5.20 (measured 5.00)"


def test_a_figure_over_its_threshold_fails():
    checks = compare({"bodies/a/refined/pa_mpjpe13_cm": 5.21, "real take/b/mpjpe13_cm": 9.0}, LIMITS)
    assert [c.ok for c in checks] == [False, True]
    assert checks[0].line().startswith("FAIL  bodies/a/refined/pa_mpjpe13_cm: 5.21 ≤ 5.20")


@pytest.mark.parametrize("value", [None, math.nan, math.inf])
def test_a_missing_or_non_finite_figure_fails(value):
    figures = {"real take/b/mpjpe13_cm": 9.0}
    if value is not None:
        figures["bodies/a/refined/pa_mpjpe13_cm"] = value
    check = compare(figures, LIMITS)[0]
    assert not check.ok and check.line().startswith("FAIL")


def test_a_skipped_part_neither_fails_nor_passes():
    checks = compare({"bodies/a/refined/pa_mpjpe13_cm": 5.0}, LIMITS, skipped_parts=["real take"])
    assert all(c.ok for c in checks) and checks[1].skipped and checks[1].line().startswith("SKIP")


def test_thresholds_are_the_measured_value_plus_the_margin_and_leave_the_floor_out():
    figures = {"bodies/a/refined/pa_mpjpe13_cm": 5.0, "bodies/a/refined/floor_mpjpe_cm": 9.0}
    assert thresholds_from(figures, 0.03, 0.05) == {"bodies/a/refined/pa_mpjpe13_cm": {"measured": 5.0, "max": 5.2}}
    with pytest.raises(ValueError, match="non-finite"):
        thresholds_from({"bodies/a/refined/pa_mpjpe13_cm": math.nan}, 0.03, 0.05)


def test_the_table_has_a_row_per_figure_group_and_a_column_per_metric():
    table = format_table({"bodies/a/refined/mpjpe13_cm": 6.0, "bodies/a/refined/pa_mpjpe13_cm": 5.0,
                          "real take/b/root_error_pct_distance": math.nan})
    lines = table.splitlines()
    assert lines[0] == "| figures | MPJPE cm | PA-MPJPE cm | root error % of distance |"
    assert lines[2] == "| bodies/a/refined | 6.00 | 5.00 | – |" and lines[3] == "| real take/b | – | – | – |"


def test_the_stored_thresholds_cover_every_gated_figure_with_a_margin():
    data = json.loads((ROOT / "data_specs" / "accuracy_gate.json").read_text())
    names = {f"{part}/{row}/{variant}/{metric}" for part, rows in (("bodies", [b.name for b in GATE_BODIES]),
                                                                   ("actions", GATE_CLIPS.values()))
             for row in rows for variant in VARIANTS for metric in BODY_METRICS}
    names |= {f"real take/{variant}, {mode.replace('_', ' ')}/{metric}"
              for variant, mode in REAL_RUNS for metric, _ in REAL_METRICS}
    names |= {f"ends/{variant}/{key}_deg" for variant in GATE_ENDS_VARIANTS for key in GATE_ENDS_FIGURES}
    assert set(data["figures"]) == names
    assert data["measured_on"]["code"] and data["measured_on"]["date"]
    assert all(0 < entry["measured"] < entry["max"] for entry in data["figures"].values())


def test_the_thresholds_file_text_is_json_with_a_line_per_figure():
    data = {"measured_on": {"code": "abc"}, "figures": {"a/b/c": {"measured": 1.0, "max": 1.08}, "a/b/d": {}}}
    text = _tool().thresholds_text(data)
    assert json.loads(text) == data and '  "a/b/c": {"measured": 1.0, "max": 1.08},\n' in text


def test_help_and_a_missing_database():
    run = subprocess.run([sys.executable, str(TOOL), "--help"], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and "--write-thresholds" in run.stdout and "accuracy_gate.md" in run.stdout
    assert _tool().main(["--db", str(ROOT / "no such database")]) == 2


@pytest.mark.parametrize("passed, skipped, in_ci, verdict", [
    (0, 48, False, ": it checked nothing"), (0, 0, False, ": it checked nothing"),
    (36, 12, True, ": 12 check(s) skipped under CI=true"), (36, 12, False, ""), (48, 0, True, "")])
def test_a_gate_that_checked_nothing_or_skipped_under_ci_fails(passed, skipped, in_ci, verdict):
    assert _tool().unchecked(passed, skipped, in_ci) == verdict


def test_without_its_data_the_gate_fails_having_checked_nothing(small_db_path, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    absent = ["--bvh-dir", str(tmp_path / "no clips"), "--real-take", str(tmp_path / "no take")]
    assert _tool().main(["--db", str(small_db_path), *absent]) == 1
    n = len(json.loads((ROOT / "data_specs" / "accuracy_gate.json").read_text())["figures"])
    assert f"accuracy gate: FAIL (0 passed, 0 failed, {n} skipped of {n} checks" in capsys.readouterr().out


def test_the_gate_data_live_in_the_repository_where_the_tool_looks():
    args = _tool().parse_args([])
    assert all((args.bvh_dir / f"{clip}.bvh").is_file() for clip in GATE_CLIPS)
    take_files = {"calibration.toml", "triangulated_4cam.trc", "openpose_body25b"}
    assert {p.name for p in args.real_take.iterdir()} >= take_files
    assert len(list((args.real_take / "openpose_body25b").glob("cam0?_json/*.json"))) == 400
    assert args.bvh_dir.is_relative_to(ROOT) and args.real_take.is_relative_to(ROOT)
