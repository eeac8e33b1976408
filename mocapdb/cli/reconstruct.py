"""`mocapdb reconstruct` (files) and `mocapdb live` (streams, video, camera): the engine's options and runs."""
from __future__ import annotations

import argparse
import logging
import os
import sys

from mocapdb.cli import paths as P
from mocapdb.cli.detect import add_detector_options, add_model_options
from mocapdb.cli.live_video import add_live_video_options, open_live_video
from mocapdb.cli.view import add_page_options, open_page
from mocapdb.core import domains as D
from mocapdb.core import search_rules as S
from mocapdb.core.formats.keypoint_layouts import LAYOUTS

LOG = logging.getLogger("mocapdb.cli")


def _add_engine_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", required=True, type=P.INPUT_DIR,
                   help="database directory written by `mocapdb build`; checked as it loads: the tables read "
                        "(sizes, sha256, row counts, finite values), the search index (sizes, shapes, CRC-32 "
                        "blocks), the projections table it does not read by its size and footer "
                        "(`mocapdb verify DB` checks every byte)")
    p.add_argument("--no-verify", action="store_true",
                   help="skip checking the database files' sha256 and CRC-32 checksums on load (sizes, row counts "
                        "and finite values are still checked)")
    p.add_argument("--keypoints",
                   choices=tuple(LAYOUTS),
                   help="keypoint layout of the input (default: detected from the keypoint count; 25 keypoints: "
                        "BODY_25 or BODY_25B by geometry); data_specs/keypoint_formats.md")
    p.add_argument("--fps", type=D.FPS_HZ,
                   help="input frame rate in Hz when frames carry no time (default: the input folder's take.json, "
                        f"else {D.INPUT_FPS_HZ.default:g} with a warning)")
    focal = p.add_mutually_exclusive_group()
    focal.add_argument("--focal", type=D.FOCAL_PX, metavar="PX",
                       help="input camera focal length in pixels (default: the input folder's take.json, else a "
                            "typical phone main camera: 26 mm equivalent, with a warning)")
    focal.add_argument("--fov", type=D.FOV_DEG, metavar="DEG",
                       help="the camera's horizontal field of view in degrees, instead of --focal")
    focal.add_argument("--focal-35mm", type=D.FOCAL_35MM, metavar="MM",
                       help="the camera's 35 mm-equivalent focal length (as phone specs give it), instead of --focal")
    p.add_argument("--image-size", type=D.IMAGE_SIZE, metavar="WxH",
                   help="input image WIDTHxHEIGHT in pixels (default: the input folder's take.json, else 1920x1080)")
    p.add_argument("--search", choices=("clustered", "exact"), default="clustered",
                   help="two-level search (the method) or brute force over every projection")
    p.add_argument("--clusters-searched", type=D.CLUSTERS_SEARCHED,
                   help=f"i: nearest clusters searched (default: {S.PAPER_CLUSTERS_SEARCHED} on the method's "
                        f"{S.PAPER_CLUSTERS} clusters, more on a database of more clusters: "
                        "mocapdb/core/search_rules.py)")
    p.add_argument("--per-cluster", type=D.PER_CLUSTER, default=D.PER_CLUSTER.default,
                   help="j: projections taken per cluster (default %(default)s)")
    p.add_argument("--subclusters-searched", type=D.SUBCLUSTERS_SEARCHED, metavar="N",
                   help="the searched clusters' sub-clusters searched, per cluster: their members are those of "
                        "the N x --clusters-searched sub-clusters with the nearest representatives (default: "
                        f"{S.PAPER_CLUSTERS_SEARCHED} up to the method's "
                        f"{S.PAPER_CLUSTERS * S.PROJECTIONS_PER_CLUSTER:,} projections, more on larger databases: "
                        "mocapdb/core/search_rules.py)")
    p.add_argument("--grid-descents", type=D.GRID_DESCENTS, default=D.GRID_DESCENTS.default,
                   help="the best N candidates each move to a nearer neighbouring frame or yaw while there is one "
                        "(default %(default)s; 0: the method's candidates only)")
    p.add_argument("--window-weights", type=D.WINDOW_WEIGHTS, default=D.WINDOW_WEIGHTS.default, metavar="LIST",
                   help="weights of the last w reconstructed frames, most recent first (default %(default)s)")
    p.add_argument("--weight-2d", type=D.WEIGHT_2D, default=D.WEIGHT_2D.default,
                   help="weight of the 2D (Eq. 1) distance added to the temporal cost (default %(default)s; "
                        "0 is the method)")
    p.add_argument("--min-cutoff", type=D.CUTOFF_HZ,
                   help=f"1€ filter min cutoff for rotations, Hz (default: {D.REFINED_MIN_CUTOFF_HZ.default:g}; "
                        f"{D.RETRIEVED_MIN_CUTOFF_HZ.default:g} with --no-refine)")
    p.add_argument("--beta", type=D.BETA, help=f"1€ filter beta for rotations (default: {D.REFINED_BETA.default:g}; "
                                               f"{D.RETRIEVED_BETA.default:g} with --no-refine)")
    p.add_argument("--no-refine", action="store_true",
                   help="output the retrieved database pose as it is (the method as published) instead of "
                        "fitting it to the keypoints")
    p.add_argument("--subject-height", type=D.PerTrackArg(D.SUBJECT_HEIGHT_M), metavar="[TRACK=]METRES",
                   action="append", default=[],
                   help="a person's standing height in metres: METRES for everyone (sets the skeleton's size and "
                        "so the depth; default: the universal skeleton's height in the stream, each person's own "
                        "from the take's world in the track files), TRACK=METRES for one track of the track files "
                        "(repeatable, e.g. "
                        "--subject-height 2=1.62 --subject-height 5=1.10)")
    p.add_argument("--camera-height", type=D.CAMERA_HEIGHT_M, metavar="METRES",
                   help="the camera's height above a flat floor the people stand on: each person's size and "
                        "depth are measured from their feet (data_specs/stream_output.md, data_specs/world.md)")
    p.add_argument("--universal-body", action="store_true",
                   help="keep the universal skeleton's proportions (default: each track's own bone proportions "
                        "measured from its 2D)")
    p.add_argument("--no-smoothing", action="store_true", help="turn the 1€ filters off")
    p.add_argument("--lag-frames", type=D.LAG_FRAMES, default=D.LAG_FRAMES.default, metavar="N",
                   help="the stream's lag: each frame's line written N frames late, through the online whole take "
                        "(planted feet locked, the root carried by them, speed limits, the size settled) with "
                        "the rotations' Kalman filter smoothed over the N frames after it: a latency of N / fps "
                        "for steadier, more accurate motion (default %(default)s: causal, the filter predicting; "
                        "data_specs/stream_output.md)")
    p.add_argument("--per-frame-stream", action="store_true",
                   help="write the stream as the per-frame engine gives it, without the online whole take "
                        "(no foot locking, no speed limits; no --lag-frames)")
    p.add_argument("--no-translation", action="store_true", help="keep the pelvis at the origin")
    p.add_argument("--no-yaw-refinement", action="store_true", help="keep the database's yaw grid (12° steps)")
    files = p.add_argument_group("track files (data_specs/stream_output.md)")
    files.add_argument("--format", default="bvh", type=P.TextArg("a list of formats"), metavar="LIST",
                       help="files per track, comma-separated: bvh (animation), trc (OpenSim/Pose2Sim markers, "
                            "metres), csv (joint positions, metres); default bvh")
    files.add_argument("--rig", choices=("universal", "humanoid"), default="humanoid",
                       help="BVH rig: humanoid, with head, clavicle, hand, foot and toe bones under Mixamo names for "
                            "Unity Humanoid, HumanIK and Blender (the default), or universal: mocapdb's 11 joints, "
                            "what `mocapdb build` reads back exactly")
    frame = files.add_mutually_exclusive_group()
    frame.add_argument("--floor", dest="view_frame", action="store_false", default=False,
                       help="the track files stand on the world's floor: levelled, feet on y = 0 (y up), "
                            "every track in one world, the origin on the floor under the camera, the camera's pose "
                            "in world.json (the default)")
    frame.add_argument("--view-frame", action="store_true",
                       help="the track files in the camera's view frame instead: the camera at the origin, "
                            "looking along -z (what versions before 2026-11-28 wrote without --floor)")
    files.add_argument("--bvh-unit", choices=("m", "cm"), default="m", help="length unit of the BVH files (default m)")
    files.add_argument("--bvh-start", choices=("input", "track"), default="input",
                       help="BVH frame 1: the input's first frame, the track's first pose held until it starts, so "
                            "every BVH lines up with the video (default), or the track's own first frame")
    files.add_argument("--smoothing-hz", type=D.SMOOTHING_HZ, default=D.SMOOTHING_HZ.default, metavar="HZ",
                       help="the track files are each track fitted over the whole take: motion slower than HZ "
                            "kept, jitter faster removed, without lag; planted feet held still, no foot below the "
                            "floor (default %(default)s; 0: no smoothing)")
    files.add_argument("--per-frame", action="store_true",
                       help="write the track files from the per-frame output (as the stream), not the whole take")
    p.add_argument("--keep-static", action="store_true",
                   help="also write BVH files for tracks whose keypoints never moved (posters, false detections)")
    limits = p.add_argument_group("limits (0: no limit; data_specs/stream_output.md)")
    limits.add_argument("--max-tracks", type=D.MAX_TRACKS, default=D.MAX_TRACKS.default,
                        help="tracks alive at once; further detections are not tracked, counted (default %(default)s)")
    limits.add_argument("--max-new-tracks-per-min", type=D.MAX_NEW_TRACKS_PER_MIN,
                        default=D.MAX_NEW_TRACKS_PER_MIN.default,
                        help="tracks started per minute (live: of arrival time; reconstruct: of the input's time); "
                             "further detections wait untracked, counted (default %(default)s)")
    limits.add_argument("--max-bvh-files", type=D.MAX_BVH_FILES, default=D.MAX_BVH_FILES.default,
                        help="BVH files per run; further tracks stay in the stream only, counted (default %(default)s)")
    limits.add_argument("--min-track-s", type=D.MIN_TRACK_S, default=D.MIN_TRACK_S.default,
                        help="a track with fewer seconds of BVH frames gets no BVH file, counted (default %(default)s)")
    limits.add_argument("--bvh-part-min", type=D.BVH_PART_MIN, default=D.BVH_PART_MIN.default,
                        help="a longer track is written as track_<id>_part<k>.bvh parts of this many minutes, "
                             "each as soon as it is complete (default %(default)s)")


def _is_video(source: str) -> bool:
    """``live --source`` names a video file or a camera (not a keypoint stream)."""
    from mocapdb.runtime.stream.video_input import is_video_source

    return is_video_source(source)


def resolve_take(args: argparse.Namespace, source: str) -> None:
    """Fill ``args.fps``, ``args.image_size`` and ``args.focal`` from what the input says where they
    were not given: ``source/take.json`` (what `mocapdb detect` wrote) for a folder, the video itself
    for ``live --source VIDEO --model``; the defaults where nothing says. An option that contradicts
    it is an error naming both. ``args.camera_sources`` says where each came from (given, read,
    default); ``args.fps`` stays None when neither gave it (the warning stays)."""
    from dataclasses import replace
    from pathlib import Path

    from mocapdb.cli.scene_evidence import use_scene
    from mocapdb.core.formats.camera_path import read_camera_path
    from mocapdb.core.formats.folder_size import size_of_keypoint_folder
    from mocapdb.core.formats.take import TAKE_FILE, TakeInfo, read_take, resolve_camera

    if getattr(args, "blazepose", None) and _is_video(source):
        take, where = _video_take(source), source
    else:
        take = read_take(source) if source and Path(source).is_dir() else None
        where = str(Path(source) / TAKE_FILE)
    given_size = args.image_size
    seen_size = None if given_size or (take and take.image_size) else size_of_keypoint_folder(source)
    if seen_size:
        take = TakeInfo(None, seen_size, None, source) if take is None else replace(take, image_size=seen_size)
    settings = resolve_camera(take, where, args.fps, given_size, _given_focal(args, given_size, take))
    if seen_size:
        settings.sources["image_size"] = "keypoints"
    if settings.sources["fps"] != "default":
        args.fps = settings.fps
    args.image_size = settings.image_size
    args.focal = settings.focal_px
    args.camera_sources = settings.sources
    args.camera_path = read_camera_path(source)   # a turning camera's (data_specs/world.md), if detect wrote one
    use_scene(args, source)   # the scene's lines (scene.json): the focal where none was given (else the guess, warned)


def _given_focal(args: argparse.Namespace, size: tuple[int, int] | None, take) -> float | None:
    """``--focal`` in pixels, or ``--fov``/``--focal-35mm`` converted for the image (the given size,
    else the take's, else the default); None when none was given (each checked by its domain)."""
    from mocapdb.core.formats.take import DEFAULTS, focal_from_35mm, focal_from_fov

    size = size or (take.image_size if take is not None and take.image_size else DEFAULTS["image_size"])
    fov, focal_35mm = getattr(args, "fov", None), getattr(args, "focal_35mm", None)
    if fov is not None:
        return focal_from_fov(fov, size)
    if focal_35mm is not None:
        return focal_from_35mm(focal_35mm, size)
    return args.focal


def _video_take(path: str):
    """A video file's frame rate and image size, as a take description (the first frame decoded)."""
    from mocapdb.core.formats.take import TakeInfo
    from mocapdb.detect.video import VideoReader

    reader = VideoReader(path)
    try:
        first = next(reader.frames())
        size = (int(first.image.shape[1]), int(first.image.shape[0]))
        return TakeInfo(fps=reader.fps, image_size=size, frames=reader.frame_count, source=path)
    finally:
        reader.close()


def subject_heights(args: argparse.Namespace) -> dict[int | None, float]:
    """``--subject-height`` as track → metres (None: everyone; the last given wins)."""
    return {track: metres for track, metres in args.subject_height}


def _engine(args: argparse.Namespace):
    from dataclasses import replace

    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.database_reader import load_database
    from mocapdb.core.formats.take import DEFAULTS, default_focal_px
    from mocapdb.runtime.engine import Engine
    from mocapdb.runtime.engine_config import EngineConfig
    from mocapdb.runtime.filters import REFINED_ROTATION_DEFAULTS, OneEuroParams

    width, height = args.image_size or DEFAULTS["image_size"]
    focal = args.focal if args.focal is not None else default_focal_px((width, height))
    default = OneEuroParams() if args.no_refine else REFINED_ROTATION_DEFAULTS
    try:
        rotation_filter = OneEuroParams(
            min_cutoff_hz=default.min_cutoff_hz if args.min_cutoff is None else args.min_cutoff,
            beta=default.beta if args.beta is None else args.beta)
        config = EngineConfig(search=args.search, n_clusters=args.clusters_searched, per_cluster=args.per_cluster,
                              grid_descents=args.grid_descents, subclusters=args.subclusters_searched,
                              window_weights=tuple(args.window_weights), weight_2d=args.weight_2d, focal_px=focal,
                              image_size=(width, height), fps=args.fps or DEFAULTS["fps"],
                              translation=not args.no_translation,
                              refine_yaw=not args.no_yaw_refinement, refine=not args.no_refine,
                              subject_height_m=subject_heights(args).get(None),
                              camera_height_m=args.camera_height,
                              smoothing=not args.no_smoothing and args.per_frame_stream,
                              own_body=not args.universal_body,
                              rotation_filter=rotation_filter, keep_take=not args.per_frame)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if getattr(args, "still_image", False):   # one sighting is all a photo has (data_specs/stream_output.md)
        config.tracker = replace(config.tracker, min_hits=1)
    return Engine(load_database(args.db, verify_checksums=not args.no_verify, projections=False), config)


def _session(args: argparse.Namespace, sink_spec: str, strict: bool, bvh_dir=None, page=None):
    from pathlib import Path

    from mocapdb.core.errors import UsageError
    from mocapdb.core.exports import TrackExport
    from mocapdb.runtime.engine_config import TrackLimits
    from mocapdb.runtime.stream.session import FrameParser, Session
    from mocapdb.runtime.stream.session_options import SessionOptions
    from mocapdb.runtime.stream.session_summary import SessionSummary
    from mocapdb.runtime.stream.transport import StreamStats, TeeSink, open_sink
    from mocapdb.runtime.take_params import TakeParams
    from mocapdb.runtime.world.subject import parse_people

    summary = SessionSummary(stream=StreamStats())
    if bvh_dir is None and getattr(args, "bvh_dir", None):  # live --bvh-dir
        bvh_dir = Path(args.bvh_dir)
    try:  # checked before the database is loaded
        limits = TrackLimits(args.max_tracks, args.max_new_tracks_per_min)
        export = TrackExport(tuple(f.strip().lower() for f in args.format.split(",") if f.strip()), args.bvh_unit,
                             args.rig, not args.view_frame, pad_to_input=args.bvh_start == "input")
        still = getattr(args, "still_image", False)   # a photo is still and lasts no time: neither check applies
        options = SessionOptions(strict=strict, fps_given=args.fps is not None,
                                 keep_static=args.keep_static or still,
                                 bvh_dir=bvh_dir, export=export, max_bvh_files=args.max_bvh_files,
                                 min_track_s=0.0 if still else args.min_track_s, bvh_part_min=args.bvh_part_min,
                                 rate_by_arrival=not strict, write_in_background=not strict,
                                 take=None if args.per_frame else TakeParams(smoothing_hz=args.smoothing_hz),
                                 shared_floor=strict, camera_height_m=args.camera_height,
                                 subject_heights_m=subject_heights(args),
                                 lag_frames=args.lag_frames, online_take=not args.per_frame_stream,
                                 camera_sources=getattr(args, "camera_sources", {}), scene=getattr(args, "scene", None),
                                 people=parse_people(getattr(args, "people", "all")),
                                 camera_path=getattr(args, "camera_path", None))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    engine = _engine(args)
    engine.config.limits = limits
    sink = open_sink(sink_spec, summary.stream, getattr(args, "vmc_track", None))
    if page is not None:  # live --view: the page's sink beside the command's own
        sink = TeeSink([sink, page])
    return Session(engine, sink, FrameParser(args.keypoints), summary, options)


def add_reconstruct_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("reconstruct", help="2D keypoint files → 3D skeletons (JSON lines) and BVH per person",
                       description="Reconstruct every frame of a folder of OpenPose JSON files or a JSON-lines "
                                   "keypoint file; writes OUT/result.jsonl and OUT/track_<id>.bvh.")
    p.add_argument("input", type=P.INPUT_ANY,
                   help="folder of OpenPose JSON frames, a .jsonl/.ndjson file, an MMPose prediction "
                        ".json, or a .npy/.npz keypoint array [T, K, 3] or [T, P, K, 3] (x, y, confidence) "
                        "or RTMLib keypoints + scores (layout detected from the keypoint count)")
    p.add_argument("--out", required=True, type=P.OUTPUT_DIR, help="output folder")
    p.add_argument("--preview", action="store_true",
                   help="also write OUT/preview.png: a contact sheet of 12 frames of the track files, re-projected "
                        "over the input keypoints beside a 3D view on the take's floor, labelled with their sizes "
                        "(`mocapdb render` draws every frame)")
    p.add_argument("--people", type=P.TextArg("main, all or track ids"), default="all", metavar="main|all|ID,...",
                   help="which tracks get files: all (default), main (the take's subject: seen long, large, near "
                        "the middle and moving; the summary and OUT/world.json name it) or track ids, e.g. 1,3; "
                        "every track still counts in the take's world")
    _add_engine_options(p)
    p.set_defaults(run=run_reconstruct)


def run_reconstruct(args: argparse.Namespace) -> int:
    from pathlib import Path

    from mocapdb.core.formats.keypoint_arrays import KEYPOINT_FILE_SUFFIXES, read_keypoint_file
    from mocapdb.core.outputs import output_folder

    resolve_take(args, args.input)
    frames = None  # a keypoint file (.npy, .npz, MMPose .json) is read and checked before any output
    if Path(args.input).suffix.lower() in KEYPOINT_FILE_SUFFIXES and not Path(args.input).is_dir():
        frames = read_keypoint_file(args.input, args.keypoints, args.fps)
    with output_folder(args.out) as tmp:
        session, interrupted = _reconstruct_into(args, tmp, frames)
        summary = session.summary
        if args.preview and summary.frames:
            _preview(args, tmp)
    print(f"wrote {Path(args.out) / 'result.jsonl'} and {len(summary.bvh_files)} track file(s) in {args.out}"
          + (f"; preview {Path(args.out) / 'preview.png'}" if args.preview else ""))
    print(summary.report())
    if interrupted:
        print(f"mocapdb reconstruct: interrupted after {summary.frames} frames; wrote what was done", file=sys.stderr)
        return 130
    return 0


def _preview(args: argparse.Namespace, out_dir) -> None:
    """OUT/preview.png: a contact sheet of the run (:func:`mocapdb.render.contact_sheet.contact_sheet`) as
    `mocapdb render` draws it: the track files just written (re-projected, and in 3D on the take's
    floor, labelled with their sizes), or the stream when no track got files (said on stderr)."""
    from pathlib import Path

    from mocapdb.render.contact_sheet import contact_sheet

    contact_sheet(out_dir, args.input, out_dir / "preview.png", focal=args.focal, image_size=args.image_size,
                  name=str(Path(args.out) / "result.jsonl"),
                  note=lambda text: print(f"mocapdb reconstruct: preview: {text}", file=sys.stderr))


def _reconstruct_into(args: argparse.Namespace, out_dir, frames):
    """Run the session into ``out_dir``; returns it (finished) and whether Ctrl-C stopped it early."""
    from itertools import chain, islice

    from mocapdb.core.errors import UsageError
    from mocapdb.core.formats.folder_size import frames_in_input
    from mocapdb.core.progress import progress
    from mocapdb.runtime.stream.session import run_arrays, run_offline
    from mocapdb.runtime.stream.transport import open_source

    if frames is not None:
        first = list(islice(frames, 2))
        total, frames = (len(first) if len(first) < 2 else None), chain(first, frames)
    else:
        total = frames_in_input(args.input)
    args.still_image = total == 1   # a photo: tracked from its one sighting (_engine, _session)
    if args.still_image:
        print("mocapdb reconstruct: one frame (a photo): each person is a track from that one sighting and gets "
              "its files although still", file=sys.stderr)
    session = _session(args, str(out_dir / "result.jsonl"), strict=True, bvh_dir=out_dir)
    interrupted = False
    try:
        if frames is not None:
            run_arrays(session, progress(frames, desc="reconstruct", unit="frame"))
        else:
            run_offline(session, open_source(args.input, stats=session.summary.stream),
                        lambda messages: progress(messages, total=total, desc="reconstruct", unit="frame"))
    except KeyboardInterrupt:
        interrupted = True
    finally:
        summary = session.finish()
    if not summary.frames:
        raise UsageError(f"no keypoint frame in {args.input}")
    return session, interrupted


def add_live_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("live", help="reconstruct a live keypoint stream",
                       description="Read keypoints as they arrive (a folder being written by a detector, "
                                   "'-' for stdin, tcp://HOST:PORT or udp://HOST:PORT to listen on), write one "
                                   "JSON line per frame to the sink, and a BVH per track on exit (Ctrl-C).")
    p.add_argument("--source", required=True, type=P.STREAM_SOURCE,
                   help="folder of keypoint files, a .jsonl file, '-', tcp://HOST:PORT or udp://HOST:PORT; or a "
                        "video file or a camera index (digits), whose people BlazePose (or --model) detects")
    add_model_options(p)
    p.add_argument("--sink", default="-", type=P.STREAM_SINK,
                   help="'-' (stdout), a file, tcp://HOST:PORT or udp://HOST:PORT: the JSON lines; or one person's "
                        "avatar as OSC over UDP: vmc://HOST[:PORT] (the VMC protocol: VSeeFace, Warudo, VNyan, "
                        "EVMC4U; port 39539 by default) or vrchat://HOST[:PORT] (VRChat's OSC trackers; port 9000 by "
                        "default); docs/guide_avatars.md")
    p.add_argument("--vmc-track", type=D.TRACK_ID, metavar="ID",
                   help="vmc:// sink: the track to send (default: the main one, kept while it is in the frame)")
    p.add_argument("--bvh-dir", type=P.OUTPUT,
                   help="folder for the tracks' BVH files, written as tracks end (a folder already holding "
                        "track files is refused: nothing is written over)")
    p.add_argument("--idle-timeout", type=D.IDLE_TIMEOUT_S,
                   help="stop after this many seconds without a message (any source; default: never)")
    p.add_argument("--client-timeout", type=D.CLIENT_TIMEOUT_S, default=D.CLIENT_TIMEOUT_S.default,
                   help="tcp:// source: close a client that sends no complete line for this many seconds "
                        "(default %(default)s)")
    p.add_argument("--max-clients", type=D.MAX_CLIENTS, default=D.MAX_CLIENTS.default,
                   help="tcp:// source: simultaneous clients; further connections are refused (default %(default)s)")
    p.add_argument("--max-rate", type=D.MAX_RATE_HZ, default=D.MAX_RATE_HZ.default,
                   help="tcp:// and udp:// sources: messages per second per sender address, the excess "
                        "dropped and counted; 0: no limit (default %(default)s)")
    add_live_video_options(p)
    p.add_argument("--buffer", type=D.BUFFER_MESSAGES, default=D.BUFFER_MESSAGES.default,
                   help="messages of a live stream (tcp, udp, stdin) buffered before the oldest is dropped (default "
                        "%(default)s); a folder of frames or a .jsonl file is read at the engine's pace, nothing "
                        "dropped")
    add_page_options(p, "--view")
    add_detector_options(p, "crops")
    _add_engine_options(p)
    p.set_defaults(run=run_live)


def run_live(args: argparse.Namespace) -> int:
    """Stream until the source ends, a signal or a sink failure (exit 1); the BVH files are written
    in every case, with the signal handlers kept (further signals ignored) until they are."""
    import threading
    from pathlib import Path

    from mocapdb.cli.signals import install_stop_handlers
    from mocapdb.core.outputs import check_no_track_files
    from mocapdb.runtime.stream.latency import steady_stream
    from mocapdb.runtime.stream.session import SinkError, run_live
    from mocapdb.runtime.stream.transport import NetworkLimits, check_sink, open_source
    from mocapdb.runtime.stream.video_input import run_video

    limits = NetworkLimits(args.max_clients, args.client_timeout, args.max_rate)   # checked before any work
    check_sink(args.sink, args.vmc_track)
    if args.bvh_dir:
        check_no_track_files(args.bvh_dir)
    resolve_take(args, args.source)
    server = feed = None
    if args.view is not None:  # the page first: its address is printed before the database loads
        from mocapdb.view.live import LiveFeed, PageSink
        from mocapdb.view.server import ViewServer

        feed = LiveFeed()
        server = ViewServer(args.view, feed=feed)
        open_page(server.url, args, "live")
    try:
        session = _session(args, args.sink, strict=False, page=None if feed is None else PageSink(feed))
    except BaseException:
        if server is not None:
            server.close()
        raise
    stop, video = threading.Event(), None
    with install_stop_handlers(stop, force_quit=False):
        try:
            if _is_video(args.source):
                with steady_stream():
                    video = open_live_video(args, session.summary.stream)
                    run_video(session, video, stop)
            else:
                source = open_source(args.source, stats=session.summary.stream, follow=True,
                                     idle_timeout_s=args.idle_timeout, limits=limits)
                with steady_stream():
                    run_live(session, source, stop, args.buffer)
        except SinkError:
            pass  # recorded in the summary; reported below
        finally:
            try:
                summary = session.finish(Path(args.bvh_dir) if args.bvh_dir else None)
            finally:
                if server is not None:
                    server.close()
        print(summary.report(), file=sys.stderr)
        if feed is not None:
            print(feed.report(), file=sys.stderr)
        if source_line := summary.stream.source_report():
            print(source_line, file=sys.stderr)
        if video is not None:
            print(video.report(), file=sys.stderr)
    if summary.sink_error is None:
        return 0
    if args.sink == "-":  # a closed pipe: nothing more can reach it, not even Python's flush at exit
        try:
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        except (OSError, ValueError):  # stdout is not a file descriptor (tests capture it)
            pass
    print(f"mocapdb live: error: the sink {args.sink} failed ({summary.sink_error}): the stream stopped there; "
          f"wrote {len(summary.bvh_files)} BVH file(s)", file=sys.stderr)
    return 1
