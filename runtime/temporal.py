"""Temporal choice among search candidates: the method's Eq. 2 (numba).

For candidate c (database frame f, yaw v) and the track's last w reconstructed skeletons
h_1 … h_w (h_1 the most recent), the cost is

    Σ_i ω_i Σ_k λ_k ‖log(h_{i,k}⁻¹ q_{f−i,k})‖² / Σ_i ω_i

over the rig joints k, where q_{f−i} are the rotations of the i-th frame before f in the same
clip (clamped at the clip's first frame) with the root turned by yaw v, ω the window weights and
λ the joint weights. ‖log(a⁻¹b)‖ is the half rotation angle, ``arccos |a·b|``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapdb.core.kernels import quat_abs_dot, quat_mul_into


@njit(cache=True, fastmath=True)
def _angle_sq(dot: float) -> float:
    """Squared half-angle ``arccos(|a·b|)²`` from the absolute dot product of two quaternions."""
    angle = np.arccos(min(dot, 1.0))
    return angle * angle


@njit(cache=True, fastmath=True)
def temporal_costs(db_quats: np.ndarray, clip_first: np.ndarray, yaw_quats: np.ndarray,
                   cand_frames: np.ndarray, cand_yaws: np.ndarray, history: np.ndarray, n_hist: int,
                   window_weights: np.ndarray, joint_weights: np.ndarray) -> np.ndarray:
    """Eq. 2 cost ``[C]`` of each candidate against ``history [w, R, 4]`` (most recent first).

    ``db_quats [F, R, 4]`` database rotations (root in the mocap world), ``clip_first [F]`` the
    first frame of each frame's clip, ``yaw_quats [V, 4]`` the database yaws as quaternions.
    Only the first ``n_hist`` history entries are used.
    """
    n_joints = db_quats.shape[1]
    costs = np.zeros(cand_frames.shape[0])
    root = np.empty(4)  # the candidate's root turned by its yaw
    for c in range(cand_frames.shape[0]):
        f, v = cand_frames[c], cand_yaws[c]
        total, weight = 0.0, 0.0
        for i in range(n_hist):
            g = max(f - 1 - i, clip_first[f])
            quat_mul_into(yaw_quats[v], db_quats[g, 0], root)
            term = joint_weights[0] * _angle_sq(quat_abs_dot(root, history[i, 0]))
            for k in range(1, n_joints):
                term += joint_weights[k] * _angle_sq(quat_abs_dot(db_quats[g, k], history[i, k]))
            total += window_weights[i] * term
            weight += window_weights[i]
        costs[c] = total / weight if weight > 0 else 0.0
    return costs


@njit(cache=True)
def yawed_rotations(db_quats: np.ndarray, frame: int, yaw_quat: np.ndarray) -> np.ndarray:
    """Rotations ``[R, 4]`` (float64) of database ``frame`` with the root turned by ``yaw_quat``."""
    out = db_quats[frame].astype(np.float64)
    quat_mul_into(yaw_quat, out[0].copy(), out[0])
    return out


def yaw_quaternion(yaw_deg: float) -> np.ndarray:
    """The rotation about the vertical (y) axis by ``yaw_deg`` as a quaternion (w, x, y, z)."""
    half = np.radians(yaw_deg) / 2.0
    return np.array([np.cos(half), 0.0, np.sin(half), 0.0])
