"""ElliPose: 3D joints from two uncalibrated views (Grund, Tanke, Gall; ``../shared/method``).

Stage 1 estimates camera 2's pose from the body keypoints of all frames (essential matrix) and
triangulates. Stage 2 fits one origin-centred ellipsoid to the bone vectors (one scale per bone
type; the fit discounts each bone's triangulation noise), undistorts the 3D points partway along
its axes, re-fits both cameras by PnP and re-triangulates, until the ellipsoid is nearly a sphere.
Stage 3 makes bone lengths constant against the 2D evidence. Views without parallax and camera
poses that put the people behind a camera are refused (``check_parallax``, ``check_geometry``).
Decisions: ``data_specs/stereo.md``. Coordinates: camera 1's OpenCV axes (x right, y down, z
forward), the baseline = 1 unless ``camera_distance_m`` gives metres.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.errors import MocapdbError

# Rigid bones over the 14 keypoints (i, j, type). The neck (mid-shoulder) and pelvis (mid-hip)
# are derived points, so only the hip and shoulder lines stand for the torso; the nose moves
# with the head and has no rigid partner.
RIGID_BONES: tuple[tuple[int, int, int], ...] = (
    (8, 11, 0),              # hip line
    (8, 9, 1), (11, 12, 1),  # thighs
    (9, 10, 2), (12, 13, 2),  # shins
    (2, 5, 3),               # shoulder line
    (2, 3, 4), (5, 6, 4),    # upper arms
    (3, 4, 5), (6, 7, 5),    # forearms
)


class StereoError(MocapdbError, ValueError):
    """Input the stereo reconstruction cannot use; the message says why."""


@dataclass
class StereoConfig:
    """The method's parameters (defaults: the paper's)."""

    ransac_threshold: float = 0.005   # essential-matrix RANSAC, normalised image units
    ransac_prob: float = 0.999
    epsilon: float = 0.025            # sphericity that stops stage 2
    delta: float = 0.2                # bone inlier band: length within 1 ± delta of its scale
    gamma: float = 0.2                # fraction of the ellipsoid undistortion applied per round
    max_rounds: int = 20
    max_draws: int = 2500
    good_samples: int = 100
    pnp_iterations: int = 10000
    alpha: float = 20.0               # stage 3 weight of the bone term
    bone_rounds: int = 5              # stage 3 rounds m
    confidence: float = 0.3
    camera_distance_m: float | None = None
    seed: int = 0
    min_correspondences: int = 50
    noise_correction: bool = True     # remove triangulation-noise bias from the ellipsoid fit (not in the paper)

    def __post_init__(self) -> None:
        distance = self.camera_distance_m
        if distance is not None and not (isinstance(distance, (int, float)) and math.isfinite(distance)
                                         and distance > 0):
            raise StereoError(f"camera distance (--camera-distance) {distance!r} is not a positive number of metres")


@dataclass
class StereoResult:
    """The reconstruction in camera 1's OpenCV axes (metres when ``scaled``, else baselines).

    ``points_m [T, J, 3]`` final joints (NaN where invalid), ``stage1_points``/``stage2_points``
    the intermediate ones; camera 2 is ``x₂ = R x₁ + t`` (``stage1_R``, ``stage1_t``: its stage-1
    estimate); ``epsilons`` the sphericity of each ellipsoid round, ``kept_round`` the one kept.
    """

    points_m: np.ndarray
    stage1_points: np.ndarray
    stage2_points: np.ndarray
    R: np.ndarray
    t: np.ndarray
    stage1_R: np.ndarray
    stage1_t: np.ndarray
    scaled: bool
    epsilons: list[float] = field(default_factory=list)
    kept_round: int = 0
    warnings: list[str] = field(default_factory=list)
    valid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))


# ---- geometry ---------------------------------------------------------------------------------

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


# ---- stage 3 ----------------------------------------------------------------------------------

def refine_bone_lengths(points: np.ndarray, P1: np.ndarray, P2: np.ndarray, n1: np.ndarray, n2: np.ndarray,
                        valid: np.ndarray, bones=RIGID_BONES, alpha: float = 20.0, rounds: int = 5) -> np.ndarray:
    """Stage 3: per frame, least squares of the DLT reprojection rows of both views plus
    ``alpha`` × Σ_b ‖v_b − w_b‖², with ``w_b`` the current bone direction at the bone's mean
    length; ``rounds`` times. The DLT row ``(u P₃ − P₁)·[p; 1]`` is the point's offset from its
    ray times its depth, i.e. roughly a distance in the points' own units, like the bone term.
    ``points [T, J, 3]``, ``n1, n2 [T, J, 2]`` normalised image coordinates, ``valid [T, J]``.
    """
    n_frames, n_joints = valid.shape
    rep_m, rep_b = _reprojection_blocks(P1, P2, n1, n2, valid)               # [T, J, 3, 3], [T, J, 3]
    pairs = np.array([(i, j) for i, j, _ in bones])
    out = points.copy()
    for _ in range(rounds):
        vec = out[:, pairs[:, 1]] - out[:, pairs[:, 0]]                      # [T, nb, 3]
        length = np.linalg.norm(vec, axis=-1)
        both = valid[:, pairs[:, 0]] & valid[:, pairs[:, 1]]
        target_len = np.where(both, length, 0.0).sum(axis=0) / np.maximum(both.sum(axis=0), 1)
        with np.errstate(invalid="ignore", divide="ignore"):
            target = np.where(both[..., None], vec * (target_len / length)[..., None], 0.0)
        out = _solve_frames(rep_m, rep_b, pairs, both, target, alpha, valid)
    return np.where(valid[..., None], out, np.nan)


def _reprojection_blocks(P1, P2, n1, n2, valid):
    """Per joint, the 3×3 normal matrix and right-hand side of its four DLT rows."""
    blocks = np.zeros(valid.shape + (3, 3))
    rhs = np.zeros(valid.shape + (3,))
    for P, n in ((P1, n1), (P2, n2)):
        for axis in range(2):
            row = np.where(valid[..., None, None], n[..., axis:axis + 1, None] * P[2] - P[axis], 0.0)[..., 0, :]
            a, b = row[..., :3], -row[..., 3]
            blocks += a[..., :, None] * a[..., None, :]
            rhs += a * b[..., None]
    return blocks, rhs


def _solve_frames(rep_m, rep_b, pairs, both, target, alpha, valid):
    """Batched normal equations over frames: unknowns are the 3J coordinates."""
    n_frames, n_joints = valid.shape
    M = np.zeros((n_frames, n_joints, 3, n_joints, 3))
    b = rep_b.copy()
    idx = np.arange(n_joints)
    M[:, idx, :, idx, :] = np.moveaxis(rep_m, 1, 0)
    eye = np.eye(3)
    for k, (i, j) in enumerate(pairs):
        w = alpha * both[:, k][:, None, None]
        M[:, i, :, i, :] += w * eye
        M[:, j, :, j, :] += w * eye
        M[:, i, :, j, :] -= w * eye
        M[:, j, :, i, :] -= w * eye
        b[:, j] += alpha * both[:, k, None] * target[:, k]
        b[:, i] -= alpha * both[:, k, None] * target[:, k]
    M[:, idx, :, idx, :] += np.moveaxis(np.where(valid, 0.0, 1.0)[..., None, None] * eye, 1, 0)  # fix invalid at 0
    sol = np.linalg.solve(M.reshape(n_frames, 3 * n_joints, 3 * n_joints), b.reshape(n_frames, -1, 1))
    return sol.reshape(n_frames, n_joints, 3)


# ---- the pipeline -----------------------------------------------------------------------------

def _bone_samples(points: np.ndarray, valid: np.ndarray, bones,
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


def _projection(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.hstack([R, t.reshape(3, 1)])


def _triangulate_all(R, t, n1, n2, valid) -> np.ndarray:
    out = np.full(valid.shape + (3,), np.nan)
    out[valid] = triangulate(_projection(np.eye(3), np.zeros(3)), _projection(R, t), n1[valid], n2[valid])
    return out


def _pnp(points: np.ndarray, normalized: np.ndarray, R: np.ndarray, t: np.ndarray,
         config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """A camera's pose fitted to 3D points and their normalised image coordinates (PnP RANSAC from ``R, t``)."""
    rvec, _ = cv2.Rodrigues(R)
    ok, rvec, tvec, _ = cv2.solvePnPRansac(points.astype(np.float64), normalized.astype(np.float64), np.eye(3),
                                           None, rvec.copy(), t.reshape(3, 1).astype(np.float64).copy(),
                                           useExtrinsicGuess=True, iterationsCount=config.pnp_iterations,
                                           reprojectionError=2 * config.ransac_threshold, confidence=0.999)
    return (cv2.Rodrigues(rvec)[0], tvec.ravel()) if ok else (R, t)


def _refit_cameras(points: np.ndarray, n1: np.ndarray, n2: np.ndarray, R: np.ndarray, t: np.ndarray,
                   config: StereoConfig) -> tuple[np.ndarray, np.ndarray]:
    """Both cameras re-fitted by PnP to corrected 3D points; camera 2 relative to camera 1, baseline 1."""
    R1, t1 = _pnp(points, n1, np.eye(3), np.zeros(3), config)
    R2, t2 = _pnp(points, n2, R, t, config)
    R_rel = R2 @ R1.T
    t_rel = t2 - R_rel @ t1
    return R_rel, t_rel / np.linalg.norm(t_rel)


# OpenCV's MAGSAC++ member of its RANSAC family. Plain cv2.RANSAC returns the best minimal-sample
# model unrefined: with σ = 5 px detector noise it put camera 2 up to 46° off on the synthetic
# front pair (MAGSAC++: 7°; tools/eval_stereo.py).
ESSENTIAL_METHOD = cv2.USAC_MAGSAC


def _stage1(n1, n2, valid, config, focal_px: float):
    count = int(valid.sum())
    if count < max(config.min_correspondences, 8):
        raise StereoError(f"{count} confident keypoint correspondences between the views; at least "
                          f"{max(config.min_correspondences, 8)} are needed")
    e, _ = cv2.findEssentialMat(n1[valid], n2[valid], np.eye(3), method=ESSENTIAL_METHOD,
                                prob=config.ransac_prob, threshold=config.ransac_threshold)
    if e is None:
        raise StereoError("no essential matrix fits the correspondences")
    check_parallax(n1[valid], n2[valid], e[:3], focal_px)
    _, R, t, _ = cv2.recoverPose(e[:3], n1[valid], n2[valid], np.eye(3))
    return R, t.ravel() / np.linalg.norm(t)


def sampson_distance(essential: np.ndarray, n1: np.ndarray, n2: np.ndarray) -> np.ndarray:
    """First-order geometric (Sampson) distance ``[...]`` of normalised correspondences ``[..., 2]``."""
    h1 = np.concatenate([n1, np.ones(n1.shape[:-1] + (1,))], axis=-1)
    h2 = np.concatenate([n2, np.ones(n2.shape[:-1] + (1,))], axis=-1)
    e1 = h1 @ essential.T          # E x1
    e2 = h2 @ essential            # Eᵀ x2
    num = np.sum(h2 * e1, axis=-1)
    den = e1[..., 0] ** 2 + e1[..., 1] ** 2 + e2[..., 0] ** 2 + e2[..., 1] ** 2
    return np.abs(num) / np.sqrt(np.maximum(den, 1e-30))


def _stage2(points, n1, n2, valid, R, t, config, bones, warnings):
    """Ellipsoid rounds; returns the points, R, t of the round with the lowest ε and all ε."""
    rng = np.random.default_rng(config.seed)
    n_types = max(b for _, _, b in bones) + 1
    best = (np.inf, points, R, t, 0)
    epsilons = []
    for round_ in range(config.max_rounds):
        cov = None
        if config.noise_correction:
            cov = np.zeros(valid.shape + (3, 3))
            cov[valid] = triangulation_covariance(points[valid], R, t, n1[valid], n2[valid])
        vectors, types, cov = _bone_samples(points, valid, bones, cov)
        if len(np.unique(np.round(vectors, 6), axis=0)) < 10 * (n_types + 5):
            warnings.append("sequence too short or too still for the ellipsoid fit: stage-1 geometry kept")
            break
        try:
            A, _, _ = ransac_ellipsoid(vectors, types, n_types, valid.shape[0], config, rng, cov)
        except StereoError as exc:
            warnings.append(f"ellipsoid fit failed ({exc}): round {best[4]} kept")
            break
        eps = sphericity(A)
        epsilons.append(eps)
        if eps < best[0]:
            best = (eps, points, R, t, round_)
        if eps < config.epsilon or not np.all(np.linalg.eigvalsh(A) > 0):
            break
        corrected = undistort(points, A, config.gamma)
        R, t = _refit_cameras(corrected[valid], n1[valid], n2[valid], R, t, config)
        points = _triangulate_all(R, t, n1, n2, valid)
    return best[1], best[2], best[3], epsilons, best[4]


def reconstruct(x1: np.ndarray, c1: np.ndarray, x2: np.ndarray, c2: np.ndarray, cam1: CameraModel,
                cam2: CameraModel, config: StereoConfig, bones=RIGID_BONES) -> StereoResult:
    """Stages 1–3 on keypoints ``x [T, J, 2]`` (pixels) with confidences ``c [T, J]``.

    Only the cameras' intrinsics and distortion are used; camera 2's pose is estimated. StereoError
    when the views have no parallax (:func:`check_parallax`, after stage 1) or the final cameras
    cannot be right (:func:`check_geometry`).
    """
    if x1.shape != x2.shape or c1.shape != c2.shape or x1.shape[:2] != c1.shape:
        raise StereoError(f"the views do not match: {x1.shape[0]} frames × {x1.shape[1]} joints against "
                          f"{x2.shape[0]} × {x2.shape[1]} (confidences {c1.shape}, {c2.shape})")
    valid = ((c1 >= config.confidence) & (c2 >= config.confidence)
             & np.isfinite(x1).all(axis=-1) & np.isfinite(x2).all(axis=-1))
    n1, n2 = np.zeros(x1.shape), np.zeros(x2.shape)
    n1[valid], n2[valid] = cam1.undistort_normalized(x1[valid]), cam2.undistort_normalized(x2[valid])
    focal_px = 0.25 * float(cam1.K[0, 0] + cam1.K[1, 1] + cam2.K[0, 0] + cam2.K[1, 1])
    R1, t1 = _stage1(n1, n2, valid, config, focal_px)
    stage1 = _triangulate_all(R1, t1, n1, n2, valid)
    warnings: list[str] = []
    stage2, R, t, epsilons, kept = _stage2(stage1, n1, n2, valid, R1, t1, config, bones, warnings)
    final = refine_bone_lengths(np.nan_to_num(stage2), _projection(np.eye(3), np.zeros(3)), _projection(R, t),
                                n1, n2, valid, bones, config.alpha, config.bone_rounds)
    warnings += check_geometry(final, valid, R, t)
    scale = config.camera_distance_m or 1.0
    return StereoResult(final * scale, stage1 * scale, stage2 * scale, R, t * scale, R1, t1 * scale,
                        config.camera_distance_m is not None, epsilons, kept, warnings, valid)


# ---- sanity of the result ---------------------------------------------------------------------

# No parallax (checked after stage 1's essential matrix): a single homography maps view 1's
# keypoints onto view 2's within HOMOGRAPHY_RATIO times the epipolar residual (medians, pixels).
# Measured ratios: 14-83 on the Pose2Sim pairs, 18 and 12 on the synthetic side and front pairs;
# two cameras 0.5 m apart 4.6 m from the person 6.6, 0.2 m apart 3.6; 5 cm apart or at one place
# (turned 10°) 2.7-3.3 over 2-5 px of noise (those above the ratio fail check_geometry instead);
# the same view shifted, scaled or mirrored 0.
HOMOGRAPHY_RATIO = 3.4
NOISE_FLOOR_PX = 0.5   # the epipolar residual counted at least this much (noise-free views)
MAX_HOMOGRAPHY_POINTS = 3000  # correspondences the homography is fitted to (its residual: all)
# The final cameras are refused when the people's median joint lies behind camera 1 or camera 2 in
# more than BEHIND_REFUSED of the frames, or when the median angle at which the two cameras' rays
# meet at a joint (the parallax) is under MIN_PARALLAX_DEG (a warning under LOW_PARALLAX_DEG).
# Median parallax: 46-148° on the Pose2Sim pairs, 44-87° on the synthetic ones; the same view
# twice 0.6°, cameras at one place 0.14°. `mocapdb stereo` warns per person above BEHIND_WARNED.
BEHIND_REFUSED = 0.5
BEHIND_WARNED = 0.05
MIN_PARALLAX_DEG = 1.0
LOW_PARALLAX_DEG = 5.0


def homography_residual(n1: np.ndarray, n2: np.ndarray, essential: np.ndarray,
                        focal_px: float) -> tuple[float, float] | None:
    """Median residuals (px) of correspondences ``n1, n2 [N, 2]`` (normalised) under the best
    homography (RANSAC, 3 px, on at most :data:`MAX_HOMOGRAPHY_POINTS` of them) and under ``essential`` (Sampson distance, at least
    :data:`NOISE_FLOOR_PX`); None when no homography is found. ``focal_px`` turns them into pixels."""
    fit = np.linspace(0, len(n1) - 1, min(len(n1), MAX_HOMOGRAPHY_POINTS)).astype(int)  # evenly spread
    # Few draws suffice: a view pair a homography explains has most points inliers (found at once);
    # for a real pair the best of many draws would still be far off.
    H, _ = cv2.findHomography(n1[fit], n2[fit], cv2.RANSAC, 3.0 / focal_px, maxIters=200, confidence=0.995)
    if H is None:
        return None
    mapped = np.c_[n1, np.ones(len(n1))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = np.linalg.norm(mapped[:, :2] / mapped[:, 2:] - n2, axis=1)
    homography_px = float(np.median(np.where(np.isfinite(moved), moved, np.inf))) * focal_px
    epipolar_px = max(float(np.median(sampson_distance(essential, n1, n2))) * focal_px, NOISE_FLOOR_PX)
    return homography_px, epipolar_px


def check_parallax(n1: np.ndarray, n2: np.ndarray, essential: np.ndarray, focal_px: float) -> None:
    """StereoError when a homography explains the correspondences about as well as the essential
    matrix does (:data:`HOMOGRAPHY_RATIO`): the views then have no parallax, and the relative pose and
    the depths are not determined."""
    residuals = homography_residual(n1, n2, essential, focal_px)
    if residuals is not None and residuals[0] <= HOMOGRAPHY_RATIO * residuals[1]:
        raise StereoError(
            f"the two views have no parallax: one homography maps view 1's keypoints onto view 2's (median "
            f"{residuals[0]:.1f} px off, against {residuals[1]:.1f} px for the epipolar geometry). They are the "
            "same view (possibly shifted, scaled, mirrored or cropped) or two cameras at the same place, so depth "
            "cannot be recovered; give the keypoints of two cameras set apart")


def behind_cameras(points: np.ndarray, valid: np.ndarray, R: np.ndarray, t: np.ndarray) -> tuple[float, float, int]:
    """Shares of the frames of ``points [T, J, 3]`` (camera 1's axes, ``valid [T, J]``) whose median
    valid joint is behind camera 1 and behind camera 2 (``x₂ = R x₁ + t``), and the frames counted."""
    ok = valid & np.isfinite(points).all(axis=-1)
    frames = ok.any(axis=1)
    if not frames.any():
        return 0.0, 0.0, 0
    depth1 = np.where(ok, points[..., 2], np.nan)[frames]
    depth2 = np.where(ok, (points @ R.T + np.ravel(t))[..., 2], np.nan)[frames]
    return (float(np.mean(np.nanmedian(depth1, axis=1) <= 0)), float(np.mean(np.nanmedian(depth2, axis=1) <= 0)),
            int(frames.sum()))


def describe_pose(R: np.ndarray, t: np.ndarray) -> str:
    """``camera 2 at rotation A°, baseline direction (x, y, z)`` for messages."""
    direction = np.ravel(t) / np.linalg.norm(t)
    return (f"camera 2 at rotation {_angle_deg(R):.1f}°, baseline direction "
            f"({', '.join(f'{v:.2f}' for v in direction)}) in camera 1's axes")


def behind_message(who: str, camera: int, share: float, frames: int, R: np.ndarray, t: np.ndarray) -> str:
    """Why a pose that puts ``who`` behind a camera cannot be right."""
    return (f"the estimated camera pose ({describe_pose(R, t)}) puts {who} behind camera {camera} in "
            f"{round(share * frames)} of {frames} frames: it cannot be right. The views are probably not two cameras "
            "filming the same scene from two places (the same view twice? different takes? mirrored keypoints or "
            "a wrong --keypoints layout?), or the intrinsics are wrong")


def check_geometry(points: np.ndarray, valid: np.ndarray, R: np.ndarray, t: np.ndarray) -> list[str]:
    """StereoError when camera 2's pose ``x₂ = R x₁ + t`` cannot be right for ``points [T, J, 3]``
    (camera 1's axes, ``valid [T, J]``): the people behind a camera in most frames, or (almost) no
    parallax between the views. Returns a warning when the parallax is low."""
    ok = valid & np.isfinite(points).all(axis=-1)
    if not ok.any():
        raise StereoError("no joint could be triangulated: the views share no usable geometry")
    *shares, frames = behind_cameras(points, valid, R, t)
    for camera, share in enumerate(shares, start=1):
        if share > BEHIND_REFUSED:
            raise StereoError(behind_message("the people", camera, share, frames, R, t))
    centre2 = -R.T @ np.ravel(t)
    p = points[ok]
    ray1 = p / np.linalg.norm(p, axis=1, keepdims=True)
    ray2 = (p - centre2) / np.linalg.norm(p - centre2, axis=1, keepdims=True)
    parallax = float(np.degrees(np.median(np.arccos(np.clip(np.sum(ray1 * ray2, axis=1), -1.0, 1.0)))))
    if parallax < MIN_PARALLAX_DEG:
        raise StereoError(
            f"the two views have almost no parallax (the rays of a joint meet at a median {parallax:.2f}°, "
            f"under {MIN_PARALLAX_DEG:g}°; {describe_pose(R, t)}): the cameras are at (nearly) the same place or "
            "the two views are the same, so depth cannot be recovered; film with two cameras set apart")
    if parallax < LOW_PARALLAX_DEG:
        return [f"little parallax between the views (the rays of a joint meet at a median {parallax:.1f}°): the "
                "cameras are close together for the distance to the people, depth is poorly determined"]
    return []


def _angle_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
