"""Runtime outputs: the JSON-lines result stream and one BVH per track (``data_specs/stream_output.md``)."""
from __future__ import annotations

import json
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from mocapdb.core.formats.bvh import write_bvh
from mocapdb.core.skeleton import KEYPOINTS, RIG_JOINTS, universal_bvh

from mocapdb.runtime.engine import PersonPose, TrackRecording

OUTPUT_FILES = ("result.jsonl", "track_*.bvh")  # what a reconstruct output folder holds


class OutputFolderError(ValueError):
    """An output folder that cannot be (re)placed; the message says why."""


STREAM_FORMAT = "mocapdb-stream"
STREAM_VERSION = 1


def _rounded(values: np.ndarray, decimals: int) -> list:
    """Nested lists of rounded values; NaN (a value not measured) becomes null."""
    values = np.asarray(values, dtype=np.float64)
    rounded = np.round(values, decimals)
    if np.isnan(values).any():
        return np.where(np.isnan(values), None, rounded).tolist()
    return rounded.tolist()


def person_record(pose: PersonPose) -> dict:
    """One person of a frame as the stream schema writes it (``match`` null without a database match)."""
    match = None if pose.match is None else {
        "clip": pose.match.clip, "frame": pose.match.frame, "yaw_deg": pose.match.yaw_deg,
        "distance_2d": round(pose.match.distance_2d, 5)}
    return {
        "track": pose.track,
        "joints": _rounded(pose.joints_m, 4),
        "quaternions": _rounded(pose.quaternions, 5),
        "root": _rounded(pose.root_m, 4),
        "height": round(pose.height_m, 3),
        "match": match,
    }


def frame_line(frame_index: int, time_s: float, poses: list[PersonPose]) -> str:
    """The JSON line of one frame (no trailing newline)."""
    return json.dumps({"frame": frame_index, "time": round(time_s, 6),
                       "people": [person_record(p) for p in poses]}, separators=(",", ":"))


def header_line(fps: float) -> str:
    """The first line of a result stream: format, version, joint and rotation orders, units."""
    return json.dumps({"format": STREAM_FORMAT, "version": STREAM_VERSION, "fps": fps,
                       "joints": list(KEYPOINTS), "rotations": list(RIG_JOINTS), "units": "m",
                       "frame": "camera-aligned: x right, y up, z away from the camera"},
                      separators=(",", ":"))


def write_track_bvhs(recordings: list[TrackRecording], out_dir: str | Path, fps: float,
                     unit: str = "m") -> list[Path]:
    """Write ``track_<id>.bvh`` for each recording (universal rig, view frame); returns the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for rec in recordings:
        quats, root_view_m, body_scale = rec.motion()
        bvh = universal_bvh(quats, root_view_m, fps, unit, body_scale)
        path = out_dir / f"track_{rec.track}.bvh"
        write_bvh(path, bvh)
        paths.append(path)
    return paths


def _is_output_folder(path: Path) -> bool:
    """An empty folder, or one holding only what a run writes (:data:`OUTPUT_FILES`)."""
    return path.is_dir() and not path.is_symlink() and all(
        any(f.match(pattern) for pattern in OUTPUT_FILES) and f.is_file() for f in path.iterdir())


@contextmanager
def output_folder(out: str | Path) -> Iterator[Path]:
    """A fresh temporary folder beside ``out`` that replaces ``out`` when the block ends normally.

    An earlier output at ``out`` (a folder of only :data:`OUTPUT_FILES`) is removed only then, so
    a failing run leaves it as it was and a new run never mixes with an old one's files; any
    other existing ``out`` is refused before work starts. On an exception the temporary folder
    is deleted.
    """
    out = Path(out)
    if out.exists() and not _is_output_folder(out):
        raise OutputFolderError(f"{out} exists and is not an output folder of mocapdb (only result.jsonl and "
                                f"track_*.bvh): choose another --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    if out.exists():
        out.rename(old)
    tmp.rename(out)
    shutil.rmtree(old, ignore_errors=True)
