"""`mocapdb live`'s options for a video source (the hands' and face's rates, a still camera, a file
delivered at its frame rate) and the source they open."""
from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from mocapdb.core import domains as D
from mocapdb.detect.landmark_schedule import LIVE_FACE_EVERY, LIVE_HANDS_EVERY

if TYPE_CHECKING:
    from mocapdb.runtime.stream.messages import StreamStats
    from mocapdb.runtime.stream.video_input import VideoDetections


def add_live_video_options(p: argparse.ArgumentParser) -> None:
    """``--hands-every N``, ``--face-every N`` (:mod:`mocapdb.detect.landmark_schedule`),
    ``--still-camera`` and ``--realtime`` (:class:`~mocapdb.runtime.stream.video_input.DecodedFrames`, ``paced``)."""
    for part, what, carrier, every in (("hands", "each hand's landmarks", "hand", LIVE_HANDS_EVERY),
                                       ("face", "each face's mesh", "face points", LIVE_FACE_EVERY)):
        p.add_argument(f"--{part}-every", type=D.MODEL_EVERY, default=every, metavar="N",
                       help=f"with --{part} on a video: {what} every N-th frame, carried with the pose's {carrier} "
                            "between (sooner when it moves fast); 1: every frame (default %(default)s)")
    p.add_argument("--still-camera", action="store_true",
                   help="a video file filmed from a tripod: no camera path measured from the background (about "
                        "1 ms a frame saved); a camera device (an index) is always taken as still")
    p.add_argument("--realtime", action="store_true",
                   help="a video file delivered at its frame rate, as a camera would (late frames dropped; the "
                        "latency a camera would give); default: as fast as detection goes")


def open_live_video(args: argparse.Namespace, stats: StreamStats) -> VideoDetections:
    """`live --source VIDEO`'s detector (each model in one intra-op thread:
    :data:`~mocapdb.detect.detectors.PIPELINE_MODEL_THREADS`) on the video, its threads started
    (:func:`~mocapdb.runtime.stream.video_input.open_video_source`); DetectError on failure."""
    from mocapdb.cli.detect import fast_path
    from mocapdb.detect.detectors import PIPELINE_MODEL_THREADS, open_detector
    from mocapdb.detect.options import DEFAULT_CONF, DEFAULT_INPUT_SIZE, DEFAULT_IOU
    from mocapdb.runtime.stream.video_input import open_video_source

    detector = open_detector(args.model, args.blazepose, conf=DEFAULT_CONF, iou=DEFAULT_IOU,
                             max_people=args.max_people, input_size=DEFAULT_INPUT_SIZE, fast=fast_path(args),
                             hands=args.hands, hands_every=args.hands_every, hand_model=args.hand_model,
                             faces=args.face, face_every=args.face_every, model_threads=PIPELINE_MODEL_THREADS)
    return open_video_source(args.source, detector, capacity=args.buffer, stats=stats, paced=args.realtime,
                             turning=not args.still_camera)
