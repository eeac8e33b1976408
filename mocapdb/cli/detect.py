"""`mocapdb detect`: video or camera → OpenPose JSON keypoints with an ONNX pose model."""
from __future__ import annotations

import argparse
import logging
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from mocapdb.cli import paths as P
from mocapdb.core import domains as D
from mocapdb.detect.options import (
    BLAZEPOSE_VARIANTS,
    DEFAULT_BLAZEPOSE,
    DEFAULT_CONF,
    DEFAULT_CROP_PX,
    DEFAULT_FULL_EVERY,
    DEFAULT_HAND_MODEL,
    DEFAULT_INPUT_SIZE,
    DEFAULT_IOU,
    DETECTORS,
    FACE,
    FETCH_COMMAND,
    HAND_MODELS,
    HANDS,
)

if TYPE_CHECKING:
    from mocapdb.detect.tracked import FastPath

LOG = logging.getLogger(__name__)


def add_model_options(p: argparse.ArgumentParser) -> None:
    """``--blazepose VARIANT`` (the default detector), ``--model POSE.onnx`` (an export instead), ``--hands``,
    ``--hand-model full|lite``, ``--face`` and ``--max-people N``."""
    p.add_argument("--blazepose", choices=BLAZEPOSE_VARIANTS, default=DEFAULT_BLAZEPOSE,
                   help="BlazePose landmark model, the detector used without --model (prepared by "
                        f"`{FETCH_COMMAND} [VARIANT]`; default %(default)s)")
    p.add_argument("--model", metavar="POSE.onnx", type=P.INPUT_FILE,
                   help="a YOLO-pose or RTMO ONNX export instead of BlazePose (data_specs/pose_models.md)")
    p.add_argument("--hands", action="store_true",
                   help="BlazePose only: also 21 points per hand from MediaPipe's hand landmark model on crops the "
                        f"pose's hand points give (prepared by `{FETCH_COMMAND} {HANDS}`; data_specs/pose_models.md, "
                        "\"Hands\")")
    p.add_argument("--hand-model", choices=HAND_MODELS, default=DEFAULT_HAND_MODEL,
                   help="with --hands: MediaPipe's hand landmark model, full or lite. lite takes about half the CPU "
                        "time a hand (2.2 against 4.3 ms here) but finds fewer small hands (73 %% of those full finds "
                        "on a 1080 x 1920 take), its finger curls differ from full's by 13-18 degrees on average and "
                        "it misreads some thumbs (gestures on MediaPipe's photos: 11 of 12, full 12); both prepared by "
                        f"`{FETCH_COMMAND} {HANDS}`; data_specs/pose_models.md, \"Hands\" (default %(default)s)")
    p.add_argument("--face", action="store_true",
                   help="BlazePose only: also the face mesh (468 points) from MediaPipe's face landmark model on crops "
                        f"the pose's face points give (prepared by `{FETCH_COMMAND} {FACE}`): the head turns, nods and "
                        "tilts with it in the BVH, the stream and over VMC, with blinks and the mouth's opening "
                        "(data_specs/head.md, \"The head from the mesh\", \"Face mesh\")")
    p.add_argument("--max-people", type=D.MAX_PEOPLE, metavar="N",
                   help="follow at most N people, no landmark run spent on the others (BlazePose: the most "
                        "prominent, region area x score, kept until lost or one twice as prominent comes; an export: "
                        "the N best-scoring per frame; default all)")


def add_detector_options(p: argparse.ArgumentParser, detector: str) -> None:
    """The detector's fast-path options (``detect`` and ``live --model``), ``--detector`` defaulting to
    ``detector`` (one of :data:`~mocapdb.detect.options.DETECTORS`); data_specs/pose_models.md."""
    group = p.add_argument_group("detection with --model (data_specs/pose_models.md, \"Following the people\")")
    group.add_argument("--detector", choices=DETECTORS, default=detector,
                       help="full: the model on every whole frame; crops: on one crop around the people of the "
                            "frame before, the whole frame every --full-every frames and whenever someone is lost "
                            f"(default {detector})")
    group.add_argument("--crop-size", type=D.MODEL_INPUT_PX, default=DEFAULT_CROP_PX, metavar="PX",
                       help="largest model input side in pixels for a crop, rounded up to a multiple of 32 (a model "
                            "with a dynamic input size only; default %(default)s)")
    group.add_argument("--full-every", type=D.DETECT_EVERY, default=DEFAULT_FULL_EVERY, metavar="N",
                       help="with crops: the whole frame at least every N frames, to find people coming in "
                            "(default %(default)s)")
    group.add_argument("--model-every", type=D.MODEL_EVERY, default=D.MODEL_EVERY.default, metavar="N",
                       help="run the model on every N-th frame only; the frames between get the keypoints carried "
                            "by optical flow (default %(default)s: the model on every frame)")


def fast_path(args: argparse.Namespace) -> FastPath:
    """The :class:`~mocapdb.detect.tracked.FastPath` the options of :func:`add_detector_options` ask for."""
    from mocapdb.detect.tracked import FastPath

    return FastPath(crops=args.detector == "crops", crop_px=args.crop_size, full_every=args.full_every,
                    model_every=args.model_every)


def add_detect_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``detect`` subcommand; its ``run`` returns the exit code (2 for a user error)."""
    p = sub.add_parser("detect", help="video or camera → 2D keypoints of several people (OpenPose JSON per frame)",
                       description="Decode a video (or a camera) with OpenCV, find the people of each frame with "
                                   "BlazePose (33 landmarks each, heels, toes and hands included; onnxruntime, CPU) "
                                   "or a YOLO-pose/RTMO export given with --model, and write "
                                   "OUT/<video>_<frame>_keypoints.json (BlazePose: the mediapipe33 layout; exports: "
                                   "OpenPose's COCO-18), OUT/take.json and OUT/camera_path.json (the camera's "
                                   "rotation per frame, from the background), ready for `mocapdb reconstruct` or "
                                   "`live`. Models and layouts: data_specs/pose_models.md.")
    p.add_argument("video", nargs="?", type=P.INPUT_FILE, help="video file (any format OpenCV's FFmpeg decodes)")
    p.add_argument("--camera", type=D.CAMERA_INDEX, metavar="N", help="read camera N instead of a file (Ctrl-C ends)")
    add_model_options(p)
    p.add_argument("--out", required=True, metavar="DIR", type=P.OUTPUT_DIR,
                   help="folder for the JSON files, written as the video is read (created if missing; an "
                        "earlier detect output there is replaced, a folder holding other files refused)")
    p.add_argument("--every", type=D.FRAMES_EVERY, default=D.FRAMES_EVERY.default, metavar="N",
                   help="detect every N-th frame only (default %(default)s)")
    p.add_argument("--conf", type=D.CONF, default=DEFAULT_CONF,
                   help="least person score kept (default %(default)s)")
    p.add_argument("--iou", type=D.IOU, default=DEFAULT_IOU, help="NMS IoU threshold (default %(default)s)")
    p.add_argument("--input-size", type=D.MODEL_INPUT_PX, default=DEFAULT_INPUT_SIZE, metavar="PX",
                   help="input side in pixels for models with a dynamic input size (default %(default)s)")
    add_detector_options(p, "full")
    p.set_defaults(run=run_detect)
    return p


def run_detect(args: argparse.Namespace) -> int:
    """``mocapdb detect``: 0 on success, also for a video file that ends before its declared frame
    count (every frame read is written; a warning says how many of how many) or whose timestamps are
    missing or jump (warned, :class:`~mocapdb.detect.video.VideoReader`); DetectError (exit 2) for a
    user error; 130 if a video file was interrupted before its end."""
    from mocapdb.cli.signals import install_stop_handlers
    from mocapdb.core.outputs import check_output_folder
    from mocapdb.detect.camera_motion import BackgroundMotion
    from mocapdb.detect.detectors import open_detector
    from mocapdb.detect.errors import DetectError
    from mocapdb.detect.openpose_out import DETECT_FILES, FrameWatcher, detect_video
    from mocapdb.detect.scene import SceneSampler
    from mocapdb.detect.video import VideoReader

    if (args.video is None) == (args.camera is None):
        raise DetectError("give either a VIDEO file or --camera N")
    if args.every < 1:
        raise DetectError("--every must be at least 1")
    check_output_folder(args.out, DETECT_FILES)  # before any work; emptied once the model and the video open
    model = open_detector(args.model, args.blazepose, conf=args.conf, iou=args.iou, max_people=args.max_people,
                          input_size=args.input_size, fast=fast_path(args), hands=args.hands,
                          hand_model=args.hand_model, faces=args.face)
    reader = VideoReader(args.camera if args.camera is not None else args.video)
    stop = threading.Event()
    try:
        with install_stop_handlers(stop):
            scene_fps = reader.fps / args.every if reader.fps else None
            watchers: list[FrameWatcher] = [BackgroundMotion(), SceneSampler(scene_fps)]
            summary = detect_video(reader, model, Path(args.out), args.every, stop, watchers=watchers)
    finally:
        reader.close()
    print(f"wrote {len(summary.people)} file(s) in {args.out} (model {model.describe()})")
    print(summary.report())
    for warning in summary.warnings:
        LOG.warning("%s", warning)
    return 130 if summary.interrupted and not reader.is_camera else 0


def add_models_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds ``models``: ``models fetch [VARIANT...]`` prepares BlazePose, ``models list`` says what is ready."""
    p = sub.add_parser("models", help="prepare the BlazePose models (once, from the package index)",
                       description="fetch: download the pinned MediaPipe packages that carry BlazePose (Apache-2.0) "
                                   "from the package indexes, check their sha256, convert the models to ONNX with "
                                   "mocapdb's own converter and keep them in $MOCAPDB_MODELS (default "
                                   "~/.cache/mocapdb/models). list: the models prepared. Nothing is downloaded at "
                                   "run time. Sources and pins: data_specs/pose_models.md.")
    p.add_argument("action", choices=("fetch", "list"))
    # a str default: argparse checks an empty nargs="*" positional's default against the choices
    p.add_argument("variants", nargs="*", choices=(*BLAZEPOSE_VARIANTS, HANDS, FACE), default=DEFAULT_BLAZEPOSE,
                   metavar="VARIANT", help=f"landmark models to prepare: {', '.join(BLAZEPOSE_VARIANTS)} (default "
                                           f"{DEFAULT_BLAZEPOSE}; the person detector always), and {HANDS}: the hand "
                                           f"landmark models ({', '.join(HAND_MODELS)}) of detect/live --hands, "
                                           f"{FACE}: the face landmark model of detect --face (with "
                                           f"{DEFAULT_BLAZEPOSE} when no variant is named)")
    p.set_defaults(run=run_models)
    return p


def run_models(args: argparse.Namespace) -> int:
    """``mocapdb models fetch|list``: 0 when every model asked for is ready; DetectError otherwise."""
    from mocapdb.detect.errors import DetectError
    from mocapdb.detect.model_store import (
        EXTRA_MODELS,
        blazepose_paths,
        extra_model_path,
        fetch_models,
        hand_landmark_path,
        models_dir,
    )

    named = (args.variants,) if isinstance(args.variants, str) else tuple(args.variants)
    variants = tuple(v for v in named if v in BLAZEPOSE_VARIANTS) or (DEFAULT_BLAZEPOSE,)
    extras = tuple(v for v in EXTRA_MODELS if v in named)
    if args.action == "fetch":
        paths = fetch_models(variants, extras=extras)
        extra = "".join(f" and the {e} landmarks" for e in extras)
        print(f"BlazePose {', '.join(variants)}{extra} ready in {models_dir()} ({len(paths)} models)")
        return 0
    # (what, where it is, the `models fetch` name that prepares it)
    models = [(v, lambda v=v: blazepose_paths(v)[1], v) for v in BLAZEPOSE_VARIANTS]
    models += [(f"{HANDS} {v}", lambda v=v: hand_landmark_path(v), HANDS) for v in HAND_MODELS]
    models += [(name, lambda name=name: extra_model_path(name), name) for name in EXTRA_MODELS if name != HANDS]
    ready = []
    for what, path_of, fetch_name in models:
        try:
            ready.append(f"{what}: {path_of()}")
        except DetectError:
            ready.append(f"{what}: not prepared (`{FETCH_COMMAND} {fetch_name}`)")
    print("\n".join([f"models in {models_dir()}"] + ready))
    return 0
