"""The accuracy gate: a fixed, fast evaluation compared with stored thresholds; exit 0 only when every check passes.

Held-out CMU clips (walk, brisk walk, punching; none in demo/sample.db) on fixed unusual bodies (narrow hip
centres 0.095 m, short legs, long arms), rendered exactly without nose, heels or toes, reconstructed by the engine
(refined, and its whole take) and scored; their head, hands and feet against the clips' own (exact 2D with face,
knuckle, heel and toe points; the humanoid BVH and the lag-0 stream); then every camera of the real take alone.
Each figure must stay at or under its threshold in data_specs/accuracy_gate.json (the contract:
data_specs/accuracy_gate.md). Its data
live in the repository (data/gate, copied from ../shared/data with their credits), so it always runs. A part
whose data are absent (other --bvh-dir/--real-take) is skipped with a message; a gate that checked nothing
fails, and so does any skipped check under CI=true. Exit codes: 0 pass, 1 a check failed (or was skipped where
it must not be), 2 usage.

    .venv/bin/python tools/accuracy_gate.py                    # the gate (CI)
    .venv/bin/python tools/accuracy_gate.py --write-thresholds # re-measure the thresholds on this code
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
GATE_DATA = ROOT / "data" / "gate"  # the held-out clips and the real take, copied from ../shared/data
# Threshold = measured × (1 + RELATIVE) + ABSOLUTE (in the figure's unit): data_specs/accuracy_gate.md, "Margin".
MARGIN_RELATIVE = 0.03
MARGIN_ABSOLUTE = 0.05
IMPROVED = 0.05  # a figure this much (relative) under its measured value is worth re-measuring the thresholds


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="contract: data_specs/accuracy_gate.md")
    parser.add_argument("--db", type=Path, default=ROOT / "demo" / "sample.db", help="motion database (%(default)s)")
    parser.add_argument("--bvh-dir", type=Path, default=GATE_DATA / "cmu_bvh",
                        help="folder of the held-out CMU clips (%(default)s)")
    parser.add_argument("--real-take", type=Path, default=GATE_DATA / "pose2sim_balancing",
                        help="the calibrated Pose2Sim take (%(default)s)")
    parser.add_argument("--thresholds", type=Path, default=ROOT / "data_specs" / "accuracy_gate.json",
                        help="thresholds file (%(default)s)")
    parser.add_argument("--write-thresholds", action="store_true",
                        help="measure on this code and write --thresholds (measured + margin) instead of checking")
    parser.add_argument("--json", type=Path, metavar="OUT", help="also write the figures to this JSON file")
    return parser.parse_args(argv)


def measure(args: argparse.Namespace) -> tuple[dict[str, float], list[str]]:
    """Every figure of the parts whose data exist, and the parts skipped (each with a message)."""
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.evaluation.ends import gate_figures as end_figures
    from mocapdb.evaluation.gate import body_figures, evaluate_bodies, real_take_figures

    db = load_database(args.db)
    figures: dict[str, float] = {}
    skipped = []
    if args.bvh_dir.is_dir():
        stats = evaluate_bodies(db, args.bvh_dir)
        figures.update(body_figures(stats))
        figures.update(end_figures(db, args.bvh_dir))
    else:
        skipped += ["bodies", "actions", "ends"]
        print(f"SKIP  bodies, actions, ends: no held-out clips at {args.bvh_dir}", file=sys.stderr)
    if args.real_take.is_dir():
        figures.update(real_take_figures(db, args.real_take))
    else:
        skipped.append("real take")
        print(f"SKIP  real take: no take at {args.real_take}", file=sys.stderr)
    return figures, skipped


def code_version() -> str:
    """``git describe --always --dirty`` of the checkout the mocapdb package is imported from."""
    import mocapdb

    run = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=Path(mocapdb.__file__).parent,
                         capture_output=True, text=True)
    return run.stdout.strip() or "unknown"


def write_thresholds(path: Path, figures: dict[str, float], seconds: float) -> None:
    from mocapdb.evaluation.ends import GATE_MARGIN
    from mocapdb.evaluation.gate import thresholds_from

    ends = {name: value for name, value in figures.items() if name.startswith("ends/")}
    others = {name: value for name, value in figures.items() if name not in ends}
    data = {"contract": "data_specs/accuracy_gate.md",
            "measured_on": {"code": code_version(), "date": datetime.date.today().isoformat(),
                            "seconds": round(seconds, 1)},
            "margin": {"relative": MARGIN_RELATIVE, "absolute": MARGIN_ABSOLUTE,
                       "ends": {"relative": GATE_MARGIN[0], "absolute": GATE_MARGIN[1]}},
            "figures": {**thresholds_from(others, MARGIN_RELATIVE, MARGIN_ABSOLUTE),
                        **thresholds_from(ends, *GATE_MARGIN)}}
    path.write_text(thresholds_text(data))
    print(f"thresholds of {len(data['figures'])} figures written to {path}")


def thresholds_text(data: dict) -> str:
    """``data`` as JSON with one line per figure (readable diffs when the thresholds are re-measured)."""
    head = json.dumps({key: value for key, value in data.items() if key != "figures"}, indent=1)
    rows = ",\n".join(f"  {json.dumps(name, ensure_ascii=False)}: {json.dumps(entry)}"
                       for name, entry in data["figures"].items())
    return head[:-2] + ',\n "figures": {\n' + rows + "\n }\n}\n"


def check(figures: dict[str, float], skipped_parts: list[str], thresholds: dict, seconds: float) -> int:
    """Print a PASS/FAIL/SKIP line per threshold, notes and the verdict; 0 when every check passes, else 1."""
    from mocapdb.evaluation.gate import compare

    checks = compare(figures, thresholds["figures"], skipped_parts)
    print("\n".join([c.line() for c in checks] + notes(figures, checks, thresholds["figures"])))
    failed = sum(not c.ok for c in checks)
    skipped = sum(c.skipped for c in checks)
    passed = len(checks) - failed - skipped
    counts = f"{passed} passed, {failed} failed, {skipped} skipped of {len(checks)} checks"
    why_not = unchecked(passed, skipped, in_ci=os.environ.get("CI", "").lower() == "true")
    measured = thresholds.get("measured_on", {})
    print(f"accuracy gate: {'FAIL' if failed or why_not else 'PASS'} ({counts}; {seconds:.1f} s; thresholds "
          f"measured on {measured.get('code', '?')}, {measured.get('date', '?')}){why_not}")
    return 1 if failed or why_not else 0


def unchecked(passed: int, skipped: int, in_ci: bool) -> str:
    """Why a gate without a failed check still fails (empty when it does not): it checked nothing, or it
    skipped a check under CI, where every part's data must be present."""
    if passed == 0:
        return ": it checked nothing"
    if skipped and in_ci:
        return f": {skipped} check(s) skipped under CI=true"
    return ""


def notes(figures: dict[str, float], checks: list, limits: dict) -> list[str]:
    """NOTE lines: gated figures without a threshold, and figures well under their measured value."""
    from mocapdb.evaluation.gate import gated

    lines = [f"NOTE  {name}: no threshold (re-measure with --write-thresholds)"
             for name in figures if gated(name) and name not in limits]
    for c in checks:
        if c.ok and not c.skipped and c.measured and c.value < c.measured * (1 - IMPROVED):
            lines.append(f"NOTE  {c.name}: {c.value:.2f}, well under the {c.measured:.2f} measured "
                         f"(tighten with --write-thresholds)")
    return lines


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if not args.db.exists():
        print(f"accuracy gate: no database at {args.db} (bash tools/quickstart.sh builds it)", file=sys.stderr)
        return 2
    if not args.write_thresholds and not args.thresholds.is_file():
        print(f"accuracy gate: no thresholds file {args.thresholds}", file=sys.stderr)
        return 2
    from mocapdb.evaluation.gate import format_table

    t0 = time.perf_counter()
    figures, skipped = measure(args)
    seconds = time.perf_counter() - t0
    print(format_table(figures) + "\n")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=1) + "\n")
    if args.write_thresholds:
        if skipped:
            print(f"accuracy gate: not writing thresholds without {', '.join(skipped)}", file=sys.stderr)
            return 2
        write_thresholds(args.thresholds, figures, seconds)
        return 0
    return check(figures, skipped, json.loads(args.thresholds.read_text()), seconds)


if __name__ == "__main__":
    raise SystemExit(main())
