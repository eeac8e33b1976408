"""ElliPose: 3D joints from two uncalibrated views (Grund, Tanke, Gall; ``../shared/method``).

Stage 1 estimates camera 2's pose from the body keypoints of all frames (essential matrix) and
triangulates. Stage 2 fits one origin-centred ellipsoid to the bone vectors (one scale per bone
type; the fit discounts each bone's triangulation noise: :mod:`mocapdb.stereo.ellipsoid`),
undistorts the 3D points partway along its axes, re-fits both cameras by PnP and re-triangulates,
until the ellipsoid is nearly a sphere or ε stops falling near it (:func:`converged`; the round
with the lowest ε is kept; when the rounds do not converge a warning says so). Stage 3 makes bone
lengths constant against the 2D evidence (:mod:`mocapdb.stereo.bone_lengths`). Views without
parallax and camera poses that put the people behind a camera are refused
(:mod:`mocapdb.stereo.checks`). Decisions:
``data_specs/stereo.md``. Coordinates: camera 1's OpenCV axes (x right, y down, z forward), the
baseline = 1 unless ``camera_distance_m`` gives metres.
"""
from __future__ import annotations

import logging

import cv2
import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.progress import progress
from mocapdb.stereo.bone_lengths import RIGID_BONES, refine_bone_lengths
from mocapdb.stereo.checks import check_bone_coverage, check_geometry, check_parallax
from mocapdb.stereo.config import StereoConfig, StereoError, StereoResult
from mocapdb.stereo.ellipsoid import bone_samples, ransac_ellipsoid, sphericity, undistort
from mocapdb.stereo.relative_pose import (
    ESSENTIAL_METHOD,
    projection_matrix,
    refit_cameras,
    triangulate_all,
    triangulation_covariance,
)

LOG = logging.getLogger(__name__)


def converged(epsilons: list[float], config: StereoConfig) -> bool | None:
    """Whether the ellipsoid rounds converged: a round's sphericity ε fell below ``config.epsilon``
    (the method's stop: the bone vectors lie on a sphere), or the lowest ε, below
    ``config.plateau_epsilon``, was not lowered in the ``config.plateau_rounds`` rounds after it
    (the floor real detections' sliding joints leave: further rounds only trade the fit's noise);
    the rounds end there. None when no round ran (stage 2 off, or a sequence too short or still)."""
    if not epsilons:
        return None
    lowest = int(np.argmin(epsilons))
    settled = len(epsilons) - 1 - lowest >= config.plateau_rounds and epsilons[lowest] < config.plateau_epsilon
    return epsilons[lowest] < config.epsilon or settled


def convergence_warning(epsilons: list[float], kept: int, config: StereoConfig) -> str:
    """The warning of rounds that did not converge (:func:`converged`): their count, the last ε and the kept round's."""
    return (f"the ellipsoid fit did not converge: ε stayed at or above {config.epsilon:g} in all {len(epsilons)} "
            f"round(s) and did not settle below {config.plateau_epsilon:g} (at most {config.max_rounds}; last ε "
            f"{epsilons[-1]:.4f}; round {kept}, ε {epsilons[kept]:.4f}, is kept). The bone vectors do not lie on "
            "one sphere under any camera pose the rounds tried: noisy or sliding joints (real detections), or a "
            "camera estimate the rounds could not correct; the relative camera pose may be off by a few degrees")


def _stage1(n1, n2, valid, config, focal_px: float, person: np.ndarray):
    """Camera 2's pose ``R, t`` (baseline 1) from the essential matrix of all valid correspondences;
    StereoError when there are too few or the views have no parallax (:func:`check_parallax`, per
    person: ``person [T]`` of each frame)."""
    count = int(valid.sum())
    if count < max(config.min_correspondences, 8):
        raise StereoError(f"{count} confident keypoint correspondences between the views; at least "
                          f"{max(config.min_correspondences, 8)} are needed")
    e, _ = cv2.findEssentialMat(n1[valid], n2[valid], np.eye(3), method=ESSENTIAL_METHOD,
                                prob=config.ransac_prob, threshold=config.ransac_threshold)
    if e is None:
        raise StereoError("no essential matrix fits the correspondences")
    check_parallax(n1[valid], n2[valid], e[:3], focal_px, np.broadcast_to(person[:, None], valid.shape)[valid])
    _, R, t, _ = cv2.recoverPose(e[:3], n1[valid], n2[valid], np.eye(3))
    return R, t.ravel() / np.linalg.norm(t)


def _stage2(points, n1, n2, valid, R, t, config, bones, warnings):
    """Ellipsoid rounds; returns the points, R, t of the round with the lowest ε and all ε."""
    rng = np.random.default_rng(config.seed)
    n_types = max(b for _, _, b in bones) + 1
    best = (np.inf, points, R, t, 0)
    epsilons = []
    for round_ in progress(range(config.max_rounds), desc="ellipsoid rounds", unit="round", leave=False):
        cov = None
        if config.noise_correction:
            cov = np.zeros(valid.shape + (3, 3))
            cov[valid] = triangulation_covariance(points[valid], R, t, n1[valid], n2[valid])
        vectors, types, cov = bone_samples(points, valid, bones, cov)
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
        if converged(epsilons, config) or not np.all(np.linalg.eigvalsh(A) > 0):
            break
        corrected = undistort(points, A, config.gamma)
        R, t = refit_cameras(corrected[valid], n1[valid], n2[valid], R, t, config)
        points = triangulate_all(R, t, n1, n2, valid)
    return best[1], best[2], best[3], epsilons, best[4]


def reconstruct(x1: np.ndarray, c1: np.ndarray, x2: np.ndarray, c2: np.ndarray, cam1: CameraModel,
                cam2: CameraModel, config: StereoConfig, bones=RIGID_BONES,
                person: np.ndarray | None = None) -> StereoResult:
    """Stages 1–3 on keypoints ``x [T, J, 2]`` (pixels) with confidences ``c [T, J]``; ``person [T]``:
    each frame's person when several are stacked along time (None: one person).

    Only the cameras' intrinsics and distortion are used; camera 2's pose is estimated. StereoError
    when the views have no parallax (:func:`check_parallax`, after stage 1), a rigid bone is not
    seen by both views (:func:`check_bone_coverage`: unsynchronised views) or the final cameras
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
    person = np.zeros(len(x1), dtype=np.int64) if person is None else np.asarray(person)
    R1, t1 = _stage1(n1, n2, valid, config, focal_px, person)
    check_bone_coverage(valid, bones)
    stage1 = triangulate_all(R1, t1, n1, n2, valid)
    warnings: list[str] = []
    stage2, R, t, epsilons, kept = _stage2(stage1, n1, n2, valid, R1, t1, config, bones, warnings)
    final = refine_bone_lengths(np.nan_to_num(stage2), projection_matrix(np.eye(3), np.zeros(3)),
                                projection_matrix(R, t), n1, n2, valid, bones, config.alpha, config.bone_rounds)
    if converged(epsilons, config) is False:
        warnings.append(convergence_warning(epsilons, kept, config))
        LOG.warning(warnings[-1])
    warnings += check_geometry(final, valid, R, t)
    scale = config.camera_distance_m or 1.0
    return StereoResult(final * scale, stage1 * scale, stage2 * scale, R, t * scale, R1, t1 * scale,
                        config.camera_distance_m is not None, epsilons, kept, warnings, valid,
                        converged(epsilons, config))
