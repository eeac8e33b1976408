"""Benchmark `mocapdb build` at the method's scale and at 2,000,000 projections.

Each size is built in its own process so that its peak memory (max RSS) is measured alone.
Prints per-stage seconds, totals, peak memory and how each stage grows between the sizes.

    python tools/bench_build.py [--sources ../shared/data/cmu_bvh] [--yaw-steps 12 3.6]

(Every clip is also stored mirrored, so 3.6° steps give ~2,100,000 projections.)
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SOURCES = ROOT.parent / "shared" / "data" / "cmu_bvh"

CHILD = """
import json, sys
from mocapdb.builder.pipeline import BuildConfig, build
cfg = BuildConfig(yaw_step_deg=float(sys.argv[2]), workers=int(sys.argv[4]))
s = build([sys.argv[1]], sys.argv[3], cfg, exclude=sys.argv[5:])
print(json.dumps({"projections": s.projections, "frames": s.frames, "clips": s.clips,
                  "seconds": s.seconds, "bytes": s.bytes_on_disk}))
"""


def run_one(sources: Path, yaw_step: float, workers: int, exclude: list[str]) -> dict:
    """Build once in a child process; return its summary and peak memory in MB."""
    with tempfile.TemporaryDirectory() as tmp:
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        out = subprocess.run([sys.executable, "-c", CHILD, str(sources), str(yaw_step),
                              str(Path(tmp) / "db"), str(workers), *exclude],
                             check=True, capture_output=True, text=True)
        peak_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["peak_mb"] = peak_kb / 1024 if peak_kb > before else float("nan")
    result["yaw_step"] = yaw_step
    return result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", type=Path, default=DEFAULT_SOURCES, help="BVH folder")
    ap.add_argument("--yaw-steps", type=float, nargs="+", default=[12.0, 3.6],
                    help="yaw steps in degrees, one build each (default 12 and 3.6)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--exclude", nargs="*", default=[], help="glob patterns to leave out")
    args = ap.parse_args()
    if not args.sources.is_dir():
        print(f"no BVH folder at {args.sources}", file=sys.stderr)
        return 2
    runs = [run_one(args.sources, step, args.workers, args.exclude) for step in args.yaw_steps]
    stages = list(runs[0]["seconds"])
    print(f"{'yaw step':>9} {'projections':>12} " + " ".join(f"{s:>9}" for s in stages)
          + f" {'total s':>9} {'peak MB':>9} {'disk MB':>9}")
    for r in runs:
        print(f"{r['yaw_step']:>9g} {r['projections']:>12,} "
              + " ".join(f"{r['seconds'][s]:>9.2f}" for s in stages)
              + f" {sum(r['seconds'].values()):>9.2f} {r['peak_mb']:>9.0f} {r['bytes'] / 1e6:>9.1f}")
    for a, b in zip(runs, runs[1:]):
        n_ratio = b["projections"] / a["projections"]
        growth = " ".join(f"{s} x{b['seconds'][s] / max(a['seconds'][s], 1e-9):.1f}" for s in stages)
        print(f"growth for x{n_ratio:.1f} projections: {growth}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
