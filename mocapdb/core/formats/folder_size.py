"""The sizes of a keypoint input: the image size of a keypoint folder that nothing describes (no
``--image-size``, no ``take.json``), the smallest standard video size that holds its first frames'
keypoints (``data_specs/take_description.md``); the frames of a folder or a JSON-lines file."""
from __future__ import annotations

import itertools
import logging
from pathlib import Path

import numpy as np

from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD, KeypointError
from mocapdb.core.formats.openpose import is_frame_file, read_openpose_folder
from mocapdb.core.formats.take import standard_size_holding

SIZE_FRAMES = 300  # the first frames whose keypoints give the size
LOG = logging.getLogger(__name__)


def size_of_keypoint_folder(folder: str | Path) -> tuple[int, int] | None:
    """(width, height) px: the smallest of the standard sizes that holds the confident keypoints of the
    folder's first :data:`SIZE_FRAMES` frames (a lower bound; logged as a warning). None for a path that
    is no folder, a folder without frames yet, unreadable frames (the session reports them) or keypoints
    no standard size holds."""
    if not Path(folder).is_dir():
        return None
    reader_log = logging.getLogger(read_openpose_folder.__module__)
    level = reader_log.level
    reader_log.setLevel(logging.ERROR)  # the session reports the folder's problems, once
    try:
        frames = list(itertools.islice(read_openpose_folder(folder), SIZE_FRAMES))
    except KeypointError:
        return None
    finally:
        reader_log.setLevel(level)
    points = np.concatenate([np.zeros((0, 2))] + [p.points_px[p.confidence >= CONFIDENCE_THRESHOLD]
                                                  for frame in frames for p in frame.people])
    if not len(points):
        return None
    size = standard_size_holding(tuple(points.min(axis=0)), tuple(points.max(axis=0)))
    if size:
        LOG.warning("no --image-size given and no take.json in %s: taking %dx%d, the smallest standard video size "
                    "holding the keypoints of its first %d frame(s) (they reach x = %.0f, y = %.0f px); give "
                    "--image-size WIDTHxHEIGHT if the video is larger", folder, *size, len(frames),
                    *points.max(axis=0))
    return size


def frames_in_input(path: str | Path) -> int | None:
    """Frames in a keypoint folder (its frame files, not the take's side files) or lines in a keypoint
    file (a last line without its newline counted); None for neither."""
    source = Path(path)
    if source.is_dir():
        return sum(1 for f in source.iterdir() if is_frame_file(f.name))
    if not source.is_file():
        return None
    lines, last = 0, b"\n"
    with open(source, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            lines, last = lines + chunk.count(b"\n"), chunk[-1:]
    return lines + (last != b"\n")
