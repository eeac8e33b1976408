"""A detector's left/right labels made consistent over a whole take (offline, before the whole-take fit),
and the stream's causal check of a frame against the frames before it (:func:`exchanged_now`).

BlazePose now and then exchanges a person's sides for a few frames (seen near frontally or from the back:
on the balancing take's camera 2, frames 43, 50, 62 and 69-74, some pairs of a frame and not others), and
a run of them passes the whole take's running median. Each side pair (shoulders, elbows, ..., heels, eyes)
of each frame is compared with the running median of the pair's own points over :data:`LABEL_WINDOW_S`
around it: where the exchanged labelling lies much nearer (:data:`LABEL_MARGIN`), the pair is exchanged
back. Pairs decide alone, as the detector's flips are often partial; a pair whose points lie close together
(a wrist on the body's mid-line) is never much nearer either way and keeps its labels; a run longer than
half the window is the take's own labelling and is kept. Cost O(F × W) per point (W: the window's frames).
"""
from __future__ import annotations

import numpy as np
from numba import njit
from scipy.ndimage import median_filter

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.skeleton import KP

BODY_PAIRS = np.array([(KP[f"r_{p}"], KP[f"l_{p}"]) for p in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")])
EXTREMITY_PAIRS = np.array([(EXTREMITIES.index(f"r_{p}"), EXTREMITIES.index(f"l_{p}"))
                            for p in ("heel", "big_toe", "index", "pinky", "eye", "ear", "mouth")])
LABEL_WINDOW_S = 0.4   # the frames around a frame whose median labels it is compared with (seconds)
LABEL_MARGIN = 0.5     # exchanged where that puts the pair within this share of its distance as labelled
PASSES = 2             # the medians taken again after the first exchanges


def consistent_sides(points: np.ndarray, pairs: np.ndarray, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """``points [F, N, 3]`` (x px, y px, confidence; 0: unseen) with the ``pairs [P, 2]`` (right, left rows)
    exchanged per frame where the detector's labels contradict the frames around (module docstring), and
    ``[F, P]`` which pairs of which frames were exchanged. ``fps``: the take's frame rate (Hz)."""
    out = np.array(points, dtype=np.float64)
    exchanged = np.zeros((len(out), len(pairs)), dtype=bool)
    size = max(int(round(LABEL_WINDOW_S * fps)) | 1, 3)
    right, left = pairs[:, 0], pairs[:, 1]
    for _ in range(PASSES):
        seen = out[..., 2] > 0
        median = _running_median(np.where(seen[..., None], out[..., :2], np.nan), size)
        now = seen[:, right] & seen[:, left] & _crossed(out[..., :2], median, pairs)
        if not now.any():
            break
        frame, pair = np.nonzero(now)
        out[frame, right[pair]], out[frame, left[pair]] = out[frame, left[pair]], out[frame, right[pair]].copy()
        exchanged[frame, pair] ^= True
    return out, exchanged


def exchanged_now(recent: np.ndarray, points: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``[P]`` which ``pairs`` of a frame's ``points [N, 3]`` (x px, y px, confidence) lie exchanged against
    the median of the ``recent [W, N, 3]`` frames before it (each point's seen ones), as
    :func:`consistent_sides` judges (causal: the stream's check, which cannot see the frames after)."""
    return _exchanged_now(np.ascontiguousarray(recent, dtype=np.float64),
                          np.ascontiguousarray(points, dtype=np.float64), pairs, LABEL_MARGIN)


@njit(cache=True)
def _exchanged_now(recent: np.ndarray, points: np.ndarray, pairs: np.ndarray, margin: float) -> np.ndarray:
    """:func:`exchanged_now`'s kernel: 6 µs a frame where NumPy's NaN median took 190."""
    out = np.zeros(len(pairs), dtype=np.bool_)
    median = np.empty((2, 2))
    for p in range(len(pairs)):
        right, left = pairs[p, 0], pairs[p, 1]
        if points[right, 2] <= 0 or points[left, 2] <= 0:
            continue
        known = True
        for side, k in enumerate((right, left)):
            seen = recent[:, k, 2] > 0
            if not seen.any():
                known = False
                break
            for axis in range(2):
                median[side, axis] = np.median(recent[:, k, axis][seen])
        if not known:
            continue
        as_labelled = (np.hypot(points[right, 0] - median[0, 0], points[right, 1] - median[0, 1])
                       + np.hypot(points[left, 0] - median[1, 0], points[left, 1] - median[1, 1]))
        crossed = (np.hypot(points[right, 0] - median[1, 0], points[right, 1] - median[1, 1])
                   + np.hypot(points[left, 0] - median[0, 0], points[left, 1] - median[0, 1]))
        out[p] = crossed < margin * as_labelled
    return out


def _crossed(xy: np.ndarray, median: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``[F, P]`` whether each pair of ``xy [F, N, 2]`` lies within :data:`LABEL_MARGIN` of its labelled
    distance of ``median [F, N, 2]`` exchanged (False where the median is unknown: NaN compares False)."""
    right, left = pairs[:, 0], pairs[:, 1]
    as_labelled = _distance(xy[:, right], median[:, right]) + _distance(xy[:, left], median[:, left])
    crossed = _distance(xy[:, right], median[:, left]) + _distance(xy[:, left], median[:, right])
    return crossed < LABEL_MARGIN * as_labelled


def _distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.norm(a - b, axis=-1)


def _running_median(xy: np.ndarray, size: int) -> np.ndarray:
    """``xy [F, N, 2]`` (NaN: unseen): each point's running median over ``size`` frames, its unseen frames
    interpolated between its seen ones first (held at the ends); NaN for a point seen fewer than twice."""
    frames = np.arange(len(xy))
    out = np.full_like(xy, np.nan)
    for k in range(xy.shape[1]):
        at = np.flatnonzero(np.isfinite(xy[:, k]).all(axis=-1))
        if len(at) >= 2:
            filled = np.stack([np.interp(frames, at, xy[at, k, axis]) for axis in range(2)], axis=-1)
            out[:, k] = median_filter(filled, size=(size, 1), mode="nearest")
    return out
