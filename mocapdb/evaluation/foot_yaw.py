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
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

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


def bvh_yaws(path: Path) -> np.ndarray:
    """``[F, 2]`` the foot yaws (degrees) of a humanoid BVH (module docstring)."""
    bvh = read_bvh(path)
    positions, _ = forward_kinematics(bvh, [bvh.names.index(n) for n in BVH_JOINTS])
    return foot_yaws(positions)


def score(estimate_deg: np.ndarray, reference_deg: np.ndarray) -> FootScore:
    """``estimate_deg`` against ``reference_deg`` (both ``[T, 2]``, NaN where unknown)."""
    both = np.isfinite(estimate_deg).all(axis=1) & np.isfinite(reference_deg).all(axis=1)
    est, ref = estimate_deg[both], reference_deg[both]
    error = (est - ref + 180.0) % 360.0 - 180.0
    return FootScore({f: float(np.sqrt(np.mean(error[:, i] ** 2))) for i, f in enumerate(FEET)},
                     {f: float(error[:, i].mean()) for i, f in enumerate(FEET)},
                     {f: float(np.corrcoef(est[:, i], ref[:, i])[0, 1]) for i, f in enumerate(FEET)},
                     {f: float(ref[:, i].std()) for i, f in enumerate(FEET)}, int(both.sum()))


def format_table(scores: dict[str, FootScore]) -> str:
    """A Markdown table of every camera's :class:`FootScore`."""
    lines = ["| camera | frames | right foot yaw RMS / r / offset | left foot yaw RMS / r / offset | "
             "reference SD right, left |", "|---|---|---|---|---|"]
    for name, s in scores.items():
        cells = [f"{s.rms_deg[f]:.1f}° / {s.r[f]:.2f} / {s.offset_deg[f]:+.1f}°" for f in FEET]
        lines.append(f"| {name} | {s.frames} | {cells[0]} | {cells[1]} | {s.reference_sd_deg['right']:.1f}°, "
                     f"{s.reference_sd_deg['left']:.1f}° |")
    return "\n".join(lines)
