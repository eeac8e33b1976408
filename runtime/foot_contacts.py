"""Foot contacts of a track from its keypoints in the image: which ankles are planted
(:func:`planted_ankles`) and, where the layout gives heels and big toes, each foot's phase
(:func:`foot_phases`), from robust image speeds (:func:`image_speeds`). Step 2 of the whole-take
fit (:mod:`mocapdb.runtime.take`)."""
from __future__ import annotations

import numpy as np
from scipy.ndimage import convolve1d

from mocapdb.core.skeleton import KP
from mocapdb.runtime.take_params import TakeParams

ANKLES = (KP["r_ankle"], KP["l_ankle"])
# Rows of the heels, big toes and knuckles (keypoint_layouts.EXTREMITIES order) per foot and hand
HEELS, TOES, INDEX_KNUCKLES, PINKY_KNUCKLES = (0, 2), (1, 3), (4, 6), (5, 7)
# Each foot's phase (foot_phases): heel or toe not seen, in the air, heel down alone, flat, toe down alone
UNSEEN, SWING, HEEL_STRIKE, FLAT, TOE_OFF = -1, 0, 1, 2, 3
MIN_CONTACT_FRAMES = 3
CONTACT_WINDOW_S = 0.25   # an ankle keypoint's image speed: the slope of a line fitted over this long
MEDIAN_FRAMES = 5         # an ankle keypoint's image track: the running median over this many frames
GAP_S = 0.1               # gaps in a contact up to this long are closed (a foot is not lifted and put back so fast)


def planted_ankles(keypoints: np.ndarray, ankles_view_m: np.ndarray, up: np.ndarray, fps: float,
                   params: TakeParams, phases: np.ndarray | None = None) -> np.ndarray:
    """Which ankles ``[F, 2]`` are planted: still in the image and near the lowest (module docstring).
    ``keypoints [F, 14, 3]`` (x, y px, confidence), ``ankles_view_m [F, 2, 3]``; ``phases [F, 2]``
    (:func:`foot_phases`): where a foot's heel and toe are seen, it is planted when flat (both
    still) instead of when its ankle is still, and, flat while the other foot is not, whatever
    the heights: it carries the body.

    Where both feet's heels and toes are seen, a foot also carries the body, and is planted, when it
    is the lower and the slower of the two while the other swings (:data:`SWING`: heel and toe both
    moving), up to :attr:`TakeParams.carrying_box_per_s`: one foot stands while the other is in the
    air, and the keypoints of a foot under the body's weight drift more than an idle foot's.

    The image track of each point is first a running median over :data:`MEDIAN_FRAMES` frames of
    its seen positions, so a detector's single-frame left/right swap or missed keypoint neither
    moves a planted foot nor splits its contact; gaps of up to :data:`GAP_S` in a contact are closed."""
    speed, seen = image_speeds(keypoints[:, ANKLES], box_height_px(keypoints), fps)
    height = ankles_view_m @ up
    low = height <= height.min(axis=1, keepdims=True) + params.planted_height_m  # the lower foot (or both)
    still = seen & low & (speed < params.planted_box_per_s)
    if phases is not None:
        other = phases[:, ::-1]
        support = (other != UNSEEN) & (other != FLAT)  # the other foot seen off the floor, or partly
        still = np.where(phases != UNSEEN, (phases == FLAT) & (low | support), still)
        slower = speed <= speed[:, ::-1]
        still |= seen & low & (phases != UNSEEN) & (other == SWING) & slower & (speed < params.carrying_box_per_s)
    planted = _close_gaps(still, int(round(GAP_S * fps)))
    return _drop_short_runs(planted, MIN_CONTACT_FRAMES)


def box_height_px(keypoints: np.ndarray) -> float:
    """The median height (pixels) of the box around each frame's seen keypoints ``[F, 14, 3]``
    (1 without any): image speeds are measured in it."""
    visible = keypoints[..., 2] > 0
    seen_frames = visible.any(axis=1)  # frames the track missed hold no keypoint
    ys = np.where(visible, keypoints[..., 1], np.nan)[seen_frames]
    return float(np.median(np.nanmax(ys, axis=1) - np.nanmin(ys, axis=1))) if len(ys) else 1.0


def image_speeds(points: np.ndarray, box_px: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Image speeds ``[F, K]`` (box heights ``box_px`` per second) of keypoints ``[F, K, 3]`` (x, y px,
    confidence) and where each is seen ``[F, K]``: the slope of a line fitted over
    :data:`CONTACT_WINDOW_S` to its running median (:func:`_robust_track_px`)."""
    px = _robust_track_px(points)
    half_window = max(int(round(CONTACT_WINDOW_S * fps / 2)), 1)
    speed = np.linalg.norm(_slope(interpolated(px), half_window), axis=-1) * fps / max(box_px, 1.0)
    return speed, np.isfinite(px[..., 0])


def foot_phases(extremities: np.ndarray, box_px: float, fps: float, params: TakeParams) -> np.ndarray:
    """Each foot's phase ``[F, 2]`` (right, left) from its heel and big toe in the image
    (``extremities [F, 8, 3]``, x px, y px, confidence): :data:`FLAT` when both are still (slower than
    :attr:`TakeParams.planted_box_per_s` box heights ``box_px`` per second, :func:`image_speeds`),
    :data:`HEEL_STRIKE` when the heel alone is, :data:`TOE_OFF` when the toe alone is, :data:`SWING`
    when neither is; :data:`UNSEEN` where either is not seen."""
    heel_speed, heel_seen = image_speeds(extremities[:, HEELS], box_px, fps)
    toe_speed, toe_seen = image_speeds(extremities[:, TOES], box_px, fps)
    heel, toe = heel_speed < params.planted_box_per_s, toe_speed < params.planted_box_per_s
    phases = np.select([heel & toe, heel, toe], [FLAT, HEEL_STRIKE, TOE_OFF], SWING)
    return np.where(heel_seen & toe_seen, phases, UNSEEN)


def _robust_track_px(points: np.ndarray) -> np.ndarray:
    """Keypoints ``[F, K, 3]`` (x, y px, confidence) as positions ``[F, K, 2]``: per frame the median of
    the seen positions over the :data:`MEDIAN_FRAMES` frames around it (NaN where none was seen)."""
    xy = np.where(points[..., 2:] > 0, points[..., :2], np.nan)
    half = MEDIAN_FRAMES // 2
    padded = np.concatenate([np.full((half,) + xy.shape[1:], np.nan), xy, np.full((half,) + xy.shape[1:], np.nan)])
    windows = np.lib.stride_tricks.sliding_window_view(padded, MEDIAN_FRAMES, axis=0)  # [F, K, 2, window]
    out = np.full(xy.shape, np.nan)
    some = np.isfinite(windows).any(axis=-1)
    out[some] = np.nanmedian(windows[some], axis=-1)
    return out


def interpolated(values: np.ndarray) -> np.ndarray:
    """``values [F, ...]`` with NaN filled by linear interpolation over frames (edges held; all-NaN
    series: 0)."""
    flat = values.reshape(len(values), -1).copy()
    frames = np.arange(len(values))
    for column in flat.T:
        ok = np.isfinite(column)
        column[~ok] = np.interp(frames[~ok], frames[ok], column[ok]) if ok.any() else 0.0
    return flat.reshape(values.shape)


def _close_gaps(mask: np.ndarray, max_gap: int) -> np.ndarray:
    """``mask [F, K]`` with gaps of at most ``max_gap`` frames between two runs of True filled."""
    out = mask.copy()
    for k in range(mask.shape[1]):
        runs = true_runs(mask[:, k])
        for (_, stop), (start, _) in zip(runs[:-1], runs[1:]):
            if start - stop <= max_gap:
                out[stop:start, k] = True
    return out


def _slope(values: np.ndarray, half: int) -> np.ndarray:
    """Per frame, the slope (per frame) of the least-squares line through ``values [F, ...]`` over
    the ``2 half + 1`` frames around it (edges repeated): a derivative that averages out jitter."""
    offsets = np.arange(-half, half + 1, dtype=np.float64)
    return convolve1d(values, offsets[::-1] / np.sum(offsets ** 2), axis=0, mode="nearest")


def _drop_short_runs(mask: np.ndarray, min_length: int) -> np.ndarray:
    """``mask [F, K]`` with runs of True shorter than ``min_length`` frames cleared."""
    out = mask.copy()
    for k in range(mask.shape[1]):
        for start, stop in true_runs(mask[:, k]):
            if stop - start < min_length:
                out[start:stop, k] = False
    return out


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of True in a 1-D mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))
