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
from mocapdb.runtime.take_smoothing import gaps_bridged

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
        median = median_filter(gaps_bridged(out[..., :2], seen), size=(size, 1, 1), mode="nearest")
        now = _crossed(out, median, pairs, LABEL_MARGIN)
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
    recent = np.ascontiguousarray(recent, dtype=np.float64)
    points = np.ascontiguousarray(points, dtype=np.float64)
    return _crossed(points[None], _seen_medians(recent, pairs)[None], pairs, LABEL_MARGIN)[0]


@njit(cache=True)
def _seen_medians(recent: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """``[N, 2]`` the median of each paired point's seen positions in ``recent [W, N, 3]`` (NaN: never seen,
    or a point in no pair): 6 µs a frame where NumPy's NaN median took 190."""
    median = np.full((recent.shape[1], 2), np.nan)
    for k in pairs.ravel():
        seen = recent[:, k, 2] > 0
        if seen.any():
            for axis in range(2):
                median[k, axis] = np.median(recent[:, k, axis][seen])
    return median


@njit(cache=True)
def _crossed(points: np.ndarray, median: np.ndarray, pairs: np.ndarray, margin: float) -> np.ndarray:
    """``[F, P]`` whether each pair, both points seen, of ``points [F, N, 3]`` (x px, y px, confidence) lies,
    exchanged, within ``margin`` of its labelled distance from ``median [F, N, 2]`` (False where the median is
    unknown: NaN compares False)."""
    out = np.zeros((points.shape[0], pairs.shape[0]), dtype=np.bool_)
    for f in range(points.shape[0]):
        for p in range(pairs.shape[0]):
            r, l_ = pairs[p, 0], pairs[p, 1]
            if points[f, r, 2] <= 0 or points[f, l_, 2] <= 0:
                continue
            as_labelled = _distance(points[f, r], median[f, r]) + _distance(points[f, l_], median[f, l_])
            crossed = _distance(points[f, r], median[f, l_]) + _distance(points[f, l_], median[f, r])
            out[f, p] = crossed < margin * as_labelled
    return out


@njit(cache=True)
def _distance(a: np.ndarray, b: np.ndarray) -> float:
    return np.hypot(a[0] - b[0], a[1] - b[1])
