"""Which of its two depths a lifted foot or hand takes, frame after frame
(:func:`~mocapdb.runtime.end_joints.lift_candidates`: one camera sees a segment's end on a ray that meets the
segment's sphere twice, nearer and farther).

Taken one frame at a time, the side prior (:func:`~mocapdb.runtime.end_joints.sign_references`: a foot where the
pelvis faces, a hand where its forearm points) picks wrong where the segment points near it across the view,
and the choice flips from frame to frame (a foot turned out in a fighting stance: 95 deg back and forth).
A segment turns smoothly, so the choice is a path through the frames (Viterbi over the two branches): each
frame's branch costs its angle from the prior, ``(1 − cos) / SIDE_SD²``, and each step its turn from the
previous frame's branch, ``(1 − cos) / (TURN_SD × Δt)²``. The whole take takes the cheapest path over all its
frames (:func:`continuous_directions`); the online take, causal, each frame's cheapest path's end
(:class:`BranchPath`): a wrong start is left as soon as the evidence since outweighs one turn.
"""
from __future__ import annotations

import numpy as np

SIDE_SD_DEG = 60.0      # a foot's heading within about this of the pelvis's, a hand's of its forearm's
TURN_SD_DEG_S = 720.0   # a foot or hand turns about this fast at most (degrees per second)
_SIDE = 1.0 / np.radians(SIDE_SD_DEG) ** 2


def _side_costs(candidates: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``[E, 2]`` each branch's cost against the prior ``reference [E, 3]`` (``candidates [E, 2, 3]``)."""
    return (1.0 - np.sum(candidates * reference[:, None], axis=-1)) * _SIDE


class BranchPath:
    """The cheapest paths so far through the branches of ``count`` segments (module docstring)."""

    def __init__(self, count: int) -> None:
        self.cost = np.full((count, 2), np.nan)          # each branch's cheapest path's cost up to its last frame
        self.last = np.full((count, 2, 3), np.nan)       # the branches of each segment's last frame seen
        self.last_s = np.full(count, np.nan)             # that frame's time (seconds)

    def step(self, time_s: float, candidates: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Add a frame at ``time_s``: ``candidates [E, 2, 3]`` (NaN: unseen) and the priors ``reference [E, 3]``.
        Returns each segment's cheapest branch now ``[E, 3]`` (NaN where unseen) and, per branch, which branch
        of its last frame seen its cheapest path came from ``[E, 2]`` (-1: none before)."""
        seen = np.isfinite(candidates).all(axis=(-2, -1))
        cost = _side_costs(np.nan_to_num(candidates), reference)
        step_sd = np.radians(TURN_SD_DEG_S) * np.maximum(time_s - self.last_s, 1e-6)
        turn = (1.0 - np.einsum("eai,ebi->eab", candidates, self.last)) / step_sd[:, None, None] ** 2
        through = self.cost[:, None, :] + turn                      # [E, now, before]
        before = np.isfinite(through).all(axis=(-2, -1))
        back = np.where(before[:, None], np.nan_to_num(through, nan=np.inf).argmin(axis=-1), -1)
        cost = cost + np.where(before[:, None], np.take_along_axis(np.nan_to_num(through, nan=np.inf),
                                                                   np.maximum(back, 0)[..., None], -1)[..., 0], 0.0)
        cost = cost - cost.min(axis=-1, keepdims=True)              # only the branches' difference counts
        self.cost = np.where(seen[:, None], cost, self.cost)
        self.last = np.where(seen[:, None, None], candidates, self.last)
        self.last_s = np.where(seen, time_s, self.last_s)
        best = np.take_along_axis(candidates, cost.argmin(axis=-1)[:, None, None], axis=1)[:, 0]
        return np.where(seen[:, None], best, np.nan), np.where(seen[:, None], back, -1)


def continuous_directions(candidates: np.ndarray, reference: np.ndarray, fps: float) -> np.ndarray:
    """``[F, E, 3]`` the branches of the cheapest path over all frames of ``candidates [F, E, 2, 3]`` (NaN:
    unseen) with the priors ``reference [F, E, 3]`` at ``fps`` frames per second (NaN where unseen)."""
    path = BranchPath(candidates.shape[1])
    backs = np.full(candidates.shape[:3], -1)
    for f in range(len(candidates)):
        backs[f] = path.step(f / fps, candidates[f], reference[f])[1]
    out = np.full(candidates.shape[:2] + (3,), np.nan)
    for e in range(candidates.shape[1]):
        seen = np.flatnonzero(np.isfinite(candidates[:, e]).all(axis=(-2, -1)))
        if not len(seen):
            continue
        branch = int(np.nanargmin(path.cost[e]))
        for f in seen[::-1]:
            out[f, e] = candidates[f, e, branch]
            branch = backs[f, e, branch] if backs[f, e, branch] >= 0 else branch
    return out
