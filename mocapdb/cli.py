"""The `mocapdb` command line."""
from __future__ import annotations

import argparse
import os
import sys

from . import __version__
from .joint_map import UNITS, UP_AXES


def _add_build(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build", help="build a motion database from BVH files",
                       description="Read BVH clips (files or folders, recursively), retarget them to the "
                                   "universal 14-joint skeleton, project every frame from every yaw, embed "
                                   "with landmark MDS, cluster with k-means and write a Parquet database.")
    p.add_argument("sources", nargs="+", help="BVH files or folders")
    p.add_argument("--out", required=True, help="database directory to write (replaced atomically)")
    p.add_argument("--fps", type=float, default=24.0, help="database frame rate in Hz (default 24)")
    p.add_argument("--yaw-step", type=float, default=12.0, help="yaw step in degrees; must divide 360 (default 12)")
    p.add_argument("--camera-height", type=float, default=1.5, help="camera height above the floor, metres (default 1.5)")
    p.add_argument("--camera-distance", type=float, default=4.0, help="camera to pelvis, metres (default 4)")
    p.add_argument("--focal", type=float, default=1000.0, help="focal length in pixels (default 1000)")
    p.add_argument("--clusters", type=int, default=500, help="k-means clusters K (default 500)")
    p.add_argument("--dims", type=int, default=5, help="MDS embedding dimensions (default 5)")
    p.add_argument("--landmarks", type=int, default=2000, help="landmark-MDS landmarks (default 2000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (the build is deterministic for a seed)")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="processes reading BVH files")
    p.add_argument("--exclude", action="append", default=[], metavar="PATTERN",
                   help="skip files whose name or path matches this glob (repeatable)")
    p.add_argument("--strict", action="store_true", help="fail the build on any unreadable BVH")
    p.add_argument("--joint-map", help="TOML file mapping skeleton roles to source joint names")
    p.add_argument("--unit", choices=UNITS, help="length unit of the BVH files (default: detected)")
    p.add_argument("--up-axis", choices=UP_AXES, help="up axis of the BVH files (default: detected)")
    p.add_argument("--credit", help="credit/licence text stored with every clip (default: nearest CREDIT.txt)")
    p.set_defaults(run=_run_build)


def _run_build(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .builder import BuildConfig, build
    from .geometry import Camera

    config = BuildConfig(
        fps=args.fps, yaw_step_deg=args.yaw_step,
        camera=Camera(height_m=args.camera_height, distance_m=args.camera_distance, focal_px=args.focal),
        clusters=args.clusters, dims=args.dims, seed=args.seed, landmarks=args.landmarks,
        workers=max(1, args.workers), strict=args.strict,
        joint_map=Path(args.joint_map) if args.joint_map else None,
        unit=args.unit, up_axis=args.up_axis, credit=args.credit)
    summary = build(args.sources, args.out, config, exclude=args.exclude)
    print(f"wrote {args.out}")
    print(summary.report())
    return 0


def _add_inspect(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="show how a BVH file maps onto the universal skeleton",
                       description="Print a BVH file's detected rig convention, unit, up axis and the "
                                   "source joint used for each skeleton role.")
    p.add_argument("bvh", help="BVH file")
    p.add_argument("--joint-map", help="TOML file mapping skeleton roles to source joint names")
    p.add_argument("--unit", choices=UNITS, help="length unit (default: detected)")
    p.add_argument("--up-axis", choices=UP_AXES, help="up axis (default: detected)")
    p.set_defaults(run=_run_inspect)


def _run_inspect(args: argparse.Namespace) -> int:
    from .bvh import read_bvh
    from .joint_map import describe, detect_mapping, load_joint_map_file

    bvh = read_bvh(args.bvh)
    overrides = load_joint_map_file(args.joint_map) if args.joint_map else None
    mapping = detect_mapping(bvh, overrides.joints if overrides else None)
    unit = args.unit or (overrides.unit if overrides else None)
    up_axis = args.up_axis or (overrides.up_axis if overrides else None)
    print(describe(bvh, mapping, unit, up_axis))
    return 0


def parser() -> argparse.ArgumentParser:
    top = argparse.ArgumentParser(prog="mocapdb", description="Motion capture from ordinary cameras by "
                                  "retrieval in a database of real motion.")
    top.add_argument("--version", action="version", version=f"mocapdb {__version__}")
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_build(sub)
    _add_inspect(sub)
    return top


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 only on success)."""
    args = parser().parse_args(argv)
    from .errors import USER_ERRORS

    try:
        return args.run(args)
    except USER_ERRORS as exc:
        print(f"mocapdb {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mocapdb {args.command}: interrupted", file=sys.stderr)
        return 130
