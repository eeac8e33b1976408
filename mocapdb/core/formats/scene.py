"""The scene's lines: what `mocapdb detect` saw of the room around the people, written beside the
keypoints as ``scene.json`` (``data_specs/keypoint_formats.md``, "scene.json").

A few frames of the video (about one a second, :mod:`mocapdb.detect.scene`) give their straight
line segments outside the people's boxes, in pixels of the full image. ``reconstruct`` reads them
(:func:`read_scene`) and finds the vanishing points (:mod:`mocapdb.runtime.world.scene_lines`): the
vertical's gives the camera's pitch and roll, two orthogonal horizontal ones its focal length.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import read_sidecar, write_atomic

SCENE_FILE = "scene.json"
SCENE_FORMAT = "mocapdb-scene"
SCENE_VERSION = 1
MAX_SCENE_BYTES = 50_000_000   # 60 frames × 256 segments is ~1 MB: more is read as broken


class SceneError(MocapdbError, ValueError):
    """A scene file that cannot be used (names the file and what is wrong)."""


@dataclass(frozen=True)
class SceneLines:
    """The line segments of a few frames of one take: ``segments[i]`` ``[N, 4]`` (x1, y1, x2, y2;
    pixels of the full image, x right, y down) seen in video frame ``frames[i]``, in an image of
    ``image_size`` (width, height) px; ``detector`` names how they were found."""

    image_size: tuple[int, int]
    frames: tuple[int, ...]
    segments: tuple[np.ndarray, ...]
    detector: str

    def __post_init__(self) -> None:
        if len(self.frames) != len(self.segments):
            raise ValueError(f"{len(self.frames)} frames but {len(self.segments)} segment lists")
        width, height = self.image_size
        if not (width > 0 and height > 0):
            raise ValueError(f"image_size must be positive pixels, not {self.image_size!r}")
        for s in self.segments:
            if s.ndim != 2 or s.shape[1] != 4 or not np.isfinite(s).all():
                raise ValueError("each frame's segments must be finite [N, 4] (x1, y1, x2, y2) pixels")

    def all_segments(self) -> np.ndarray:
        """Every frame's segments together ``[N, 4]``."""
        return np.concatenate(self.segments) if self.segments else np.zeros((0, 4))


def write_scene(folder: str | Path, scene: SceneLines) -> Path:
    """``folder/scene.json`` (atomically; segments to 0.1 px); returns its path."""
    path = Path(folder) / SCENE_FILE
    body = {"format": SCENE_FORMAT, "version": SCENE_VERSION, "image_size": list(scene.image_size),
            "detector": scene.detector,
            "frames": [{"frame": int(f), "segments": np.round(s, 1).tolist()}
                       for f, s in zip(scene.frames, scene.segments)]}
    write_atomic(path, json.dumps(body, separators=(",", ":")) + "\n")
    return path


def read_scene(folder: str | Path) -> SceneLines | None:
    """The scene's lines in ``folder`` (None when there is no ``scene.json``); SceneError when it is
    broken."""
    found = read_sidecar(folder, SCENE_FILE, MAX_SCENE_BYTES, SceneError, "scene file", SCENE_FORMAT, SCENE_VERSION)
    if found is None:
        return None
    path, body = found
    try:
        frames = body["frames"]
        size = tuple(int(v) for v in body["image_size"])
        if len(size) != 2 or not all(math.isfinite(v) for v in size):
            raise ValueError(f"image_size {body['image_size']!r} is not (width, height)")
        segments = tuple(_segments(f["segments"], n) for n, f in enumerate(frames))
        return SceneLines((size[0], size[1]), tuple(int(f["frame"]) for f in frames), segments,
                          str(body.get("detector", "")))
    except (KeyError, TypeError, ValueError) as exc:
        raise SceneError(f"{path}: {exc!r}") from None


def _segments(value: object, n: int) -> np.ndarray:
    """A frame's segment list as ``[N, 4]``; ValueError naming frame ``n`` otherwise."""
    rows = np.asarray(value, dtype=np.float64)
    if rows.size and (rows.ndim != 2 or rows.shape[1] != 4):
        raise ValueError(f"frame {n}: segments must be [x1, y1, x2, y2] lists, not shape {rows.shape}")
    return rows.reshape(-1, 4)
