"""Two-view geometry of `mocapdb stereo`: triangulation, epipolar distance, camera re-fitting.

Camera 1 is ``[I | 0]`` and camera 2 ``x₂ = R x₁ + t`` in camera 1's OpenCV axes (x right, y down,
z forward); image points are undistorted normalised coordinates. The essential matrix method used
for the relative pose (:data:`ESSENTIAL_METHOD`) is shared by the camera estimate
(:mod:`mocapdb.stereo.ellipose`) and the matching of people (:mod:`mocapdb.stereo.people`).
"""
from __future__ import annotations

import cv2
import numpy as np

from mocapdb.stereo.config import StereoConfig

# OpenCV's MAGSAC++ member of its RANSAC family. Plain cv2.RANSAC returns the best minimal-sample
# model unrefined: with σ = 5 px detector noise it put camera 2 up to 46° off on the synthetic
# front pair (MAGSAC++: 7°; tools/eval_stereo.py).
ESSENTIAL_METHOD = cv2.USAC_MAGSAC


def triangulate(P1: np.ndarray, P2: np.ndarray, n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """Linear (DLT) triangulation of ``N`` correspondences ``[N, 2]`` by 3×4 matrices → ``[N, 3]``.

    The four rows ``u P₃ − P₁``, ``v P₃ − P₂`` per point are solved for ``[p; 1]`` in the least-squares
    sense (3×3 normal equations, batched), which equals the homogeneous SVD solution for points
    at finite depth.
    """
    rows = np.stack([n1[:, :1] * P1[2] - P1[0], n1[:, 1:] * P1[2] - P1[1],
                     n2[:, :1] * P2[2] - P2[0], n2[:, 1:] * P2[2] - P2[1]], axis=1)  # [N, 4, 4]
    a, b = rows[..., :3], -rows[..., 3]
    normal = np.einsum("nki,nkj->nij", a, a)
    return np.linalg.solve(normal, np.einsum("nki,nk->ni", a, b)[..., None])[..., 0]


def projection_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The 3×4 matrix ``[R | t]`` of a camera in normalised coordinates."""
    return np.hstack([R, t.reshape(3, 1)])


def triangulate_all(R, t, n1, n2, valid) -> np.ndarray:
    """Joints ``[T, J, 3]`` triangulated from camera 1 = [I | 0] and camera 2 = [R | t] where ``valid [T, J]``
    (NaN elsewhere); ``n1, n2 [T, J, 2]`` normalised coordinates."""
    out = np.full(valid.shape + (3,), np.nan)
    out[valid] = triangulate(projection_matrix(np.eye(3), np.zeros(3)), projection_matrix(R, t), n1[valid], n2[valid])
    return out


def triangulation_covariance(points: np.ndarray, R: np.ndarray, t: np.ndarray, n1: np.ndarray,
                             n2: np.ndarray) -> np.ndarray:
    """First-order covariances ``[N, 3, 3]`` of points ``[N, 3]`` triangulated from camera 1 = [I | 0]
    and camera 2 = [R | t]: ``σ² (JᵀJ)⁻¹`` with ``J`` the 4×3 Jacobian of both projections and
    the image noise σ (normalised units) from the median squared reprojection residual, which
    for two views has one degree of freedom (median of χ²₁ = 0.455).
    """
    jac, residual2 = [], np.zeros(len(points))
    for rot, shift, observed in ((np.eye(3), np.zeros(3), n1), (R, t, n2)):
        q = points @ rot.T + shift
        inv_z = 1.0 / q[:, 2]
        d = np.zeros((len(points), 2, 3))
        d[:, 0, 0] = d[:, 1, 1] = inv_z
        d[:, :, 2] = -q[:, :2] * inv_z[:, None] ** 2
        jac.append(d @ rot)
        residual2 += np.sum((q[:, :2] * inv_z[:, None] - observed) ** 2, axis=1)
    J = np.concatenate(jac, axis=1)
    sigma2 = np.median(residual2) / 0.455
    return sigma2 * np.linalg.inv(np.einsum("nki,nkj->nij", J, J))


def sampson_distance(essential: np.ndarray, n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) distance ``[...]`` of normalised correspondences ``[..., 2]``."""
    h1 = np.concatenate([n1, np.ones(n1.shape[:-1] + (1,))], axis=-1)
    h2 = np.concatenate([n2, np.ones(n2.shape[:-1] + (1,))], axis=-1)
    e1 = h1 @ essential.T          # E x1
    e2 = h2 @ essential            # Eᵀ x2
    num = np.sum(h2 * e1, axis=-1)
    den = e1[..., 0] ** 2 + e1[..., 1] ** 2 + e2[..., 0] ** 2 + e2[..., 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-30))


def _pnp(points: np.ndarray, normalized: np.ndarray, R: np.ndarray, t: np.ndarray,
         config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """A camera's pose fitted to 3D points and their normalised image coordinates (PnP RANSAC from ``R, t``)."""
    rvec, _ = cv2.Rodrigues(R)
    ok, rvec, tvec, _ = cv2.solvePnPRansac(points.astype(np.float64), normalized.astype(np.float64), np.eye(3),
                                           None, rvec.copy(), t.reshape(3, 1).astype(np.float64).copy(),
                                           useExtrinsicGuess=True, iterationsCount=config.pnp_iterations,
                                           reprojectionError=2 * config.ransac_threshold, confidence=0.999)
    return (cv2.Rodrigues(rvec)[0], tvec.ravel()) if ok else (R, t)


def refit_cameras(points: np.ndarray, n1: np.ndarray, n2: np.ndarray, R: np.ndarray, t: np.ndarray,
                  config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras re-fitted by PnP to corrected 3D points; camera 2 relative to camera 1, baseline 1."""
    R1, t1 = _pnp(points, n1, np.eye(3), np.zeros(3), config)
    R2, t2 = _pnp(points, n2, R, t, config)
    R_rel = R2 @ R1.T
    t_rel = t2 - R_rel @ t1
    return R_rel, t_rel / np.linalg.norm(t_rel)


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees."""
    return float(np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1.0, 1.0))))
