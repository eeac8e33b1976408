"""Pose accuracy metrics shared by the runtime and stereo evaluations (metres in, metres out)."""
from __future__ import annotations

import numpy as np


def mpjpe(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Mean per-joint position error per frame: ``pred, true [F, J, 3]`` → ``[F]``."""
    return np.linalg.norm(pred - true, axis=-1).mean(axis=-1)


def procrustes_align(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``pred [F, J, 3]`` moved onto ``true`` by the best similarity (rotation, scale, shift) per frame."""
    mu_p, mu_t = pred.mean(axis=1, keepdims=True), true.mean(axis=1, keepdims=True)
    p, t = pred - mu_p, true - mu_t
    u, s, vt = np.linalg.svd(np.einsum("fji,fjk->fik", p, t))
    d = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", u, vt)))  # no reflections
    s[:, -1] *= d
    u[:, :, -1] *= d[:, None]
    rot = np.einsum("fij,fjk->fik", u, vt)
    scale = s.sum(axis=1) / np.maximum(np.sum(p ** 2, axis=(1, 2)), 1e-12)
    return scale[:, None, None] * np.einsum("fji,fik->fjk", p, rot) + mu_t


def pa_mpjpe(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """MPJPE after Procrustes alignment, per frame ``[F]``."""
    return mpjpe(procrustes_align(pred, true), true)


def acceleration_error(pred: np.ndarray, true: np.ndarray) -> np.ndarray:
    """Mean per-joint difference of second differences (per frame²), ``[F - 2]``."""
    acc_p = pred[2:] - 2 * pred[1:-1] + pred[:-2]
    acc_t = true[2:] - 2 * true[1:-1] + true[:-2]
    return np.linalg.norm(acc_p - acc_t, axis=-1).mean(axis=-1)


def pck(pred: np.ndarray, true: np.ndarray, threshold_m: float) -> float:
    """Fraction of joints within ``threshold_m`` of the truth."""
    return float(np.mean(np.linalg.norm(pred - true, axis=-1) <= threshold_m))


def speeds_mps(points_m: np.ndarray, fps: float, horizontal: bool = False) -> np.ndarray:
    """Speed ``[F, ...]`` (m/s) of points ``[F, ..., 3]`` (y up) by central differences (one-sided at
    the ends); NaN where the point or a neighbour is NaN (no output). ``horizontal``: x-z only."""
    p = np.asarray(points_m, dtype=np.float64)
    if horizontal:
        p = p[..., [0, 2]]
    if len(p) < 2:
        return np.full(p.shape[:-1], np.nan)
    step = np.empty_like(p)
    step[1:-1] = (p[2:] - p[:-2]) / 2.0
    step[0], step[-1] = p[1] - p[0], p[-1] - p[-2]
    step[np.isnan(p)] = np.nan  # a frame without output has no speed either
    return np.linalg.norm(step, axis=-1) * fps


PLANTED_SPEED_MPS = 0.25   # a foot slower than this …
PLANTED_HEIGHT_M = 0.05    # … and within this of its lowest height over the clip is planted


def planted_feet(ankles_m: np.ndarray, fps: float) -> np.ndarray:
    """Which ankles ``[F, 2, 3]`` (world, y up, metres) are planted ``[F, 2]``: slower than
    :data:`PLANTED_SPEED_MPS` and within :data:`PLANTED_HEIGHT_M` of that ankle's lowest height."""
    speed = speeds_mps(ankles_m, fps)
    low = ankles_m[..., 1] <= np.nanmin(ankles_m[..., 1], axis=0) + PLANTED_HEIGHT_M
    return (speed < PLANTED_SPEED_MPS) & low


def foot_skating_mps(pred_ankles_m: np.ndarray, planted: np.ndarray, fps: float) -> np.ndarray:
    """Horizontal speeds (m/s) of the predicted ankles ``[F, 2, 3]`` (world) where the truth's are
    ``planted [F, 2]`` (1-D, NaN-free: frames without output left out)."""
    speed = speeds_mps(pred_ankles_m, fps, horizontal=True)[planted]
    return speed[np.isfinite(speed)]


def foot_height_error_m(pred_ankles_m: np.ndarray, true_ankles_m: np.ndarray, planted: np.ndarray) -> np.ndarray:
    """Predicted minus true ankle height (m; negative: into the floor) where the truth is planted (1-D)."""
    diff = (pred_ankles_m[..., 1] - true_ankles_m[..., 1])[planted]
    return diff[np.isfinite(diff)]
