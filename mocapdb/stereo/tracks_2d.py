"""`mocapdb stereo`: one view's detections, linked into 2D tracks frame by frame.

Every person with a confident joint is a detection (:class:`Detections`, :func:`detections`). A
detection continues a 2D track by proximity (median joint displacement in units of the body's box
diagonal, :func:`box_diagonal`); a contested choice (two people close together) ends the tracks
(:func:`continuations`, :func:`track_2d`). Decisions and thresholds: ``data_specs/stereo.md``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.skeleton import N_KEYPOINTS_2D

# 2D tracks. A detection continues a track when the median displacement of their common confident
# joints is at most TRACK_STEP box diagonals (of the track's last detection; ≥ 3 common joints), the
# track was last seen at most TRACK_GAP frames before, and neither has a rival choice within
# TRACK_AMBIGUITY times that displacement (two people overlapping: their tracks end, new ones start).
TRACK_STEP = 0.3
TRACK_GAP = 10
TRACK_AMBIGUITY = 2.0
MIN_TRACK_JOINTS = 3


@dataclass
class Detections:
    """One view's people with a confident joint, flattened in frame order."""

    frame: np.ndarray       # [N] frame index
    points: np.ndarray      # [N, 14, 2] pixels, NaN where missing
    conf: np.ndarray        # [N, 14]
    vis: np.ndarray         # [N, 14] confident
    normalised: np.ndarray  # [N, 14, 2] undistorted normalised coordinates (NaN where missing)
    track: np.ndarray       # [N] 2D track id within the view


def masked_median(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Median over the last axis of the entries where ``mask``; NaN where there are none."""
    ordered = np.sort(np.where(mask, values, np.inf), axis=-1)
    n = mask.sum(axis=-1)
    lo = np.take_along_axis(ordered, np.maximum((n - 1) // 2, 0)[..., None], -1)[..., 0]
    hi = np.take_along_axis(ordered, (n // 2)[..., None].clip(0, values.shape[-1] - 1), -1)[..., 0]
    return np.where(n > 0, 0.5 * (lo + hi), np.nan)


def normalised(cam: CameraModel, points: np.ndarray) -> np.ndarray:
    """Undistorted normalised coordinates of ``[N, 14, 2]`` pixels (NaN stays NaN)."""
    flat = points.reshape(-1, 2)
    ok = np.isfinite(flat).all(axis=1)
    out = np.full_like(flat, np.nan)
    if ok.any():
        out[ok] = np.asarray(cam.undistort_normalized(flat[ok])).reshape(-1, 2)
    return out.reshape(points.shape)


def detections(frames: list[KeypointFrame], cam: CameraModel, threshold: float) -> Detections:
    """Every person of ``frames`` with a confident joint, with its 2D track."""
    people = [(t, p) for t, f in enumerate(frames) for p in f.people]
    frame = np.array([t for t, _ in people], dtype=np.int64)
    points = np.array([p.points_px for _, p in people], dtype=np.float64).reshape(-1, N_KEYPOINTS_2D, 2)
    conf = np.array([p.confidence for _, p in people], dtype=np.float64).reshape(-1, N_KEYPOINTS_2D)
    vis = (conf >= threshold) & (conf > 0) & np.isfinite(points).all(axis=-1)
    keep = vis.any(axis=1)
    frame, points, conf, vis = frame[keep], points[keep], conf[keep], vis[keep]
    return Detections(frame, points, conf, vis, normalised(cam, points), track_2d(frame, points, vis))


def box_diagonal(points: np.ndarray, vis: np.ndarray) -> np.ndarray:
    xy = np.where(vis[..., None], points, np.nan)
    with np.errstate(invalid="ignore"):
        diag = np.linalg.norm(np.fmax.reduce(xy, axis=1) - np.fmin.reduce(xy, axis=1), axis=-1)
    return np.maximum(np.nan_to_num(diag), 1.0)


def _step_cost(points: np.ndarray, vis: np.ndarray, size: np.ndarray, prev: np.ndarray,
               now: np.ndarray) -> np.ndarray:
    """``[K, D]``: median displacement of the common confident joints from each track's last
    detection ``prev`` to each detection ``now``, in box diagonals (the larger of the two boxes:
    a detection with few joints has a small one; inf with too few common joints)."""
    both = vis[prev][:, None] & vis[now][None]
    moved = np.linalg.norm(np.nan_to_num(points[prev][:, None] - points[now][None]), axis=-1)
    cost = masked_median(moved, both) / np.maximum(size[prev][:, None], size[now][None])
    return np.where(both.sum(axis=-1) >= MIN_TRACK_JOINTS, cost, np.inf)


def _contested(near: np.ndarray, axis: int) -> np.ndarray:
    """Rows (``axis`` 1) or columns (0) whose second-best finite cost is within TRACK_AMBIGUITY of the best."""
    if near.shape[axis] < 2:
        return np.zeros(near.shape[1 - axis], dtype=bool)
    best2 = np.sort(near, axis=axis).take([0, 1], axis=axis)
    first, second = best2.take(0, axis=axis), best2.take(1, axis=axis)
    return np.isfinite(second) & (second < TRACK_AMBIGUITY * first)


def continuations(cost: np.ndarray, last_seen: np.ndarray) -> tuple[list[tuple[int, int]], np.ndarray]:
    """(track, detection) pairs continuing tracks, greedily by increasing cost up to TRACK_STEP,
    and the tracks that end because a choice was contested (a rival nearly as good: two people
    close together). ``last_seen [K]``: the tracks' last frames; of the tracks near a detection
    only the most recently seen may take it (an older one is the same person's broken-off track)."""
    near = np.where(cost <= TRACK_STEP, cost, np.inf)
    latest = np.max(np.where(np.isfinite(near), last_seen[:, None], -1), axis=0, initial=-1)
    near[last_seen[:, None] < latest[None]] = np.inf
    rows, cols = _contested(near, 1), _contested(near, 0)
    ended = rows | np.isfinite(near[:, cols]).any(axis=1)
    near[ended], near[:, cols] = np.inf, np.inf
    pairs: list[tuple[int, int]] = []
    used_r, used_c = set(), set()
    for flat in np.argsort(near, axis=None)[:int(np.isfinite(near).sum())]:
        r, c = (int(v) for v in np.unravel_index(flat, near.shape))
        if r not in used_r and c not in used_c:
            pairs.append((r, c))
            used_r.add(r)
            used_c.add(c)
    return pairs, ended


def track_2d(frame: np.ndarray, points: np.ndarray, vis: np.ndarray) -> np.ndarray:
    """2D track id ``[N]`` of every detection (``frame`` sorted), by proximity to the tracks' last detections."""
    size = box_diagonal(points, vis)
    track = np.full(len(frame), -1, dtype=np.int64)
    last: dict[int, int] = {}  # open track → its latest detection
    n_tracks = 0
    for now in np.split(np.arange(len(frame)), np.flatnonzero(np.diff(frame)) + 1):
        if not len(now):
            continue
        last = {k: d for k, d in last.items() if frame[now[0]] - frame[d] <= TRACK_GAP}
        open_ = np.array(list(last), dtype=np.int64)
        prev = np.array(list(last.values()), dtype=np.int64)
        pairs, ended = continuations(_step_cost(points, vis, size, prev, now), frame[prev])
        for r, c in pairs:
            track[now[c]] = open_[r]
            last[int(open_[r])] = int(now[c])
        for k in open_[ended]:
            del last[int(k)]
        for unmatched in np.flatnonzero(track[now] < 0):
            track[now[unmatched]], last[n_tracks] = n_tracks, int(now[unmatched])
            n_tracks += 1
    return track
