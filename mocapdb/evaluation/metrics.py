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
