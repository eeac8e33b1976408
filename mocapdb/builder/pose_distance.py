"""The pose distance of the method (Eq. 1) over many poses: :func:`pose_distances` (a distance
matrix) and :func:`nearest_poses` (each pose's nearest, without the matrix), numba kernels in a
joint-major layout, and the poses' checks and working precision the embedding shares.

Database poses are ``[N, J, 2]`` (``J = 14`` normalised 2D keypoints, unit bounding-box height).
The pose distance (Eq. 1) sums the Euclidean distances of corresponding joints (not squared).
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

from mocapdb.core.kernels import pose_distances_into


@njit(parallel=True, cache=True)
def distances_to_joint_major(a: np.ndarray, bt: np.ndarray) -> np.ndarray:
    """Eq. 1 distances ``[N, M]`` float64 of poses ``a [N, J, 2]`` to joint-major ``bt [2, J, M]``.
    Per-joint differences and square roots run in the inputs' precision, the sums in float64."""
    joints = np.arange(a.shape[1])
    out = np.zeros((a.shape[0], bt.shape[2]))
    for i in prange(a.shape[0]):
        pose_distances_into(bt[0], bt[1], 0, bt.shape[2], a[i], joints, out[i])
    return out


@njit(parallel=True, cache=True)
def _nearest_kernel(a: np.ndarray, bt: np.ndarray, out: np.ndarray) -> None:
    """``out[i]`` = index of the pose of joint-major ``bt [2, J, M]`` nearest ``a[i]`` under Eq. 1 (the
    first on ties), from the distances :func:`distances_to_joint_major` gives, one ``[M]`` row per pose."""
    joints = np.arange(a.shape[1])
    for i in prange(a.shape[0]):
        row = np.zeros(bt.shape[2])
        pose_distances_into(bt[0], bt[1], 0, bt.shape[2], a[i], joints, row)
        out[i] = np.argmin(row)


def as_poses(poses: np.ndarray, dtype) -> np.ndarray:
    """C-contiguous ``[N, J, 2]`` poses of ``dtype``; ValueError for another shape."""
    poses = np.asarray(poses)
    if poses.ndim != 3 or poses.shape[2] != 2:
        raise ValueError(f"poses must be [N, J, 2], got shape {poses.shape}")
    return np.ascontiguousarray(poses, dtype=dtype)


def joint_major(poses: np.ndarray) -> np.ndarray:
    """``[M, J, 2]`` → contiguous ``[2, J, M]``: x then y, joint-major (the kernels' vectorised layout)."""
    return np.ascontiguousarray(poses.transpose(2, 1, 0))


def work_dtype(*arrays: np.ndarray) -> type:
    """float32 when every input is float32 (the database's storage type), else float64."""
    return np.float32 if all(np.asarray(x).dtype == np.float32 for x in arrays) else np.float64


def pose_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Eq. 1 distance matrix ``[N, M]`` float64 between poses ``a [N, J, 2]`` and ``b [M, J, 2]``.

    ``dist(p, q) = Σ_k ||p_k − q_k||`` over the ``J`` joints, in the poses' units. Two float32
    inputs are differenced in float32 (relative error ~1e-6); otherwise everything is float64.
    """
    dtype = work_dtype(a, b)
    a, b = as_poses(a, dtype), as_poses(b, dtype)
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"joint counts differ: {a.shape[1]} vs {b.shape[1]}")
    return distances_to_joint_major(a, joint_major(b))


def nearest_poses(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """int64 ``[N]``: for each pose of ``a [N, J, 2]`` the index of the nearest pose of ``b [M, J, 2]``
    under Eq. 1 (the first on ties): ``pose_distances(a, b).argmin(axis=1)`` without the ``[N, M]``
    matrix."""
    dtype = work_dtype(a, b)
    a, b = as_poses(a, dtype), as_poses(b, dtype)
    out = np.empty(len(a), dtype=np.int64)
    _nearest_kernel(a, joint_major(b), out)
    return out
