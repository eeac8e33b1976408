"""`mocapdb build` and `mocapdb inspect`: BVH files → database; how a BVH maps onto the skeleton."""
from __future__ import annotations

import argparse
import os
import sys

from mocapdb.cli import paths as P
from mocapdb.core import domains as D
from mocapdb.core.units import UNITS, UP_AXES


def add_build_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("build", help="build a motion database from BVH files",
                       description="Read BVH clips (files or folders, recursively), retarget them to the "
                                   "universal 14-joint skeleton (each also as its left-right mirror image), "
                                   "project every frame from every yaw, embed with landmark MDS, cluster with "
                                   "k-means and write a Parquet database.")
    p.add_argument("sources", nargs="+", type=P.INPUT_ANY, help="BVH files or folders")
    p.add_argument("--out", required=True, type=P.OUTPUT_DIR,
                   help="database directory to write (replaced atomically; a symlink is followed and kept)")
    p.add_argument("--fps", type=D.DATABASE_FPS_HZ, default=D.DATABASE_FPS_HZ.default,
                   help="database frame rate in Hz (default %(default)s)")
    p.add_argument("--yaw-step", type=D.YAW_STEP_DEG, default=D.YAW_STEP_DEG.default,
                   help="yaw step in degrees; must divide 360 (default %(default)s)")
    p.add_argument("--camera-height", type=D.DATABASE_CAMERA_HEIGHT_M, default=D.DATABASE_CAMERA_HEIGHT_M.default,
                   metavar="METRES",
                   help="the database's virtual camera: its height above the floor, metres (default %(default)s)")
    p.add_argument("--camera-distance", type=D.DATABASE_CAMERA_DISTANCE_M, default=D.DATABASE_CAMERA_DISTANCE_M.default,
                   metavar="METRES",
                   help="the database's virtual camera: its distance to the pelvis, metres (default %(default)s)")
    p.add_argument("--focal", type=D.DATABASE_FOCAL_PX, default=D.DATABASE_FOCAL_PX.default, metavar="PX",
                   help="the database's virtual camera: its focal length in pixels (default %(default)s)")
    p.add_argument("--clusters", type=D.CLUSTERS, default=D.CLUSTERS.default,
                   help="k-means clusters K (default %(default)s)")
    p.add_argument("--dims", type=D.DIMS, default=D.DIMS.default, help="MDS embedding dimensions (default %(default)s)")
    p.add_argument("--landmarks", type=D.LANDMARKS, default=D.LANDMARKS.default,
                   help="landmark-MDS landmarks (default %(default)s)")
    p.add_argument("--seed", type=D.SEED, default=0, help="random seed (the build is deterministic for a seed)")
    p.add_argument("--workers", type=D.WORKERS, default=os.cpu_count() or 1,
                   help="processes reading BVH files (default: one per CPU)")
    p.add_argument("--memory-limit", type=D.MEMORY_LIMIT_MB, metavar="MB",
                   help="peak memory the build aims at, in MB; it sets the chunk sizes (default: a quarter of "
                        "the machine's memory; below ~400 MB the build runs in its smallest chunks)")
    p.add_argument("--work-dir", type=P.OUTPUT_DIR, metavar="DIR",
                   help="folder for the stages' arrays and the resumable state (default: --out with '.work' "
                        "appended); removed once the database is written")
    p.add_argument("--restart", action="store_true",
                   help="ignore an interrupted build's work folder and start again (by default the same "
                        "command goes on where it stopped; a changed option or source restarts the stages "
                        "it affects)")
    p.add_argument("--scheduler", type=P.TextArg("a Dask scheduler address"), metavar="ADDRESS",
                   help="run the build's tasks on a Dask cluster: a scheduler's address (tcp://host:8786; the "
                        "sources and the work folder must be at the same paths on every worker) or local:N "
                        "for N worker processes on this machine (needs mocapdb[dask])")
    p.add_argument("--exclude", action="append", type=P.TextArg("a glob pattern"), default=[], metavar="PATTERN",
                   help="skip files whose name or path matches this glob (repeatable)")
    p.add_argument("--strict", action="store_true",
                   help="fail the build when any file is skipped (by default a file that cannot be read, "
                        "mapped or retargeted is skipped and named with the reason)")
    p.add_argument("--joint-map", type=P.INPUT_FILE,
                   help="TOML file mapping skeleton roles to source joint names, for the files no other map "
                        "covers (default: every rig is recognised from its joints' names, hierarchy and poses)")
    p.add_argument("--joint-map-for", nargs=2, action="append", default=[], metavar=("PATTERN", "MAP"),
                   type=P.TextArg("a glob pattern or a joint-map file"),
                   help="read the files whose name or path matches PATTERN (a glob, as --exclude) with the "
                        "joint map MAP (repeatable; the first match wins, before a joint_map.toml beside the "
                        "files, which applies to its folder and those below, and before --joint-map)")
    p.add_argument("--unit", choices=UNITS, help="length unit of the BVH files (default: detected)")
    p.add_argument("--up-axis", choices=UP_AXES, help="up axis of the BVH files (default: detected)")
    p.add_argument("--credit", type=P.TextArg("a credit text"),
                   help="credit/licence text stored with every clip (default: nearest CREDIT.txt)")
    p.add_argument("--no-mirror", action="store_true",
                   help="store only the clips as captured, not also their left-right mirror images")
    p.set_defaults(run=run_build)


def run_build(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mocapdb.builder.config import BuildConfig, BuildError
    from mocapdb.builder.pipeline import build
    from mocapdb.core.cameras import DatabaseCamera
    from mocapdb.core.files import output_target

    config = BuildConfig(
        fps=args.fps, yaw_step_deg=args.yaw_step,
        camera=DatabaseCamera(height_m=args.camera_height, distance_m=args.camera_distance, focal_px=args.focal),
        clusters=args.clusters, dims=args.dims, seed=args.seed, landmarks=args.landmarks,
        workers=args.workers, strict=args.strict,
        joint_map=Path(args.joint_map) if args.joint_map else None,
        joint_maps=tuple((pattern, Path(map_path)) for pattern, map_path in args.joint_map_for),
        unit=args.unit, up_axis=args.up_axis, credit=args.credit, mirror=not args.no_mirror,
        memory_limit_mb=args.memory_limit, work_dir=Path(args.work_dir) if args.work_dir else None,
        restart=args.restart, scheduler=args.scheduler)
    try:
        summary = build(args.sources, args.out, config, exclude=args.exclude)
    except BuildError as exc:  # the files skipped before it stopped, each with its reason, then the error
        for path, why in exc.skipped:
            print(f"skipped {path}: {why}", file=sys.stderr)
        raise
    except KeyboardInterrupt:
        print("mocapdb build: the same command goes on where this build stopped (--restart starts again)",
              file=sys.stderr)
        raise
    target = output_target(args.out)
    print(f"wrote {args.out}" + (f" (symlink to {target})" if os.path.islink(args.out) else ""))
    print(summary.report())
    return 0


def add_inspect_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("inspect", help="show how a BVH file maps onto the universal skeleton",
                       description="Print a BVH file's detected rig, unit, up axis and the source joint used "
                                   "for each skeleton role with the evidence: the words of its name, the "
                                   "hierarchy (pelvis, chest, head) and the sides in the clip's poses.")
    p.add_argument("bvh", type=P.INPUT_FILE, help="BVH file")
    p.add_argument("--joint-map", type=P.INPUT_FILE,
                   help="TOML file mapping skeleton roles to source joint names (default: a joint_map.toml "
                        "beside the file, as `mocapdb build` reads it for a file given alone)")
    p.add_argument("--unit", choices=UNITS, help="length unit (default: detected)")
    p.add_argument("--up-axis", choices=UP_AXES, help="up axis (default: detected)")
    p.set_defaults(run=run_inspect)


def run_inspect(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mocapdb.core.clips import JOINT_MAP_FILE
    from mocapdb.core.formats.bvh import read_bvh
    from mocapdb.core.joint_map import describe, detect_mapping, load_joint_map_file

    bvh = read_bvh(args.bvh)
    beside = Path(args.bvh).parent / JOINT_MAP_FILE
    map_path = args.joint_map or (beside if beside.is_file() else None)
    overrides = load_joint_map_file(map_path) if map_path else None
    mapping = detect_mapping(bvh, overrides.joints if overrides else None)
    unit = args.unit or (overrides.unit if overrides else None)
    up_axis = args.up_axis or (overrides.up_axis if overrides else None)
    if map_path:
        print(f"joint map:   {map_path}" + ("" if args.joint_map else " (beside the file)"))
    print(describe(bvh, mapping, unit, up_axis))
    return 0


def add_verify_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("verify", help="check every file of a database against its manifest",
                       description="Check a database written by `mocapdb build` end to end: each table's size, "
                                   "sha256 and contents (columns, finite values), the search index's sizes, "
                                   "shapes and CRC-32 blocks, then the tables against each other. Prints one line "
                                   "per check; exit code 0 when all pass, 1 when any fails. (`reconstruct` and "
                                   "`live` check the tables and the index they load the same way, and the "
                                   "projections table they do not read by its size and footer.)")
    p.add_argument("db", type=P.INPUT_DIR, help="database directory")
    p.set_defaults(run=run_verify)


def run_verify(args: argparse.Namespace) -> int:
    from mocapdb.core.formats.database_reader import verify_database

    report = verify_database(args.db)
    for what, problem in report:
        print(f"{'FAIL' if problem else 'ok  '}  {what}" + (f": {problem}" if problem else ""))
    failed = sum(problem is not None for _, problem in report)
    print(f"{args.db}: " + (f"{failed} of {len(report)} checks failed: the database is damaged; rebuild it"
                            if failed else f"all {len(report)} checks passed"))
    return 1 if failed else 0
