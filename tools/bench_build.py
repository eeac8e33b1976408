"""Benchmark `mocapdb build` at several sizes: seconds per stage, peak memory, disk.

A small build of one file comes first in each version (numba compiles the kernels on first use,
and again after their source changes). Each size is built in its own process, which reports its
own peak resident memory (and that of its reader processes) and the processor seconds it and they
used (less sensitive than the wall time to other work on a shared machine). Prints one row per
size, and how each stage grows between sizes. With ``--baseline DIR`` (a checkout of another
version, e.g. ``git worktree add /tmp/old HEAD~1``) each size is also built with that version,
alternately, so the two are compared on the same machine load. With ``--schedulers local:1 local:2``
each size is built on a Dask cluster of each of those (one build each, alternately), and the
speed-up of every stage over the first cluster is printed (issue 21: read, project and embed
≥ 1.7× from 1 to 2 workers).

    python tools/bench_build.py [--sources ../shared/data/cmu_bvh] [--yaw-steps 12 3.6 1.25]
                                [--memory-limit MB] [--baseline DIR] [--repeat N]
                                [--schedulers local:1 local:2]

(Every clip is also stored mirrored: 12°, 3.6° and 1.25° give 0.63 M, 2.1 M and 6.0 M projections.)
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_SOURCES = ROOT.parent / "shared" / "data" / "cmu_bvh"

CHILD = """
import json, resource, sys
from mocapdb.builder.config import BuildConfig
from mocapdb.builder.pipeline import build
options = {"yaw_step_deg": float(sys.argv[2]), "workers": int(sys.argv[4])}
if sys.argv[5] != "default":
    options["memory_limit_mb"] = int(sys.argv[5])
if sys.argv[6] != "here":
    options["scheduler"] = sys.argv[6]
s = build([sys.argv[1]], sys.argv[3], BuildConfig(**options), exclude=sys.argv[7:])
cpu = [resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)]
print(json.dumps({"cpu_s": sum(u.ru_utime + u.ru_stime for u in cpu), "projections": s.projections,
                  "seconds": s.seconds, "bytes": s.bytes_on_disk, "work_bytes": getattr(s, "work_bytes", 0),
                  "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "reader_peak_mb": max(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024,
                                        getattr(s, "worker_peak_mb", 0.0))}))
"""


def run_one(sources: Path | str, yaw_step: float, workers: int, memory_limit: str, exclude: list[str],
            code: Path = ROOT, scheduler: str = "here") -> dict:
    """Build once in a child process running the package at ``code`` (its tasks on ``scheduler``, or
    here); its summary and peaks (``reader_peak_mb``: of its reader processes or Dask workers; their
    processor seconds are not counted)."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(code), os.environ.get("PYTHONPATH", "")])}
    with tempfile.TemporaryDirectory() as tmp:
        out = subprocess.run([sys.executable, "-c", CHILD, str(sources), str(yaw_step), str(Path(tmp) / "db"),
                              str(workers), memory_limit, scheduler, *exclude],
                             check=True, capture_output=True, text=True, env=env, cwd=tmp)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    result["yaw_step"] = yaw_step
    return result


def median_run(runs: list[dict]) -> dict:
    """The run of median total time, its per-stage seconds replaced by the per-stage medians."""
    ordered = sorted(runs, key=lambda r: sum(r["seconds"].values()))
    result = dict(ordered[len(ordered) // 2])
    result["seconds"] = {s: statistics.median(r["seconds"][s] for r in runs) for s in runs[0]["seconds"]}
    result["peak_mb"] = max(r["peak_mb"] for r in runs)
    return result


def print_table(title: str, runs: list[dict]) -> None:
    stages = list(runs[0]["seconds"])
    print(title)
    print(f"{'yaw step':>9} {'projections':>12} " + " ".join(f"{s:>8}" for s in stages)
          + f" {'total s':>8} {'cpu s':>8} {'peak MB':>8} {'readers':>8} {'db MB':>8} {'work MB':>8}")
    for r in runs:
        print(f"{r['yaw_step']:>9g} {r['projections']:>12,} " + " ".join(f"{r['seconds'][s]:>8.2f}" for s in stages)
              + f" {sum(r['seconds'].values()):>8.2f} {r['cpu_s']:>8.1f} {r['peak_mb']:>8.0f}"
              + f" {r['reader_peak_mb']:>8.0f}"
              + f" {r['bytes'] / 1e6:>8.1f} {r['work_bytes'] / 1e6:>8.1f}")
    for a, b in zip(runs, runs[1:]):
        growth = " ".join(f"{s} x{b['seconds'][s] / max(a['seconds'][s], 1e-9):.1f}" for s in stages)
        total = sum(b["seconds"].values()) / sum(a["seconds"].values())
        print(f"growth for x{b['projections'] / a['projections']:.1f} projections: {growth}; total x{total:.1f}, "
              f"peak memory x{b['peak_mb'] / a['peak_mb']:.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sources", type=Path, default=DEFAULT_SOURCES, help="BVH folder")
    ap.add_argument("--yaw-steps", type=float, nargs="+", default=[12.0, 3.6, 1.25],
                    help="yaw steps in degrees, one build each (default 12, 3.6 and 1.25)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--memory-limit", default="default", help="--memory-limit in MB (default: the build's own)")
    ap.add_argument("--repeat", type=int, default=1, help="builds per size (medians are printed)")
    ap.add_argument("--baseline", type=Path, help="a checkout of another version to build alternately")
    ap.add_argument("--exclude", nargs="*", default=[], help="glob patterns to leave out")
    ap.add_argument("--schedulers", nargs="+", default=[], metavar="SCHEDULER",
                    help="build on these Dask clusters (local:N or an address) instead of here")
    args = ap.parse_args()
    if not args.sources.is_dir():
        print(f"no BVH folder at {args.sources}", file=sys.stderr)
        return 2
    variants = {f"--scheduler {s}": (ROOT, s) for s in args.schedulers} or {"this version": (ROOT, "here")}
    if args.baseline:
        variants[f"baseline {args.baseline}"] = (args.baseline, "here")
    for code in {code for code, _ in variants.values()}:  # numba compiles on first use: a small build first
        run_one(next(args.sources.rglob("*.bvh")), 120.0, 1, "default", [], code)
    runs: dict[str, list[dict]] = {name: [] for name in variants}
    for step in args.yaw_steps:
        repeats: dict[str, list[dict]] = {name: [] for name in variants}
        for _ in range(args.repeat):
            for name, (code, scheduler) in variants.items():
                repeats[name].append(run_one(args.sources, step, args.workers, args.memory_limit, args.exclude,
                                             code, scheduler))
        for name in variants:
            runs[name].append(median_run(repeats[name]))
    for name, results in runs.items():
        print_table(f"{name} (--memory-limit {args.memory_limit}, {args.workers} workers, "
                    f"median of {args.repeat}):", results)
    print_speedups(runs, args.schedulers)
    return 0


def print_speedups(runs: dict[str, list[dict]], schedulers: list[str]) -> None:
    """Each stage's speed-up on every cluster after the first, over the first, per size."""
    first = f"--scheduler {schedulers[0]}" if schedulers else None
    for scheduler in schedulers[1:]:
        for a, b in zip(runs[first], runs[f"--scheduler {scheduler}"]):
            ratios = " ".join(f"{s} x{a['seconds'][s] / max(b['seconds'][s], 1e-9):.2f}" for s in a["seconds"])
            print(f"{scheduler} over {schedulers[0]}, {a['projections']:,} projections: {ratios}; total "
                  f"x{sum(a['seconds'].values()) / sum(b['seconds'].values()):.2f}")


if __name__ == "__main__":
    raise SystemExit(main())
