"""ElliPose stage 3: bone lengths made constant over time against the 2D evidence of both views."""
from __future__ import annotations

import numpy as np

from mocapdb.core.skeleton import KP

# Rigid bones over the 14 keypoints (i, j, type). The neck (mid-shoulder) and pelvis (mid-hip)
# are derived points, so only the hip and shoulder lines stand for the torso; the nose moves
# with the head and has no rigid partner.
RIGID_BONES: tuple[tuple[int, int, int], ...] = (
    (KP["r_hip"], KP["l_hip"], 0),                                          # hip line
    (KP["r_hip"], KP["r_knee"], 1), (KP["l_hip"], KP["l_knee"], 1),         # thighs
    (KP["r_knee"], KP["r_ankle"], 2), (KP["l_knee"], KP["l_ankle"], 2),     # shins
    (KP["r_shoulder"], KP["l_shoulder"], 3),                                # shoulder line
    (KP["r_shoulder"], KP["r_elbow"], 4), (KP["l_shoulder"], KP["l_elbow"], 4),  # upper arms
    (KP["r_elbow"], KP["r_wrist"], 5), (KP["l_elbow"], KP["l_wrist"], 5),   # forearms
)


def refine_bone_lengths(points: np.ndarray, P1: np.ndarray, P2: np.ndarray, n1: np.ndarray, n2: np.ndarray,
                        valid: np.ndarray, bones=RIGID_BONES, alpha: float = 20.0, rounds: int = 5) -> np.ndarray:
    """Stage 3: per frame, least squares of the DLT reprojection rows of both views plus
    ``alpha`` × Σ_b ‖v_b − w_b‖², with ``w_b`` the current bone direction at the bone's mean
    length; ``rounds`` times. The DLT row ``(u P₃ − P₁)·[p; 1]`` is the point's offset from its
    ray times its depth, i.e. roughly a distance in the points' own units, like the bone term.
    ``points [T, J, 3]``, ``n1, n2 [T, J, 2]`` normalised image coordinates, ``valid [T, J]``.
    """
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
