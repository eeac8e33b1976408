"""The root's path online: the whole take's root model (:func:`~mocapdb.runtime.take.fit_root_path`
without its contacts) as a Kalman filter.

The model is the whole take's least-squares problem, read as a state-space one:

* **motion**: the root's velocity changes by white noise; its second difference per frame has SD
  ``root_accel_mps2 · dt²`` (state ``[p, v]`` in the view frame, metres and metres per second);
* **measurement**: each per-frame root, near the truth across the viewing ray (SD ``root_across_m``:
  the image fixes it) and loosely along it (SD ``root_depth_m``: the depth from the body's size).

A measurement the state predicts badly (squared Mahalanobis distance of its innovation above
:data:`GATE_CHI2`: a retrieval's pop, a false detection) has its noise inflated by that excess, so it
moves the path as much as a gate-sized one would and no more (a Huber-like weight).

The estimate of frame ``t`` is the last frame of the batch least-squares path through frames up to
``t`` (the filter's and the batch's models are one). Costs a few 6×6 products per frame.
"""
from __future__ import annotations

import numpy as np

from mocapdb.runtime.take_params import TakeParams

GATE_CHI2 = 16.0        # squared Mahalanobis distance of a 3D innovation: 99.9 % of clean ones stay below
RESTART_GAP_S = 0.5     # a track unseen this long starts its path anew
FIRST_SPEED_SD_MPS = 2.0  # the first frame's velocity: unknown, of a walking or running person


class RootFilter:
    """Per-frame roots in, filtered roots out (:meth:`__call__`). ``fps``: the frame rate (Hz);
    ``params``: the whole take's ``root_across_m``, ``root_depth_m`` and ``root_accel_mps2``."""

    def __init__(self, fps: float, params: TakeParams = TakeParams()):
        self.dt = 1.0 / fps
        self.params = params
        self.last: tuple[int, np.ndarray, np.ndarray] | None = None  # frame, state [6], covariance [6, 6]

    def __call__(self, index: int, root_m: np.ndarray) -> np.ndarray:
        """The root ``[3]`` (view frame, metres) of frame ``index`` given its per-frame root ``root_m
        [3]`` and the frames before (indices must increase)."""
        z = np.asarray(root_m, dtype=np.float64)
        if not np.isfinite(z).all():   # nothing to learn from: the state stays as it was
            return z.copy()
        noise = self._measurement_noise(z)
        last = self.last
        if last is None or (index - last[0]) * self.dt > RESTART_GAP_S:
            covariance = np.zeros((6, 6))
            covariance[:3, :3] = noise
            covariance[3:, 3:] = np.eye(3) * FIRST_SPEED_SD_MPS ** 2
            self.last = (index, np.concatenate([z, np.zeros(3)]), covariance)
            return z.copy()
        transition = _transition((index - last[0]) * self.dt)
        predicted = transition @ last[1]
        predicted_cov = transition @ last[2] @ transition.T + self._process_noise(index - last[0])
        innovation = z - predicted[:3]
        s = predicted_cov[:3, :3] + noise
        distance2 = float(innovation @ np.linalg.solve(s, innovation))
        if distance2 > GATE_CHI2:
            s = predicted_cov[:3, :3] + noise * (distance2 / GATE_CHI2)
        gain = np.linalg.solve(s, predicted_cov[:3, :]).T        # P Hᵀ S⁻¹ (S symmetric)
        state = predicted + gain @ innovation
        covariance = predicted_cov - gain @ predicted_cov[:3, :]
        self.last = (index, state, 0.5 * (covariance + covariance.T))
        return state[:3].copy()

    def constrain(self, root_m: np.ndarray) -> None:
        """Move the last estimate to ``root_m [3]`` (view frame, metres; a constraint the caller put
        on it): the next frame is predicted from where the root was put, at the same velocity."""
        if self.last is not None:
            self.last[1][:3] = root_m

    def _measurement_noise(self, root_m: np.ndarray) -> np.ndarray:
        """``[3, 3]``: ``root_across_m`` across the viewing ray, ``root_depth_m`` along it (SDs)."""
        p = self.params
        ray = root_m / max(float(np.linalg.norm(root_m)), 1e-9)
        return np.eye(3) * p.root_across_m ** 2 + np.outer(ray, ray) * (p.root_depth_m ** 2 - p.root_across_m ** 2)

    def _process_noise(self, frames: int) -> np.ndarray:
        """``[6, 6]``: the velocity's random walk over ``frames`` frames (each adds ``accel · dt`` SD)."""
        q = np.zeros((6, 6))
        q[3:, 3:] = np.eye(3) * frames * (self.params.root_accel_mps2 * self.dt) ** 2
        return q


def _transition(dt_s: float) -> np.ndarray:
    """``[6, 6]``: position += velocity · dt."""
    f = np.eye(6)
    f[:3, 3:] = np.eye(3) * dt_s
    return f
