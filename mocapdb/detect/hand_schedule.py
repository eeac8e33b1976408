"""Hands at a lower rate (``live``): which hands the hand landmark model runs on a frame, and where the others go.

The hand model costs more than the pose on a small machine (``docs/benchmarks.md``, "Hands' cost in
live"). With :class:`HandSchedule` ``every`` N > 1, a hand is run on every N-th frame (the frame count
a multiple of N: a frame's hands share one batch) and **carried** in between: the 21 points of its last
run moved with the pose's hand (:func:`similarity`: the shift, turn and scale taking the pose's wrist,
index and pinky knuckles at that run onto this frame's; depth scaled alike), its flag and handedness
kept. A hand the model found empty (unsure) is carried as unsure and retried every ``empty_every``
frames. A hand is run at once, whatever the frame, when it is new (no run yet, or its person's slot
lost it) or its pose hand moved more than :data:`MOVED` of its crop's side since its last run (a carry
would be a guess). ``every`` 1: every hand on every frame (what ``detect`` does for files).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

LIVE_HANDS_EVERY = 2   # `live --hands`: each hand run every this many frames unless told (--hands-every)
MOVED = 0.25   # a hand whose pose points moved more than this share of its crop's side since its last run runs again


def similarity(source_xy: np.ndarray, target_xy: np.ndarray) -> tuple[complex, complex]:
    """The 2D similarity (z ↦ a z + b on points as complex numbers x + iy) that best takes ``source_xy
    [K, 2]`` onto ``target_xy [K, 2]`` (least squares; K ≥ 2 points not all at one place)."""
    source = source_xy[:, 0] + 1j * source_xy[:, 1]
    target = target_xy[:, 0] + 1j * target_xy[:, 1]
    s0, t0 = source - source.mean(), target - target.mean()
    a = complex(np.vdot(s0, t0) / max(np.vdot(s0, s0).real, 1e-12))
    return a, complex(target.mean() - a * source.mean())


def carry(points: np.ndarray, a: complex, b: complex) -> np.ndarray:
    """Hand points ``[21, 3]`` (x, y frame px, z px) moved by the similarity ``z ↦ a z + b``; z scaled by ``|a|``."""
    moved = a * (points[:, 0] + 1j * points[:, 1]) + b
    return np.column_stack([moved.real, moved.imag, points[:, 2] * abs(a)])


@dataclass
class LastRun:
    """What the model gave for a hand: points ``[21, 3]`` (x, y frame px, z px), flag, handedness score,
    ``empty`` (unsure); and when: the frame, the pose's wrist, index and pinky knuckles then ``[3, 2]``
    (frame px) and the crop's side (px), set by :meth:`HandSchedule.ran`."""

    points: np.ndarray
    presence: float
    handedness: float
    empty: bool
    frame: int = 0
    pose_xy: np.ndarray | None = None
    side_px: float = 0.0


class HandSchedule:
    """Which hands run on each frame and what the others carry (module docstring); keys are
    (person, side). Call :meth:`due` for each hand a frame shows, :meth:`ran` for each one run,
    :meth:`carried` for the others, then :meth:`end_frame`."""

    def __init__(self, every: int = 1, empty_every: int | None = None) -> None:
        if every < 1 or (empty_every is not None and empty_every < 1):
            raise ValueError("hands' every and empty_every must be at least 1")
        self.every, self.empty_every = every, empty_every or 3 * every
        self.frame = 0
        self.last: dict[tuple[int, int], LastRun] = {}
        self.carries = 0   # hands carried instead of run

    def due(self, key: tuple[int, int], pose_xy: np.ndarray, side_px: float) -> bool:
        """Whether the hand ``key``, its pose points ``[3, 2]`` and crop side (px) on this frame, is run now."""
        last = self.last.get(key)
        if last is None or last.pose_xy is None or self.every == 1:
            return True
        if np.abs(pose_xy - last.pose_xy).max() > MOVED * max(side_px, last.side_px):
            return True
        period = self.empty_every if last.empty else self.every
        return self.frame % period == 0 or self.frame - last.frame >= period

    def ran(self, key: tuple[int, int], pose_xy: np.ndarray, side_px: float, found: LastRun) -> LastRun:
        """Notes the run of hand ``key`` on this frame: ``found``, its result, with the frame and pose set."""
        found.frame, found.pose_xy, found.side_px = self.frame, pose_xy, side_px
        self.last[key] = found
        return found

    def carried(self, key: tuple[int, int], pose_xy: np.ndarray) -> LastRun:
        """Hand ``key``'s last run moved onto this frame's pose points ``[3, 2]``."""
        last = self.last[key]
        assert last.pose_xy is not None
        self.carries += 1
        points = carry(last.points, *similarity(last.pose_xy, pose_xy))
        return LastRun(points, last.presence, last.handedness, last.empty, self.frame, pose_xy, last.side_px)

    def end_frame(self, shown: set[tuple[int, int]]) -> None:
        """The frame is done; hands not ``shown`` on it (hidden, small, their person gone) are forgotten."""
        self.last = {key: run for key, run in self.last.items() if key in shown}
        self.frame += 1
