"""A fixed lag for the live stream: each frame's poses written ``lag_frames`` frames late, smoothed
without lag over the frames on both sides.

The stream is causal: a pose is fitted from the past alone, and the 1€ filters that calm its jitter
also delay it. With ``--lag-frames L`` the engine's 1€ filters are off and :class:`FixedLag` holds
the last ``L`` frames: when frame ``t`` arrives, frame ``t − L`` is written, each person's rotations
and root the Gaussian-weighted mean of that person's per-frame fits over frames ``t − 2L … t``
(weights of a zero-phase Gaussian of cut-off ``smoothing_hz``, as the whole take's; quaternions
sign-aligned to the centre frame, then normalised), and the joints are the person's own skeleton
at those. What a viewer gets is the whole take's smoothing at a latency of ``L / fps`` seconds;
``L = 0`` is the causal stream.
"""
from __future__ import annotations

from collections import deque
from dataclasses import replace

import numpy as np

from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose
from mocapdb.core.skeleton import UNIVERSAL_HEIGHT_M, body_offsets_m, pose_from_rotations

Frame = tuple[int, float, list[PersonPose]]  # frame index, time (s), the people in it


class FixedLag:
    """Frames in, the same frames out ``lag_frames`` later with every person smoothed (see the module)."""

    def __init__(self, lag_frames: int, fps: float, smoothing_hz: float = 4.0):
        """``lag_frames`` frames of delay at ``fps`` Hz; ``smoothing_hz`` the Gaussian's cut-off (0: none)."""
        if lag_frames < 0 or not fps > 0 or not smoothing_hz >= 0:
            raise ValueError("--lag-frames must be 0 or more, with a positive fps and --smoothing-hz of 0 or more")
        self.lag = int(lag_frames)
        self.sigma_frames = fps / (2.0 * np.pi * smoothing_hz) if smoothing_hz > 0 else 0.0  # 0: the centre only
        self.frames: deque[Frame] = deque()

    def push(self, index: int, time_s: float, poses: list[PersonPose]) -> list[Frame]:
        """Add one frame; returns the frames now due (at most one), smoothed."""
        self.frames.append((index, time_s, poses))
        if len(self.frames) <= self.lag:
            return []
        due = self._smoothed(len(self.frames) - 1 - self.lag)
        if len(self.frames) > 2 * self.lag:
            self.frames.popleft()
        return [due]

    def flush(self) -> list[Frame]:
        """The frames not yet written (the last ``lag_frames``, at the end of the input), smoothed
        over what is left of their windows."""
        first = len(self.frames) - min(len(self.frames), self.lag)
        out = [self._smoothed(i) for i in range(first, len(self.frames))]
        self.frames.clear()
        return out

    def _smoothed(self, centre: int) -> Frame:
        index, time_s, poses = self.frames[centre]
        return index, time_s, [self._person(pose, centre) for pose in poses]

    def _person(self, pose: PersonPose, centre: int) -> PersonPose:
        quats, roots, weights = [], [], []
        for k in range(max(centre - self.lag, 0), min(centre + self.lag + 1, len(self.frames))):
            same = [p for p in self.frames[k][2] if p.track == pose.track]
            if same:
                q = same[0].quaternions
                quats.append(np.where((np.sum(q * pose.quaternions, axis=-1) < 0)[:, None], -q, q))
                roots.append(same[0].root_m)
                weights.append(np.exp(-0.5 * ((k - centre) / max(self.sigma_frames, 1e-6)) ** 2))
        w = np.array(weights)[:, None]
        mean_q = np.tensordot(w[:, 0], np.array(quats), axes=1)
        mean_q /= np.linalg.norm(mean_q, axis=-1, keepdims=True)
        root = (w * np.array(roots)).sum(axis=0) / w.sum()
        scale = pose.height_m / UNIVERSAL_HEIGHT_M
        offsets = None if pose.bones_m is None else body_offsets_m(pose.bones_m / scale)
        joints_view = pose_from_rotations(mean_q[None], (root * CAMERA_FROM_VIEW)[None], scale, offsets)[0]
        return replace(pose, joints_m=joints_view * CAMERA_FROM_VIEW, quaternions=mean_q, root_m=root)
