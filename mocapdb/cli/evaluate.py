"""`mocapdb eval`: held-out accuracy of the engine against the database floor."""
from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from mocapdb.cli import paths as P
from mocapdb.core import domains as D

if TYPE_CHECKING:
    from mocapdb.runtime.engine_config import EngineConfig

REPORT_FORMAT = "mocapdb-eval"  # the first key of an --out report: how a later run knows it may replace it


def add_eval_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("eval", help="accuracy and speed on held-out BVH clips (JSON report)",
                       description="Render held-out clips (not in the database) to 2D from yaws off the "
                                   "database grid, several camera heights, pitches and noise models, "
                                   "reconstruct them with the engine refined and as published, and report "
                                   "accuracy against the truth and against the database's own floor. Either "
                                   "one database (--db, --bvh: JSON report on stdout), "
                                   "--leave-one-subject-out (a database per subject; table on stdout) or "
                                   "--db with --real-take (each camera of a calibrated Pose2Sim take alone, "
                                   "against its multi-camera triangulation; table on stdout) or --db with --world "
                                   "(several held-out people rendered in one camera's world; table on stdout).")
    p.add_argument("--db", type=P.INPUT_DIR, help="database built WITHOUT the held-out clips")
    p.add_argument("--bvh", nargs="+", type=P.INPUT_ANY, help="held-out BVH files or folders")
    p.add_argument("--leave-one-subject-out", nargs="+", type=P.INPUT_ANY, metavar="SOURCE", dest="loso",
                   help="BVH files or folders named SUBJECT_TRIAL.bvh: build a database without each "
                        "subject in turn (in a temporary folder) and evaluate that subject on it")
    p.add_argument("--real-take", metavar="FOLDER", type=P.INPUT_DIR,
                   help="a Pose2Sim take (calibration.toml, triangulated_4cam.trc, openpose_body25b/camNN_json): "
                        "run each camera alone through the engine (needs --db) and score it against the TRC")
    p.add_argument("--live", nargs="+", type=P.INPUT_DIR, metavar="KEYPOINTS",
                   help="keypoint folders of one take's calibrated cameras (`mocapdb detect` of each video, in the "
                        "calibration's camera order): the first run alone as `live` runs it, the stream at each "
                        "--lags lag, the per-frame stream and the published method beside the whole take (and the "
                        "detector's raw world landmarks where the keypoints carry them), against all cameras' "
                        "triangulation, with the database floor (needs --db and --calibration; table on stdout)")
    p.add_argument("--calibration", type=P.INPUT_FILE, metavar="TOML",
                   help="with --live: the cameras' calibration (Pose2Sim/OpenCV calibration.toml)")
    p.add_argument("--fps", type=D.FPS_HZ, help="with --live: the frame rate (Hz) where the folders have no take.json")
    p.add_argument("--lags", type=P.TextArg("a list of lags"), default="0,3,6", metavar="LIST",
                   help="with --live: the stream's lags in frames, comma-separated (default %(default)s)")
    p.add_argument("--videos", nargs="+", type=P.INPUT_DIR, metavar="KEYPOINTS",
                   help="with --world: keypoint folders of real videos (a detector's output with its take.json, "
                        "e.g. data/sample_keypoints/video_*) reconstructed as `reconstruct --floor` does, every track "
                        "of 1 s or more checked for a human size, in front of the camera and on the floor")
    p.add_argument("--world", nargs="+", type=P.INPUT_ANY, metavar="HELDOUT",
                   help="held-out BVH files or folders: takes of several people in one camera (adults, a child, a "
                        "still bystander, one on a 0.4 m box, one cut by the image edge, one 15 m away), each through "
                        "the engine and the whole-take world with the camera height given and not; stature, root and "
                        "floor errors and implausible tracks against the truth (needs --db)")
    p.add_argument("--cameras", nargs="+", type=P.TextArg("a camera name"), metavar="NAME",
                   help="with --real-take: camera names as in its calibration, e.g. cam_01 cam_03 (default all); "
                        "with --live: the calibration's camera of each keypoint folder (default its first ones)")
    p.add_argument("--subjects", type=P.TextArg("a list of subjects"),
                   help="with --leave-one-subject-out: subjects to hold out, e.g. 1,2 (default all)")
    p.add_argument("--max-clips", type=D.MAX_CLIPS, default=D.MAX_CLIPS.default,
                   help="with --leave-one-subject-out: clips per subject, evenly spaced (default %(default)s)")
    p.add_argument("--max-frames", type=D.MAX_FRAMES, default=D.MAX_FRAMES.default,
                   help="with --leave-one-subject-out: frames per clip from its middle, at 24 fps "
                        "(default %(default)s)")
    p.add_argument("--clusters", type=D.CLUSTERS, default=D.CLUSTERS.default,
                   help="with --leave-one-subject-out: k-means K (default %(default)s)")
    p.add_argument("--landmarks", type=D.LANDMARKS, default=D.LANDMARKS.default,
                   help="with --leave-one-subject-out: landmark-MDS landmarks (default %(default)s)")
    p.add_argument("--workers", type=D.WORKERS, default=2,
                   help="with --leave-one-subject-out: processes reading BVH files per build (default %(default)s)")
    p.add_argument("--out", type=P.OUTPUT,
                   help="also write the JSON report to this file (atomically; an existing file is replaced only "
                        "when it is an earlier report, anything else refused before any work)")
    p.add_argument("--quick", action="store_true",
                   help="one database: two yaws and two scenarios; leave-one-subject-out: 2 clips per "
                        "subject, 120 frames, two scenarios; --world: one take per scenario, 48 frames")
    p.add_argument("--weight-2d", type=D.WEIGHT_2D, default=D.WEIGHT_2D.default, help="as in reconstruct")
    p.add_argument("--search", choices=("clustered", "exact"), default="clustered")
    p.add_argument("--universal-body", action="store_true",
                   help="the engine keeps the universal skeleton's proportions (as before own bodies: for comparison)")
    p.set_defaults(run=run_eval)


def run_eval(args: argparse.Namespace) -> int:
    import logging
    from dataclasses import replace

    from mocapdb.builder.config import BuildConfig
    from mocapdb.builder.read_stage import find_sources
    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.core.outputs import check_output_file, output_file
    from mocapdb.evaluation.reconstruction import EvalConfig, evaluate
    from mocapdb.runtime.engine_config import EngineConfig

    if not getattr(args, "quiet", False):  # the evaluation's progress lines (info level) are worth seeing on a long run
        logging.getLogger("mocapdb.evaluation").setLevel(min(logging.INFO, logging.getLogger("mocapdb").level))

    if args.out:
        check_output_file(args.out, _report_file())  # before any work
    engine = EngineConfig(weight_2d=args.weight_2d, search=args.search, own_body=not args.universal_body)
    if args.videos and not args.world:
        raise UsageError("--videos goes with --world")
    if args.cameras and not (args.real_take or args.live):
        raise UsageError("--cameras goes with --real-take or --live")
    if (args.calibration or args.fps or args.lags != "0,3,6") and not args.live:
        raise UsageError("--calibration, --fps and --lags go with --live")
    if args.live:
        report = _live_report(args, engine)
    elif args.world:
        report = _world_report(args, engine)
    elif args.real_take:
        from mocapdb.evaluation.real_take import check_lines, evaluate_real_take, format_table

        if args.bvh or args.loso or not args.db:
            raise UsageError("--real-take needs --db and goes without --bvh and --leave-one-subject-out")
        report = evaluate_real_take(load_database(args.db), args.real_take, engine, args.cameras)
        report["checks"] = check_lines(report)
        print(format_table(report) + "\n\n" + "\n".join(report["checks"]))
    elif args.loso:
        from mocapdb.evaluation.loso import LosoConfig, format_table, leave_one_subject_out

        if args.db or args.bvh:
            raise UsageError("--leave-one-subject-out builds its own databases: leave out --db and --bvh")
        try:
            subjects = tuple(int(s) for s in args.subjects.split(",")) if args.subjects else None
        except ValueError:
            raise UsageError("--subjects takes subject numbers separated by commas, e.g. 1,2") from None
        if min(args.max_clips, args.max_frames, args.clusters, args.landmarks, args.workers) < 1:
            raise UsageError("--max-clips, --max-frames, --clusters, --landmarks and --workers must be positive")
        build = BuildConfig(clusters=args.clusters, landmarks=args.landmarks, workers=args.workers)
        loso = LosoConfig.quick() if args.quick else LosoConfig(max_clips=args.max_clips, max_frames=args.max_frames)
        loso = replace(loso, subjects=subjects, build=build, eval=replace(loso.eval, engine=engine))
        report = leave_one_subject_out(args.loso, loso)
        print(format_table(report))
    else:
        if not args.db or not args.bvh:
            raise UsageError("give --db and --bvh, or --leave-one-subject-out SOURCES")
        config = EvalConfig(engine=engine)
        if args.quick:
            config = replace(config, yaws_deg=config.yaws_deg[:2], scenarios=config.scenarios[:2])
        files = [f for f, _ in find_sources(args.bvh)]
        if not files:
            raise UsageError(f"no .bvh file in {', '.join(args.bvh)}")
        report = evaluate(load_database(args.db), files, config)
        print(_report_json(report))
    if args.out:
        with output_file(args.out, _report_file()) as tmp:
            tmp.write_text(_report_json({"format": REPORT_FORMAT, **report}) + "\n", encoding="utf-8")
    return 0


def _live_report(args: argparse.Namespace, engine: EngineConfig) -> dict:
    """``eval --db DB --live KEYPOINTS... --calibration TOML``: the report of
    :mod:`mocapdb.evaluation.live`, its table and checks printed."""
    from pathlib import Path

    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.evaluation.live import check_lines, evaluate_live, format_table

    if args.bvh or args.loso or args.real_take or args.world or not args.db or not args.calibration:
        raise UsageError("--live needs --db and --calibration and goes without --bvh, --leave-one-subject-out, "
                         "--real-take and --world")
    try:
        lags = tuple(int(v) for v in args.lags.split(","))
    except ValueError:
        raise UsageError(f"--lags takes frame counts separated by commas, e.g. 0,3,6 (got {args.lags!r})") from None
    for lag in lags:
        D.LAG_FRAMES.check(lag, "--lags")
    report = evaluate_live(load_database(args.db), [Path(f) for f in args.live], Path(args.calibration), lags, engine,
                           args.cameras, args.fps)
    report["checks"] = check_lines(report)
    print(format_table(report) + "\n\n" + "\n".join(report["checks"]))
    return report


def _world_report(args: argparse.Namespace, engine: EngineConfig) -> dict:
    """``eval --db DB --world HELDOUT...``: the report of :mod:`mocapdb.evaluation.world`, its tables
    and checks printed."""
    from mocapdb.builder.read_stage import find_sources
    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.evaluation.world import check_lines, evaluate_world, format_table
    from mocapdb.evaluation.world_takes import WorldConfig

    if args.bvh or args.loso or args.real_take or not args.db:
        raise UsageError("--world needs --db and goes without --bvh, --leave-one-subject-out and --real-take")
    files = [f for f, _ in find_sources(args.world)]
    if not files:
        raise UsageError(f"no .bvh file in {', '.join(args.world)}")
    config = WorldConfig.quick(engine=engine) if args.quick else WorldConfig(engine=engine)
    db = load_database(args.db)
    report = evaluate_world(db, files, config)
    report["checks"] = check_lines(report)
    text = format_table(report)
    if args.videos:
        from mocapdb.evaluation.real_footage import check_footage, footage_check_line, footage_table

        report["real_footage"] = [check_footage(db, folder, engine) for folder in args.videos]
        report["checks"].append(footage_check_line(report["real_footage"]))
        text += "\n\n" + footage_table(report["real_footage"])
    print(text + "\n\n" + "\n".join(report["checks"]))
    return report


def _report_file():
    """What ``eval --out`` writes (:class:`mocapdb.core.outputs.OutputFile`): a JSON report whose
    first key is ``"format": REPORT_FORMAT``, so a later run replaces it and nothing else."""
    from mocapdb.core.outputs import OutputFile

    return OutputFile("eval", "a JSON report", f'{{\n  "format": "{REPORT_FORMAT}"'.encode())


def _finite(value):
    """``value`` with every NaN or infinite float (nested in dicts and lists) replaced by None."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _report_json(report: dict) -> str:
    """Strict JSON (undefined figures are null, never a bare NaN)."""
    import json

    return json.dumps(_finite(report), indent=2, allow_nan=False)
