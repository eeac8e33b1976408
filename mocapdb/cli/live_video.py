"""`mocapdb live`'s options for a video source: the hands' and face's rates, a still
camera, a file delivered at its frame rate."""
from __future__ import annotations

import argparse

from mocapdb.core import domains as D
from mocapdb.detect.landmark_schedule import LIVE_FACE_EVERY, LIVE_HANDS_EVERY


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
