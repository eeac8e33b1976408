"""The feet's yaw on a real take: each camera's humanoid BVH against the calibrated cameras' triangulation of
the detector's own heels, foot tips, hips and shoulders (``tools/eval_foot_yaw.py``; issue 49, item 3).

Reference: per frame the main person's BlazePose heels, foot tips (``foot_index``), hips and shoulders,
triangulated (:func:`~mocapdb.evaluation.head_turn.triangulated_points`). The hips' frame: x along right →
left hip, y towards the shoulders' mid-point (made perpendicular), z = x × y (forwards). A foot's **yaw**:
its heel → foot tip direction in that frame, the angle about y from z (positive towards the subject's left).

Estimate: the same of the BVH's joints: the hips' frame from ``RightUpLeg``/``LeftUpLeg`` and
``RightArm``/``LeftArm``, the foot's direction from ``…Foot`` to ``…ToeBase`` (the rig's ankle → ball, which
at rest points as its heel → toe: forwards). Scored per foot as the head is (:class:`FootScore`: RMS, Pearson's
r, the mean offset, the reference's own SD).

Each turn alone, as the camera sees it (:func:`azimuths`): the feet's and the hips' headings in the camera's view
frame (the BVH written in it, ``--view-frame``; the triangulation taken into it by the calibration), about the
world's up: a foot yaw against the hips that is off while both headings are right is the hips' error.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.evaluation.head_turn import frame_from_x_and_hint

FEET = ("right", "left")
REFERENCE_POINTS = ("right_heel", "right_foot_index", "left_heel", "left_foot_index", "right_hip", "left_hip",
                    "right_shoulder", "left_shoulder")
BVH_JOINTS = ("RightFoot", "RightToeBase", "LeftFoot", "LeftToeBase", "RightUpLeg", "LeftUpLeg", "RightArm",
              "LeftArm")   # in REFERENCE_POINTS' roles


@dataclass
class FootScore:
    """One camera's foot yaws against the reference, per foot (:data:`FEET`): RMS error (degrees), mean
    offset (estimate − reference), Pearson's r and the reference's SD, over ``frames`` frames both have."""

    rms_deg: dict[str, float]
    offset_deg: dict[str, float]
    r: dict[str, float]
    reference_sd_deg: dict[str, float]
    frames: int


def foot_yaws(points_m: np.ndarray) -> np.ndarray:
    """``[T, 2]`` right and left foot yaw (degrees) of points ``[T, 8, 3]`` in :data:`REFERENCE_POINTS`' roles."""
    r_heel, r_tip, l_heel, l_tip, r_hip, l_hip, r_sh, l_sh = np.moveaxis(points_m, 1, 0)
    hips = frame_from_x_and_hint(l_hip - r_hip, 0.5 * (l_sh + r_sh) - 0.5 * (l_hip + r_hip), "y")
    feet = np.stack([r_tip - r_heel, l_tip - l_heel], axis=1)
    local = np.einsum("tji,tkj->tki", hips, feet)
    return np.degrees(np.arctan2(local[..., 0], local[..., 2]))


def bvh_points(path: Path) -> np.ndarray:
    """``[F, 8, 3]`` a humanoid BVH's :data:`BVH_JOINTS` (its frame, metres), in :data:`REFERENCE_POINTS`' roles."""
    bvh = read_bvh(path)
    return forward_kinematics(bvh, [bvh.names.index(n) for n in BVH_JOINTS])[0]


def azimuths(points: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``[T, 3]`` the headings (degrees, about ``up [3]``, from z towards x) of the right foot, the left foot
    (heel → tip) and the hips' x axis (right → left hip) of points ``[T, 8, 3]`` in REFERENCE_POINTS' roles:
    in a camera's view frame, each one's own turn as that camera sees it, free of the body's."""
    vectors = np.stack([points[:, 1] - points[:, 0], points[:, 3] - points[:, 2], points[:, 5] - points[:, 4]], 1)
    level = vectors - (vectors @ up)[..., None] * up
    return np.degrees(np.arctan2(level[..., 0], level[..., 2]))


def view_points(points_world: np.ndarray, camera: CameraModel) -> np.ndarray:
    """``[..., 3]`` calibration-world points in ``camera``'s view frame (x right, y up, z towards it)."""
    return (points_world @ camera.R.T + camera.t) * [1.0, -1.0, -1.0]


def score(estimate_deg: np.ndarray, reference_deg: np.ndarray, names: tuple[str, ...] = FEET) -> FootScore:
    """``estimate_deg`` against ``reference_deg`` (both ``[T, len(names)]``, NaN where unknown), per column; angles
    are taken about the reference's circular mean (a heading near ±180° does not wrap)."""
    both = np.isfinite(estimate_deg).all(axis=1) & np.isfinite(reference_deg).all(axis=1)
    radians = np.radians(reference_deg[both])
    mean = np.degrees(np.arctan2(np.sin(radians).mean(axis=0), np.cos(radians).mean(axis=0)))
    est, ref = _wrapped(estimate_deg[both] - mean), _wrapped(reference_deg[both] - mean)
    error = _wrapped(est - ref)
    return FootScore({f: float(np.sqrt(np.mean(error[:, i] ** 2))) for i, f in enumerate(names)},
                     {f: float(error[:, i].mean()) for i, f in enumerate(names)},
                     {f: float(np.corrcoef(est[:, i], ref[:, i])[0, 1]) for i, f in enumerate(names)},
                     {f: float(ref[:, i].std()) for i, f in enumerate(names)}, int(both.sum()))


def _wrapped(degrees: np.ndarray) -> np.ndarray:
    return (degrees + 180.0) % 360.0 - 180.0


def format_table(scores: dict[str, FootScore], title: str) -> str:
    """A Markdown table of every camera's :class:`FootScore` (RMS / r / offset, and the reference's SD, per
    column), the first column headed ``title``."""
    names = list(next(iter(scores.values())).rms_deg)
    lines = [f"| {title} | frames | " + " | ".join(f"{n} RMS / r / offset" for n in names) + " | reference SD |",
             "|---|---|" + "---|" * (len(names) + 1)]
    for camera, s in scores.items():
        cells = [f"{s.rms_deg[n]:.1f}° / {s.r[n]:.2f} / {s.offset_deg[n]:+.1f}°" for n in names]
        sd = ", ".join(f"{s.reference_sd_deg[n]:.1f}°" for n in names)
        lines.append(f"| {camera} | {s.frames} | " + " | ".join(cells) + f" | {sd} |")
    return "\n".join(lines)
