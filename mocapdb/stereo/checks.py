"""Sanity of a two-view reconstruction: unsynchronised views, views without parallax, camera poses that
cannot be right.

:func:`check_synchronised` runs on the main person after matching, :func:`check_parallax` after stage
1's essential matrix, :func:`check_geometry` on the final cameras and joints, :func:`behind_cameras`
per person (``mocapdb stereo``'s warnings). Decisions and measured thresholds: ``data_specs/stereo.md``.
"""
from __future__ import annotations

import cv2
import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.skeleton import KEYPOINTS
from mocapdb.stereo.config import StereoConfig, StereoError
from mocapdb.stereo.epipolar_pairs import fit_essential, mean_focal
from mocapdb.stereo.people import Selection
from mocapdb.stereo.relative_pose import rotation_angle_deg, sampson_distance
from mocapdb.stereo.tracks_2d import normalised

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
# The ellipsoid has one scale per rigid bone type: each type needs both joints seen by both views
# in at least MIN_BONE_FRAMES frames. Unsynchronised views match no real person; what matches by
# chance (the bundled pair with one view reversed or shifted, before check_synchronised and the
# still-or-moving rule of the matching: view 1's still partial figure paired with view 2's person)
# never shows the shoulder line in both.
MIN_BONE_FRAMES = 5
# Synchronised views (check_synchronised): the main person's keypoints fit the epipolar geometry
# best as given; with view 2 shifted in time by an offset of SYNC_OFFSETS frames (each offset with its
# own essential matrix) they fit worse. Views of two moments fit some offset better. Refused when one
# fits below SYNC_RATIO times the unshifted median distance. Measured (best offset / as given): 1.6-2.0
# on the Pose2Sim take's pairs, 1.03-1.28 on the demo video's (YOLO11n-pose); camera 4 of the bundled
# pair reversed 0.77, shifted by 50 frames 0.59. A still main person cannot tell (not checked).
SYNC_OFFSETS = (-30, -15, -8, -4, 4, 8, 15, 30)
SYNC_RATIO = 0.9


def homography_residual(n1: np.ndarray, n2: np.ndarray, essential: np.ndarray, focal_px: float,
                        person: np.ndarray | None = None) -> tuple[float, float] | None:
    """Median residuals (px) of correspondences ``n1, n2 [N, 2]`` (normalised) under the best
    homography (RANSAC, 3 px, on at most :data:`MAX_HOMOGRAPHY_POINTS` of them) and under ``essential``
    (Sampson distance, at least :data:`NOISE_FLOOR_PX`), of the person (``person [N]``: each
    correspondence's; None: one person) whose homography residual is the largest against its epipolar
    one; None when no homography is found. ``focal_px`` turns them into pixels."""
    fit = np.linspace(0, len(n1) - 1, min(len(n1), MAX_HOMOGRAPHY_POINTS)).astype(int)  # evenly spread
    # Few draws suffice: a view pair a homography explains has most points inliers (found at once);
    # for a real pair the best of many draws would still be far off.
    H, _ = cv2.findHomography(n1[fit], n2[fit], cv2.RANSAC, 3.0 / focal_px, maxIters=200, confidence=0.995)
    if H is None:
        return None
    mapped = np.c_[n1, np.ones(len(n1))] @ H.T
    with np.errstate(divide="ignore", invalid="ignore"):
        moved = np.linalg.norm(mapped[:, :2] / mapped[:, 2:] - n2, axis=1)
    moved = np.where(np.isfinite(moved), moved, np.inf) * focal_px
    epipolar = sampson_distance(essential, n1, n2) * focal_px
    person = np.zeros(len(n1), dtype=np.int64) if person is None else person
    medians = [(float(np.median(moved[person == k])), max(float(np.median(epipolar[person == k])), NOISE_FLOOR_PX))
               for k in np.unique(person)]
    return max(medians, key=lambda m: m[0] / m[1])


def check_parallax(n1: np.ndarray, n2: np.ndarray, essential: np.ndarray, focal_px: float,
                   person: np.ndarray | None = None) -> None:
    """StereoError when one homography explains the correspondences of every person (``person [N]``:
    each correspondence's; None: one person) about as well as the essential matrix does
    (:data:`HOMOGRAPHY_RATIO`): the views then have no parallax, and the relative pose and the depths are
    not determined. Per person, because a still person far away is nearly flat: a homography maps it
    whatever the baseline, and its repeated keypoints would outnumber a moving person's."""
    residuals = homography_residual(n1, n2, essential, focal_px, person)
    if residuals is not None and residuals[0] <= HOMOGRAPHY_RATIO * residuals[1]:
        raise StereoError(
            f"the two views have no parallax: one homography maps view 1's keypoints onto view 2's (median "
            f"{residuals[0]:.1f} px off, against {residuals[1]:.1f} px for the epipolar geometry). They are the "
            "same view (possibly shifted, scaled, mirrored or cropped) or two cameras at the same place, so depth "
            "cannot be recovered; give the keypoints of two cameras set apart")


def check_bone_coverage(valid: np.ndarray, bones) -> None:
    """StereoError when a bone type of ``bones`` (``(joint, joint, type)`` triples) has both joints
    seen by both views (``valid [T, J]``) in fewer than :data:`MIN_BONE_FRAMES` frames: then no
    person matches across the views as a whole body, the sign of unsynchronised views."""
    seen: dict[int, tuple[str, int]] = {}
    for i, j, b in bones:
        name, frames = seen.get(b, (f"{KEYPOINTS[i]}–{KEYPOINTS[j]}", 0))
        seen[b] = (name, frames + int(np.sum(valid[:, i] & valid[:, j])))
    short = [f"{name} ({frames})" for name, frames in seen.values() if frames < MIN_BONE_FRAMES]
    if short:
        raise StereoError(
            f"no person matches across the views as a whole body: bones seen by both views in fewer than "
            f"{MIN_BONE_FRAMES} frames: {', '.join(short)}; the camera fit needs every rigid bone. The views do "
            "not look synchronised (frames of two different takes, or one view shifted or reversed in time), or "
            "the cameras see different parts of the people")


def offset_distance(n1: np.ndarray, n2: np.ndarray, offset: int, focal_px: float,
                    config: StereoConfig) -> float | None:
    """Median over frames of the median Sampson distance (px) of a person's joints ``n1, n2 [T, J, 2]``
    (normalised, NaN where not seen), view 2 taken ``offset`` frames later, under an essential matrix
    fitted to them; None with fewer than ``config.min_correspondences`` or no matrix."""
    n = len(n1)
    a, b = n1[max(0, -offset):n - max(0, offset)], n2[max(0, offset):n - max(0, -offset)]
    ok = np.isfinite(a).all(axis=-1) & np.isfinite(b).all(axis=-1)
    essential = fit_essential(a[ok], b[ok], config) if ok.sum() >= max(8, config.min_correspondences) else None
    if essential is None:
        return None
    distance = np.full(ok.shape, np.nan)
    distance[ok] = sampson_distance(essential, a[ok], b[ok]) * focal_px
    return float(np.median(np.nanmedian(distance[ok.any(axis=1)], axis=1)))


def check_synchronised(person: Selection, cam1: CameraModel, cam2: CameraModel, config: StereoConfig) -> None:
    """StereoError when the main ``person``'s keypoints fit the epipolar geometry clearly better with view 2
    shifted in time (:data:`SYNC_OFFSETS`, :data:`SYNC_RATIO`): the views are not synchronised."""
    if person.still:
        return
    n1, n2 = (normalised(cam, np.where((c >= config.confidence)[..., None], x, np.nan))
              for cam, x, c in ((cam1, person.x1, person.c1), (cam2, person.x2, person.c2)))
    focal_px = mean_focal(cam1, cam2)
    base = offset_distance(n1, n2, 0, focal_px, config)
    if not base:  # no distance as given: nothing to compare the shifted views with
        return
    shifted = {k: d for k in SYNC_OFFSETS if (d := offset_distance(n1, n2, k, focal_px, config)) is not None}
    best = min(shifted, key=shifted.__getitem__, default=None)
    if best is not None and shifted[best] < SYNC_RATIO * base:
        raise StereoError(
            f"the views do not look synchronised: the main person's keypoints fit one camera geometry better "
            f"with view 2 {abs(best)} frames {'later' if best > 0 else 'earlier'} (median {shifted[best]:.1f} px "
            f"off) than as given ({base:.1f} px). Give two views of one take, frame i of one taken at the same "
            "instant as frame i of the other (the same start and frame rate)")


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
    return (f"camera 2 at rotation {rotation_angle_deg(R):.1f}°, baseline direction "
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
        return [(f"little parallax between the views (the rays of a joint meet at a median {parallax:.1f}°): the "
                 "cameras are close together for the distance to the people, depth is poorly determined")]
    return []
