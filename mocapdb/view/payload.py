"""The JSON the viewer's page reads, shared by a recorded take and a live stream (``data_specs/viewer.md``).

Scene coordinates are right-handed, y up, metres: the track files' own frame (on the floor: y = 0
the floor, the origin under the camera; else the camera's view frame: x right, y up, z towards
the camera). Pixels are the input image's (x right, y down). Unknown values are ``null``.
"""
from __future__ import annotations

import math

import numpy as np

from mocapdb.core.skeleton import DRAWING_LINES, KEYPOINTS
from mocapdb.render.draw import track_colour

INPUT_THRESHOLD = 0.3   # input keypoints below this confidence are not drawn (as `mocapdb render`)
VIEW_AXES = np.diag([1.0, -1.0, -1.0])   # rows: a camera's right, down and forward in its view frame


def numbers(values: np.ndarray, decimals: int) -> list:
    """``values`` as nested lists rounded to ``decimals``, non-finite values as None (JSON null)."""
    a = np.round(np.asarray(values, dtype=np.float64), decimals).astype(object)
    a[~np.isfinite(np.asarray(values, dtype=np.float64))] = None
    return a.tolist()


def colour(track: int) -> str:
    """A track's colour as CSS ``#rrggbb`` (the colours of ``mocapdb render``)."""
    b, g, r = track_colour(track)
    return f"#{r:02x}{g:02x}{b:02x}"


def skeleton() -> dict:
    """The joints' names and the lines drawn between them (indices)."""
    return {"joints": list(KEYPOINTS), "lines": [list(line) for line in DRAWING_LINES]}


def image(focal_px: float, size: tuple[int, int], principal: tuple[float, float] | None = None) -> dict:
    """The pinhole camera the re-projection used: focal and principal point (pixels), image size."""
    cx, cy = principal or (size[0] / 2, size[1] / 2)
    return {"width": int(size[0]), "height": int(size[1]), "focal": float(focal_px), "cx": float(cx), "cy": float(cy)}


def camera(name: str, position: np.ndarray, axes: np.ndarray, fov: tuple[float, float] | None, label: str) -> dict:
    """A camera in the scene: its centre, rows ``axes`` its right, down and forward directions,
    ``fov`` the tangents of half its horizontal and vertical field of view, a label."""
    return {"name": name, "position": numbers(position, 4), "axes": numbers(axes, 6),
            "fov": None if fov is None else [float(v) for v in fov], "label": label}


def fov(image_info: dict) -> tuple[float, float]:
    """Tangents of half the horizontal and vertical field of view of :func:`image`'s camera."""
    return image_info["width"] / 2 / image_info["focal"], image_info["height"] / 2 / image_info["focal"]


def input_people(people: list) -> list:
    """Input keypoints (:class:`~mocapdb.core.formats.keypoints.Person` or ``[14, 3]`` x, y,
    confidence arrays) as per-person lists of ``[x, y]`` or null below :data:`INPUT_THRESHOLD`."""
    out = []
    for p in people:
        if isinstance(p, np.ndarray):
            pts, conf = p[:, :2], p[:, 2]
        else:
            pts, conf = p.points_px, p.confidence
        seen = np.asarray(conf) >= INPUT_THRESHOLD
        out.append(numbers(np.where(seen[:, None], pts, np.nan), 1))
    return out


def spread_text(log_sd: float | None) -> str:
    """`` ±13 %`` for an SD of log stature (empty when unknown)."""
    return f" ±{100 * (math.exp(log_sd) - 1):.0f} %" if isinstance(log_sd, (int, float)) else ""
