"""The whole take's smoothing (:mod:`mocapdb.runtime.take`, step 1): rotations and keypoints de-popped by a
running median and smoothed without lag by a zero-phase Gaussian at the take's cut-off."""
from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d, median_filter

from mocapdb.core.geometry import slerp
from mocapdb.runtime.take_params import TakeParams

MIN_SIGMA_FRAMES = 0.05   # narrower Gaussians (cut-offs above ~3 × the frame rate) leave the rotations as they are


def smooth_rotations(quats: np.ndarray, fps: float, params: TakeParams) -> np.ndarray:
    """``quats [F, R, 4]`` sign-continuous, de-popped (running median) and smoothed without lag."""
    q = quats.copy()
    flips = np.sum(q[1:] * q[:-1], axis=-1) < 0
    sign = np.concatenate([np.ones((1,) + flips.shape[1:]), np.cumprod(np.where(flips, -1.0, 1.0), axis=0)])
    q *= sign[..., None]
    q = depopped_and_smoothed(q, fps, params)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def depopped_and_smoothed(values: np.ndarray, fps: float, params: TakeParams) -> np.ndarray:
    """``values [F, ...]`` through a running median over :attr:`TakeParams.pop_frames` frames (single-frame
    pops), then :func:`zero_phase_smoothed` at :attr:`TakeParams.smoothing_hz`."""
    if params.pop_frames > 1 and len(values) >= params.pop_frames:
        values = median_filter(values, size=(params.pop_frames,) + (1,) * (values.ndim - 1), mode="nearest")
    return zero_phase_smoothed(values, fps, params.smoothing_hz)


def zero_phase_smoothed(values: np.ndarray, fps: float, cutoff_hz: float) -> np.ndarray:
    """``values [F, ...]`` through a Gaussian along the frames (``fps`` Hz) with its cut-off at
    ``cutoff_hz``: no lag. Unchanged for 0 or a cut-off far above the frame rate."""
    sigma_frames = fps / (2.0 * np.pi * cutoff_hz) if cutoff_hz > 0 else 0.0
    if sigma_frames < MIN_SIGMA_FRAMES:
        return values
    return gaussian_filter1d(values, sigma_frames, axis=0, mode="nearest")


def bridged_frames(quats: np.ndarray, root_m: np.ndarray, skip: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``quats [F, R, 4]`` and ``root_m [F, 3]`` with the ``skip [F]`` frames' values interpolated between the
    nearest frames not skipped (quaternions by slerp, signs aligned; held beyond the first and last); as given
    where no frame or every frame is skipped."""
    keep, frames = np.flatnonzero(~skip), np.flatnonzero(skip)
    if not len(frames) or not len(keep):
        return quats, root_m
    after = np.searchsorted(keep, frames)
    a, b = keep[np.maximum(after - 1, 0)], keep[np.minimum(after, len(keep) - 1)]
    share = np.where(b > a, (frames - a) / np.maximum(b - a, 1), 0.0)
    towards = quats[b] * np.where(np.sum(quats[a] * quats[b], axis=-1, keepdims=True) < 0, -1.0, 1.0)
    out_quats, out_root = quats.copy(), root_m.copy()
    out_quats[frames] = slerp(quats[a], towards, np.repeat(share[:, None], quats.shape[1], axis=1))
    out_root[frames] = root_m[a] + share[:, None] * (root_m[b] - root_m[a])
    return out_quats, out_root


def smoothed_keypoints(keypoints: np.ndarray, fps: float, params: TakeParams) -> np.ndarray:
    """The detector's keypoints ``[F, K, 3]`` (x px, y px, confidence; 0: unseen) de-popped and smoothed
    as the rotations (:func:`smooth_rotations`: running median over ``pop_frames``, then the zero-phase
    cut-off ``smoothing_hz``), each keypoint's unseen frames bridged by its seen neighbours first; an
    unseen keypoint stays unseen, and one seen fewer than twice stays as it is."""
    out = keypoints.copy()
    xy = depopped_and_smoothed(gaps_bridged(keypoints[..., :2], keypoints[..., 2] > 0), fps, params)
    seen = (keypoints[..., 2] > 0) & np.isfinite(xy).all(axis=-1)
    out[..., :2] = np.where(seen[..., None], xy, keypoints[..., :2])
    return out


def gaps_bridged(xy: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``xy [F, K, 2]`` with each keypoint's unseen frames linearly interpolated between its seen ones
    (held at the ends); NaN for a keypoint seen fewer than twice."""
    out = np.full_like(xy, np.nan, dtype=np.float64)
    frames = np.arange(len(xy))
    for k in np.flatnonzero(seen.sum(axis=0) >= 2):
        at = np.flatnonzero(seen[:, k])
        for axis in range(2):
            out[:, k, axis] = np.interp(frames, at, xy[at, k, axis])
    return out
