"""`mocapdb detect`: video or camera → OpenPose JSON keypoints with an ONNX pose model."""
from __future__ import annotations

import argparse
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from mocapdb.cli import paths as P
from mocapdb.core import domains as D
from mocapdb.detect.options import (
    DEFAULT_CONF,
    DEFAULT_CROP_PX,
    DEFAULT_FULL_EVERY,
    DEFAULT_INPUT_SIZE,
    DEFAULT_IOU,
    DETECTORS,
    NO_MODEL,
)

if TYPE_CHECKING:
    from mocapdb.detect.tracked import FastPath


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
                            f"with a dynamic input size only; default {DEFAULT_CROP_PX})")
    group.add_argument("--full-every", type=D.DETECT_EVERY, default=DEFAULT_FULL_EVERY, metavar="N",
                       help=f"with crops: the whole frame at least every N frames, to find people coming in "
                            f"(default {DEFAULT_FULL_EVERY})")
    group.add_argument("--model-every", type=D.MODEL_EVERY, default=1, metavar="N",
                       help="run the model on every N-th frame only; the frames between get the keypoints carried "
                            "by optical flow (default 1: the model on every frame)")


def fast_path(args: argparse.Namespace) -> FastPath:
    """The :class:`~mocapdb.detect.tracked.FastPath` the options of :func:`add_detector_options` ask for."""
    from mocapdb.detect.tracked import FastPath

    return FastPath(crops=args.detector == "crops", crop_px=args.crop_size, full_every=args.full_every,
                    model_every=args.model_every)


def add_detect_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds the ``detect`` subcommand; its ``run`` returns the exit code (2 for a user error)."""
    p = sub.add_parser("detect", help="video or camera → 2D keypoints (OpenPose JSON per frame), ONNX pose model",
                       description="Decode a video (or a camera) with OpenCV, run a YOLO-pose or RTMO ONNX export "
                                   "on each frame with onnxruntime (CPU) and write OUT/<video>_<frame>_keypoints.json "
                                   "in OpenPose's COCO-18 layout, ready for `mocapdb reconstruct` or `live`. "
                                   "Model layouts: data_specs/pose_models.md.")
    p.add_argument("video", nargs="?", type=P.INPUT_FILE, help="video file (any format OpenCV's FFmpeg decodes)")
    p.add_argument("--camera", type=D.CAMERA_INDEX, metavar="N", help="read camera N instead of a file (Ctrl-C ends)")
    p.add_argument("--model", metavar="POSE.onnx", type=P.INPUT_FILE,
                   help="pose model: a YOLO-pose or RTMO ONNX export (see data_specs/pose_models.md)")
    p.add_argument("--out", required=True, metavar="DIR", type=P.OUTPUT_DIR,
                   help="folder for the JSON files, written as the video is read (created if missing; an "
                        "earlier detect output there is replaced, a folder holding other files refused)")
    p.add_argument("--every", type=D.DETECT_EVERY, default=1, metavar="N",
                   help="detect every N-th frame only (default 1)")
    p.add_argument("--max-people", type=D.MAX_PEOPLE, metavar="N",
                   help="keep the N best-scoring people per frame (default all)")
    p.add_argument("--conf", type=D.CONF, default=DEFAULT_CONF,
                   help=f"least person score kept (default {DEFAULT_CONF})")
    p.add_argument("--iou", type=D.IOU, default=DEFAULT_IOU, help=f"NMS IoU threshold (default {DEFAULT_IOU})")
    p.add_argument("--input-size", type=D.MODEL_INPUT_PX, default=DEFAULT_INPUT_SIZE, metavar="PX",
                   help=f"input side in pixels for models with a dynamic input size (default {DEFAULT_INPUT_SIZE})")
    add_detector_options(p, "full")
    p.set_defaults(run=run_detect)
    return p


def run_detect(args: argparse.Namespace) -> int:
    """``mocapdb detect``: 0 on success; DetectError (exit 2) for a user error, also a video file
    that ends before its declared frame count (its frames read are kept); 130 if a video file was
    interrupted before its end."""
    from mocapdb.core.outputs import check_output_folder
    from mocapdb.core.signals import install_stop_handlers
    from mocapdb.detect.errors import DetectError
    from mocapdb.detect.model import PoseModel
    from mocapdb.detect.openpose_out import DETECT_FILES, detect_video
    from mocapdb.detect.tracked import TrackedDetector
    from mocapdb.detect.video import VideoReader

    if not args.model:
        raise DetectError(NO_MODEL)
    if (args.video is None) == (args.camera is None):
        raise DetectError("give either a VIDEO file or --camera N")
    if args.every < 1:
        raise DetectError("--every must be at least 1")
    check_output_folder(args.out, DETECT_FILES)  # before any work; emptied once the model and the video open
    model = TrackedDetector(PoseModel(args.model, conf=args.conf, iou=args.iou, max_people=args.max_people,
                                      input_size=args.input_size), fast_path(args))
    reader = VideoReader(args.camera if args.camera is not None else args.video)
    stop = threading.Event()
    try:
        with install_stop_handlers(stop):
            summary = detect_video(reader, model, Path(args.out), args.every, stop)
    finally:
        reader.close()
    print(f"wrote {len(summary.people)} file(s) in {args.out} (model {model.describe()})")
    print(summary.report())
    if summary.truncated:
        raise DetectError(f"{summary.truncated}; the {len(summary.people)} file(s) written in {args.out} are kept")
    return 130 if summary.interrupted and not reader.is_camera else 0
