"""Landmark models at a lower rate (``live``): which hands and faces their landmark model runs on a frame,
and where the others go.

The hand and face models cost more than the pose on a small machine (``docs/benchmarks.md``, "Hands'
cost in live", "Face mesh"). With :class:`LandmarkSchedule` ``every`` N > 1, a hand or face is run on
every N-th frame (the frame count a multiple of N: a frame's crops share one batch) and **carried** in
between: the points of its last run moved with the pose's points of that part (:func:`similarity`: the
shift, turn and scale taking the pose's points at that run onto this frame's, least squares; depth
scaled alike; a hand: the wrist, index and pinky knuckles; a face: BlazePose's 11 face points), its
flag and score kept. One the model found empty (unsure) is carried as unsure and retried every
``empty_every`` frames. It is run at once, whatever the frame, when it is new (no run yet, or its
person's slot lost it) or its pose points moved more than :data:`MOVED` of its crop's side since its
last run (a carry would be a guess). ``every`` 1: every one on every frame (what ``detect`` does for files).
"""
from __future__ import annotations

from collections.abc import Callable, Hashable
from dataclasses import dataclass

import numpy as np

LIVE_HANDS_EVERY = 2   # `live --hands`: each hand run every this many frames unless told (--hands-every)
LIVE_FACE_EVERY = 2    # `live --face`: each face run every this many frames unless told (--face-every)
MOVED = 0.25   # a part whose pose points moved more than this share of its crop's side since its last run runs again


def similarity(source_xy: np.ndarray, target_xy: np.ndarray) -> tuple[complex, complex]:
    """The 2D similarity (z ↦ a z + b on points as complex numbers x + iy) that best takes ``source_xy
    [K, 2]`` onto ``target_xy [K, 2]`` (least squares; K ≥ 2 points not all at one place)."""
    source = source_xy[:, 0] + 1j * source_xy[:, 1]
    target = target_xy[:, 0] + 1j * target_xy[:, 1]
    s0, t0 = source - source.mean(), target - target.mean()
    a = complex(np.vdot(s0, t0) / max(np.vdot(s0, s0).real, 1e-12))
    return a, complex(target.mean() - a * source.mean())


def carry(points: np.ndarray, a: complex, b: complex) -> np.ndarray:
    """Points ``[N, 3]`` (x, y frame px, z px) moved by the similarity ``z ↦ a z + b``; z scaled by ``|a|``."""
    moved = a * (points[:, 0] + 1j * points[:, 1]) + b
    return np.column_stack([moved.real, moved.imag, points[:, 2] * abs(a)])


@dataclass
class LastRun:
    """What the model gave for a hand or face: points ``[N, 3]`` (x, y frame px, z px), flag, ``score``
    (a hand's handedness; 0 for a face), ``empty`` (unsure); and when: the frame, the pose's points of
    the part then ``[K, 2]`` (frame px) and the crop's side (px), set by :meth:`LandmarkSchedule.ran`."""

    points: np.ndarray
    presence: float
    score: float
    empty: bool
    frame: int = 0
    pose_xy: np.ndarray | None = None
    side_px: float = 0.0


class LandmarkSchedule:
    """Which crops run on each frame and what the others carry (module docstring); keys name a part of a
    person (a hand: (person, side); a face: the person). :meth:`frame_runs` does a frame; or call
    :meth:`due` for each part a frame shows, :meth:`ran` for each one run, :meth:`carried` for the
    others, then :meth:`end_frame`."""

    def __init__(self, every: int = 1, empty_every: int | None = None) -> None:
        if every < 1 or (empty_every is not None and empty_every < 1):
            raise ValueError("a landmark model's every and empty_every must be at least 1")
        self.every, self.empty_every = every, empty_every or 3 * every
        self.frame = 0
        self.last: dict[Hashable, LastRun] = {}
        self.carries = 0   # parts carried instead of run

    def due(self, key: Hashable, pose_xy: np.ndarray, side_px: float) -> bool:
        """Whether the part ``key``, its pose points ``[K, 2]`` and crop side (px) on this frame, is run now."""
        last = self.last.get(key)
        if last is None or last.pose_xy is None or self.every == 1:
            return True
        if np.abs(pose_xy - last.pose_xy).max() > MOVED * max(side_px, last.side_px):
            return True
        period = self.empty_every if last.empty else self.every
        return self.frame % period == 0 or self.frame - last.frame >= period

    def ran(self, key: Hashable, pose_xy: np.ndarray, side_px: float, found: LastRun) -> LastRun:
        """Notes the run of part ``key`` on this frame: ``found``, its result, with the frame and pose set."""
        found.frame, found.pose_xy, found.side_px = self.frame, pose_xy, side_px
        self.last[key] = found
        return found

    def carried(self, key: Hashable, pose_xy: np.ndarray) -> LastRun:
        """Part ``key``'s last run moved onto this frame's pose points ``[K, 2]``."""
        last = self.last[key]
        assert last.pose_xy is not None
        self.carries += 1
        points = carry(last.points, *similarity(last.pose_xy, pose_xy))
        return LastRun(points, last.presence, last.score, last.empty, self.frame, pose_xy, last.side_px)

    def end_frame(self, shown: set) -> None:
        """The frame is done; parts not ``shown`` on it (hidden, small, their person gone) are forgotten."""
        self.last = {key: run for key, run in self.last.items() if key in shown}
        self.frame += 1

    def frame_runs(self, pose_xy: dict, sides_px: dict, run: Callable[[list], list[LastRun]]) -> dict:
        """A whole frame: each part shown (the keys of ``pose_xy``, its pose points ``[K, 2]``, and of
        ``sides_px``, its crop's side, px) run or carried; ``run(keys)`` runs the model on the due ones
        (one batch) and gives their results in order. Returns key → :class:`LastRun`."""
        due = [key for key in pose_xy if self.due(key, pose_xy[key], sides_px[key])]
        found = dict(zip(due, run(due))) if due else {}
        runs = {key: self.ran(key, pose_xy[key], sides_px[key], found[key]) if key in found
                else self.carried(key, pose_xy[key]) for key in pose_xy}
        self.end_frame(set(pose_xy))
        return runs
