"""The online take's fingers: each hand's 15 finger joints turned per frame of the stream from the frame's
hand points (``Person.hands``), as the whole take turns them (:func:`~mocapdb.runtime.hand_pose.finger_rotations`).

Per track (:class:`OnlineFingers`), per frame:

1. **Measured**: each hand's finger angles (degrees; :func:`~mocapdb.runtime.hand_pose.finger_angles_deg` in
   its :func:`~mocapdb.runtime.hand_pose.palm_frames`); NaN where the hand is absent.
2. **Smoothed** as the online take's other end joints (:mod:`mocapdb.runtime.online_ends`): lag 0, a causal
   1€ filter of the angles; lag ``L``, their Gaussian mean over the frames ``t − L … t + L`` measured.
3. **Unseen**: a hand keeps its last angles for 2 × :data:`~mocapdb.runtime.hand_pose.EASE_S` (the gap the
   whole take bridges), then eases to the relaxed hand (:data:`~mocapdb.core.hand_rig.RELAXED_DEG`, the
   whole take's rest) over :data:`~mocapdb.runtime.hand_pose.EASE_S` (smoothstep); seen again, or seen
   first, it eases in from there as long. Every frame says which hand was measured (``fingers_seen``).

The angles become the joints' local rotations as the whole take's
(:func:`~mocapdb.runtime.hand_pose.finger_quaternions`).
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.hand_rig import RELAXED_DEG
from mocapdb.runtime.filters import OneEuroFilter, OneEuroParams
from mocapdb.runtime.hand_pose import EASE_S, finger_angles_deg, finger_quaternions, hand_points_view, palm_frames
from mocapdb.runtime.online_ends import EaseToRest

HOLD_S = 2.0 * EASE_S   # an unseen hand keeps its last angles this long (seconds), as the whole take bridges
_REST = np.broadcast_to(RELAXED_DEG, (2, 5, 5))


def measured_angles_deg(hands_px: np.ndarray) -> np.ndarray:
    """``[2, 5, 5]`` the finger angles (degrees) of one frame's hands ``hands_px [2, 21, 3]`` (right, left;
    x, y, z px; NaN: absent), NaN for an absent hand."""
    points = hand_points_view(np.asarray(hands_px, dtype=np.float64))
    return finger_angles_deg(points, palm_frames(points))


class OnlineFingers:
    """One track's fingers in the online take (module docstring). ``fps``: frames per second;
    ``lag_frames``, ``sigma_frames``: the online take's lag and Gaussian (frames); ``causal``: its 1€
    filter at lag 0."""

    def __init__(self, fps: float, lag_frames: int, sigma_frames: float, causal: OneEuroParams) -> None:
        self.fps, self.lag, self.sigma_frames = fps, lag_frames, sigma_frames
        self.measured: dict[int, np.ndarray] = {}   # frame → angles [2, 5, 5] (degrees; NaN: absent)
        self.filter = OneEuroFilter(causal)
        self.held = _REST.copy()                      # the last smoothed angles (what an unseen hand keeps)
        self.ease = EaseToRest(2, fps, HOLD_S, EASE_S)

    def add(self, index: int, hands_px: np.ndarray) -> None:
        """Frame ``index``'s hands ``[2, 21, 3]`` (px; NaN: absent): measured, kept while the window needs them."""
        self.measured[index] = measured_angles_deg(hands_px)
        for old in [i for i in self.measured if i < index - 2 * self.lag - 1]:
            del self.measured[old]

    def output(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """The finger joints' local rotations ``[30, 4]`` (``hand_rig.FINGER_JOINTS`` order) of frame ``index``
        and which hands were seen ``[2]`` (right, left)."""
        angles = self.measured.get(index, np.full((2, 5, 5), np.nan))
        seen = np.isfinite(angles).all(axis=(-2, -1))
        if self.lag == 0:
            smoothed = self.filter(np.where(seen[:, None, None], angles, self.held), index / self.fps)
        else:
            smoothed = self._window_mean(index)
        self.held = np.where(seen[:, None, None], smoothed, self.held)
        weight = self.ease.weight(seen)[:, None, None]
        return finger_quaternions((_REST + weight * (self.held - _REST))[None])[0], seen

    def _window_mean(self, index: int) -> np.ndarray:
        """``[2, 5, 5]`` each hand's Gaussian mean angles over the frames measured in ``index`` ± lag;
        the held angles where the hand is seen in none."""
        near = [i for i in range(index - self.lag, index + self.lag + 1) if i in self.measured]
        angles = np.array([self.measured[i] for i in near]).reshape(len(near), 2, 25)     # [n, 2, 25]
        weights = np.exp(-0.5 * ((np.array(near, dtype=np.float64) - index) / self.sigma_frames) ** 2)
        w = np.where(np.isfinite(angles).all(axis=-1), weights[:, None], 0.0)            # [n, 2]
        total = w.sum(axis=0)
        mean = (w[..., None] * np.nan_to_num(angles)).sum(axis=0) / np.maximum(total, 1e-12)[:, None]
        return np.where(total[:, None, None] > 0, mean.reshape(2, 5, 5), self.held)
