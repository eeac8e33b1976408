"""A person's size from the floor: metric scale of a track seen by a camera at a known height.

One camera cannot tell a small person near it from a tall one further away: the image fixes
the body only up to a scale ``k`` about the camera centre. A flat floor at a known distance
below the camera (``--camera-height``) fixes it: the lowest ankle of a standing or walking
person sits :data:`~mocapdb.core.skeleton.ANKLE_HEIGHT_M` (times the body scale) above the floor.

The floor's normal in the view frame is the world's up seen by the camera (:class:`CameraTilt`). Per frame, with ``u`` that normal and ``a``
the lower ankle (view frame, metres, body scale ``s``)::

    k (u·a) + H = ANKLE_HEIGHT_M · s · k    ⇒    k = H / (ANKLE_HEIGHT_M · s − u·a)

and ``s·k`` is that frame's estimate of the body scale. The track's scale is the median of its
estimates so far (jumps and frames with both feet off the floor are a minority), clipped to
bodies 0.5–2.5 m tall. Assumes a level floor, at least one foot on it most of the time, and a
camera roll/pitch that does not change during the track.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from numba import njit

from mocapdb.core.kernels import quat_mul_into
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KP, UNIVERSAL_HEIGHT_M

MIN_SAMPLES = 6        # frames before the floor's estimate replaces the starting scale
WINDOW = 240           # the median runs over the last this many frames
SCALE_RANGE = (0.5 / UNIVERSAL_HEIGHT_M, 2.5 / UNIVERSAL_HEIGHT_M)
_ANKLES = (KP["r_ankle"], KP["l_ankle"])


class CameraTilt:
    """One track's estimate of the world's up direction in the view frame (the camera's pitch and roll).

    The database poses are upright (only turned about the vertical), so the rotation the
    refinement adds to a retrieved root is, on average, the camera's tilt: each frame gives the
    retrieved root's up axis carried by that rotation, and their mean is the estimate. The next
    frames' retrieved roots are tilted by it before the fit, so its prior stops pulling upright.
    """

    def __init__(self) -> None:
        self.up_sum = np.zeros(3)
        self._scratch = np.empty((3, 4))

    @property
    def up(self) -> np.ndarray:
        """Unit world up in the view frame (``[0, 1, 0]`` before any frame)."""
        norm = np.linalg.norm(self.up_sum)
        return self.up_sum / norm if norm > 0 else np.array([0.0, 1.0, 0.0])

    def tilt_root(self, root_upright: np.ndarray, out: np.ndarray) -> None:
        """``out`` = the upright root quaternion turned by the estimated tilt (view frame)."""
        _tilt_into(self.up_sum, root_upright, self._scratch[0], out)

    def update(self, root_refined: np.ndarray, root_upright: np.ndarray) -> None:
        """Add one frame: root quaternions (view frame) after the fit and as retrieved (untilted)."""
        _add_up_observation(root_refined, root_upright, self._scratch, self.up_sum)


@njit(cache=True)
def _tilt_into(up_sum, root, tilt, out):
    """``out = t ⊗ root``, ``t`` the smallest rotation taking y to ``up_sum`` (identity if zero)."""
    norm = np.sqrt(up_sum[0] ** 2 + up_sum[1] ** 2 + up_sum[2] ** 2)
    if norm == 0.0:
        out[:] = root
        return
    ux, uy, uz = up_sum[0] / norm, up_sum[1] / norm, up_sum[2] / norm
    half = np.sqrt((1.0 + uy) ** 2 + uz * uz + ux * ux)  # (1 + y·u, y × u), normalised
    tilt[0], tilt[1], tilt[2], tilt[3] = (1.0 + uy) / half, uz / half, 0.0, -ux / half
    quat_mul_into(tilt, root, out)


@njit(cache=True)
def _add_up_observation(refined, upright, scratch, up_sum):
    """``up_sum += R(refined) R(upright)ᵀ y``: the upright root's up axis carried by the fit."""
    conj = scratch[0]
    conj[0], conj[1], conj[2], conj[3] = upright[0], -upright[1], -upright[2], -upright[3]
    quat_mul_into(refined, conj, scratch[1])
    w, x, y, z = scratch[1]
    up_sum[0] += 2 * (x * y - w * z)
    up_sum[1] += 1 - 2 * (x * x + z * z)
    up_sum[2] += 2 * (y * z + w * x)


class FloorScale:
    """Running estimate of one track's body scale from its feet (see the module docstring)."""

    def __init__(self, camera_height_m: float):
        if not 0.1 <= camera_height_m <= 50.0:
            raise ValueError(f"camera height must be between 0.1 and 50 m, not {camera_height_m}")
        self.camera_height_m = camera_height_m
        self.samples: deque[float] = deque(maxlen=WINDOW)

    def update(self, up: np.ndarray, joints_view_m: np.ndarray, scale: float) -> float:
        """Add one frame; returns the track's scale (``scale`` until enough frames were seen).

        ``up``: the world's up in the view frame (:class:`CameraTilt`); ``joints_view_m [15, 3]``:
        the refined keypoints at body scale ``scale``.
        """
        ankle_height = min(float(up @ joints_view_m[k]) for k in _ANKLES)
        denominator = ANKLE_HEIGHT_M * scale - ankle_height
        if denominator > 0.1:
            self.samples.append(scale * self.camera_height_m / denominator)
        if len(self.samples) < MIN_SAMPLES:
            return scale
        return float(np.clip(np.median(self.samples), *SCALE_RANGE))
