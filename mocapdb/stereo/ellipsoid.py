"""ElliPose stage 2's ellipsoid: one origin-centred ellipsoid fitted to the bone vectors.

Bone vectors of a rigid skeleton reconstructed with a wrong camera pose lie on an ellipsoid (one
scale per bone type) instead of a sphere; Turner's linear system fits it, robustly by RANSAC, the
fit discounting each bone's triangulation noise. :func:`sphericity` measures how far it is from a
sphere and :func:`undistort` moves points partway to one. The rounds: :mod:`mocapdb.stereo.ellipose`.
"""
from __future__ import annotations

import numpy as np

from mocapdb.stereo.config import StereoConfig, StereoError


def bone_samples(points: np.ndarray, valid: np.ndarray, bones,
                 point_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Vectors ``[N, 3]``, types ``[N]`` and (with ``point_cov [T, J, 3, 3]``) noise covariances
    ``[N, 3, 3]`` of every bone whose two joints are valid."""
    vectors, types, covs = [], [], []
    for i, j, b in bones:
        ok = valid[:, i] & valid[:, j]
        vectors.append(points[ok, j] - points[ok, i])
        types.append(np.full(int(ok.sum()), b))
        if point_cov is not None:
            covs.append(point_cov[ok, i] + point_cov[ok, j])
    return np.concatenate(vectors), np.concatenate(types), (np.concatenate(covs) if covs else None)


def _design(vectors: np.ndarray, bone_type: np.ndarray, n_types: int,
            noise_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Turner's linear ellipsoid system with one constant per bone type: rows and right-hand side.

    The system is linear in each sample's second moments ``v vᵀ``; with ``noise_cov [N, 3, 3]``
    (each vector's noise covariance) they are replaced by ``v vᵀ − Σ``, removing the bias that
    triangulation noise (largest along depth) adds to the squared lengths.
    """
    moments = vectors[:, :, None] * vectors[:, None, :]
    if noise_cov is not None:
        moments = moments - noise_cov
    xx, yy, zz = moments[:, 0, 0], moments[:, 1, 1], moments[:, 2, 2]
    rows = np.zeros((len(vectors), 5 + n_types))
    rows[:, 0] = xx + yy - 2 * zz
    rows[:, 1] = xx - 2 * yy + zz
    rows[:, 2], rows[:, 3], rows[:, 4] = 4 * moments[:, 0, 1], 2 * moments[:, 0, 2], 2 * moments[:, 1, 2]
    rows[np.arange(len(vectors)), 5 + bone_type] = 1.0
    return rows, xx + yy + zz


def _shape_from(params: np.ndarray) -> np.ndarray:
    """Quadratic forms ``[..., 3, 3]`` (trace 3) from Turner parameters ``[..., 5 + B]``."""
    u, v, m, n, p = (params[..., i] for i in range(5))
    return np.stack([np.stack([1 - u - v, -2 * m, -n], -1),
                     np.stack([-2 * m, 1 - u + 2 * v, -p], -1),
                     np.stack([-n, -p, 1 + 2 * u - v], -1)], -2)


def fit_ellipsoid(vectors: np.ndarray, bone_type: np.ndarray, n_types: int,
                  noise_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares origin-centred ellipsoid ``vᵀ A v = scale_b²`` shared by all bone types.

    Returns ``A`` (symmetric, trace 3) and the per-type scales (the bone length that ``A``'s
    metric gives each type). ``vectors [N, 3]``, ``bone_type [N]`` in ``[0, n_types)``,
    ``noise_cov [N, 3, 3]`` optional (see :func:`_design`).
    """
    rows, rhs = _design(vectors, bone_type, n_types, noise_cov)
    if noise_cov is not None:
        weight = 1.0 / np.sqrt(_residual_variance(vectors, noise_cov))
        rows, rhs = rows * weight[:, None], rhs * weight
    params = np.linalg.lstsq(rows, rhs, rcond=None)[0]
    return _shape_from(params), np.sqrt(np.maximum(params[5:], 0.0))


def _residual_variance(vectors: np.ndarray, noise_cov: np.ndarray) -> np.ndarray:
    """Variance of ``‖v‖² − s²`` under Gaussian noise ``Σ`` on ``v`` (near a sphere):
    ``4 vᵀΣv + 2 tr(Σ²)``. Short, noisy bones (the hip line) get little weight."""
    return (4 * np.einsum("ni,nij,nj->n", vectors, noise_cov, vectors)
            + 2 * np.einsum("nij,nji->n", noise_cov, noise_cov))


def sphericity(A: np.ndarray) -> float:
    """ε: sum of squared element differences between ``A`` scaled to trace 3 and the identity."""
    return float(np.sum((A * (3.0 / np.trace(A)) - np.eye(3)) ** 2))


def undistort(points: np.ndarray, A: np.ndarray, gamma: float) -> np.ndarray:
    """Move ``points [..., 3]`` a fraction ``gamma`` of the way along ``A``'s axes to a sphere."""
    values, vectors = np.linalg.eigh(A * (3.0 / np.trace(A)))
    step = vectors @ np.diag((1 - gamma) + gamma * np.sqrt(np.maximum(values, 1e-12))) @ vectors.T
    return points @ step.T


def ransac_ellipsoid(vectors: np.ndarray, bone_type: np.ndarray, n_types: int, n_frames: int,
                     config: StereoConfig, rng: np.random.Generator,
                     noise_cov: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robust :func:`fit_ellipsoid`: returns ``A``, scales and the inlier mask of the best draw.

    Minimal samples of ``n_types + 5`` bones (one of each type first); a bone is an inlier if
    undistorting by the candidate puts its length within ``1 ± delta`` of its type's scale;
    score Σ_b √inliers_b; a draw is good if its score exceeds √(0.25 T)·B; stops after
    ``good_samples`` good draws or ``max_draws``.
    """
    rows, rhs = _design(vectors, bone_type, n_types, noise_cov)
    tolerance = np.full(len(vectors), config.delta)
    if noise_cov is not None:  # a band of 3 noise σ where that is wider than δ: δ is for gross errors
        spread = np.sqrt(_residual_variance(vectors, noise_cov)) / (2 * np.sum(vectors ** 2, axis=1))
        tolerance = np.maximum(tolerance, 3 * spread)
    by_type = [np.flatnonzero(bone_type == b) for b in range(n_types)]
    moments_t = (vectors[:, :, None] * vectors[:, None, :]).reshape(-1, 9).T
    good_score = np.sqrt(0.25 * n_frames) * n_types
    best_score, best_inliers, good, drawn = -1.0, None, 0, 0
    while drawn < config.max_draws and good < config.good_samples:
        batch = min(100, config.max_draws - drawn)
        picks = np.concatenate([np.stack([rng.choice(ix, batch) for ix in by_type], axis=1),
                                rng.integers(0, len(vectors), (batch, 5))], axis=1)
        params = _solve_batch(rows[picks], rhs[picks])
        inliers, scores = _score(params, moments_t, bone_type, n_types, tolerance)
        good += int(np.sum(scores > good_score))
        k = int(np.argmax(scores))
        if scores[k] > best_score:
            best_score, best_inliers = float(scores[k]), inliers[k]
        drawn += batch
    if best_inliers is None or best_inliers.sum() < 5 + n_types:
        raise StereoError("no ellipsoid fits the bone vectors")
    cov = None if noise_cov is None else noise_cov[best_inliers]
    A, scales = fit_ellipsoid(vectors[best_inliers], bone_type[best_inliers], n_types, cov)
    return A, scales, best_inliers


def _solve_batch(rows: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solutions of the square systems ``[D, n, n]`` (pseudo-inverse: degenerate draws score low)."""
    return (np.linalg.pinv(rows) @ rhs[..., None])[..., 0]


def _score(params: np.ndarray, moments_t: np.ndarray, bone_type: np.ndarray, n_types: int,
           tolerance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inlier masks ``[D, N]`` and scores ``[D]`` of candidate parameters ``[D, 5 + B]``;
    a bone is an inlier when its undistorted length is within ``1 ± tolerance`` of its scale.
    ``moments_t [9, N]``: each vector's ``v vᵀ``, flattened."""
    shapes = _shape_from(params).reshape(len(params), 9)                     # [D, 9]
    scale2 = params[:, 5:]                                                   # [D, B]
    quad = shapes @ moments_t                                                # vᵀ A v, [D, N]
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.sqrt(quad / scale2[:, bone_type])
    inliers = np.abs(ratio - 1.0) <= tolerance                                   # NaN compares False
    counts = np.stack([inliers[:, bone_type == b].sum(axis=1) for b in range(n_types)], axis=1)
    return inliers, np.sqrt(counts).sum(axis=1)
