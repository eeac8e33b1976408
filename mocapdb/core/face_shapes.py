"""Blend shapes from the face mesh (MediaPipe's 468 points): the eyes' blinks and the mouth's opening, as the
VRM/VMC expressions ``Blink_L``, ``Blink_R`` and ``A`` (0: neutral, 1: fully), per frame.

- **Eye openness**: the eye aspect ratio (Soukupová & Čech, 2016) of each eye's six mesh points: the two
  lid-to-lid heights over twice the corner-to-corner width. A blink is 0 at :data:`EAR_OPEN` and above, 1
  at :data:`EAR_CLOSED` and below, linear between. ``Blink_L`` is the subject's (and the avatar's) left eye.
- **Mouth opening**: the inner lips' gap (vertices 13 ↔ 14) over the inner corners' width (78 ↔ 308); ``A`` is
  0 at :data:`MOUTH_CLOSED` and below, 1 at :data:`MOUTH_OPEN` and above, linear between.
- A face whose mesh is narrower than :data:`MIN_BLEND_PX` (the cheek contours 234 ↔ 454) gives none.
- **Smoothing** (:class:`BlendSmoother`, per track, causal): an exponential whose time constant is
  :data:`RISE_S` while a value rises (an eye shutting, the mouth opening: a blink of 100–150 ms must
  not vanish) and :data:`FALL_S` while it falls; its weight ``1 − exp(−Δt/τ)`` from the frames' times
  (frame-rate aware). A steady value is unchanged.

Thresholds measured on real photos (MediaPipe's test images): ``data_specs/head.md``, "Blend shapes".
"""
from __future__ import annotations

import numpy as np

BLEND_SHAPES = ("Blink_L", "Blink_R", "A")
# Each eye's six mesh vertices: outer corner, upper lid ×2, inner corner, lower lid ×2 (p1 … p6 of the ratio)
EYE_RIGHT = (33, 160, 158, 133, 153, 144)
EYE_LEFT = (263, 387, 385, 362, 380, 373)
LIPS_INNER = (13, 14)            # the upper and the lower inner lip's middle
MOUTH_CORNERS = (78, 308)        # the inner lips' corners
FACE_BREADTH = (234, 454)        # the cheek contours at the ears' height
EAR_OPEN = 0.17      # eye aspect ratio of an open eye at its narrowest (measured on open eyes: 0.17-0.34)
EAR_CLOSED = 0.09    # of a nearly shut, down-cast eye (measured: 0.08-0.09; no photo of a blink: head.md)
MOUTH_CLOSED = 0.10  # inner lips' gap over width of a closed mouth (measured on closed mouths: 0.003-0.104)
MOUTH_OPEN = 0.60    # of a mouth open as for "a" (a guess, not measured: no such photo; head.md)
MIN_BLEND_PX = 40.0  # the mesh's breadth (px) below which the eyes and lips are too coarse (head.md)
RISE_S = 0.015       # smoothing's time constant (s) while a shape rises: fast attack (head.md, "Smoothing")
FALL_S = 0.060       # while it falls (s): the release that takes the frame-to-frame jitter out


def eye_aspect_ratio(mesh_xy: np.ndarray, eye: tuple[int, ...]) -> np.ndarray:
    """``[...]`` the eye aspect ratio of ``eye``'s six vertices in meshes ``[..., 468, ≥2]`` (px)."""
    p1, p2, p3, p4, p5, p6 = (mesh_xy[..., i, :2] for i in eye)
    heights = np.linalg.norm(p2 - p6, axis=-1) + np.linalg.norm(p3 - p5, axis=-1)
    return heights / (2.0 * np.linalg.norm(p1 - p4, axis=-1))


def mouth_ratio(mesh_xy: np.ndarray) -> np.ndarray:
    """``[...]`` the inner lips' gap over the inner corners' width of meshes ``[..., 468, ≥2]`` (px)."""
    gap = np.linalg.norm(mesh_xy[..., LIPS_INNER[0], :2] - mesh_xy[..., LIPS_INNER[1], :2], axis=-1)
    return gap / np.linalg.norm(mesh_xy[..., MOUTH_CORNERS[0], :2] - mesh_xy[..., MOUTH_CORNERS[1], :2], axis=-1)


def _ramp(value: np.ndarray, zero: float, one: float) -> np.ndarray:
    """``value`` mapped linearly from ``zero`` → 0 to ``one`` → 1, clipped to [0, 1]."""
    return np.clip((value - zero) / (one - zero), 0.0, 1.0)


def blend_shapes(mesh_xy: np.ndarray) -> np.ndarray:
    """``[..., 3]`` :data:`BLEND_SHAPES` (0–1) of meshes ``[..., 468, ≥2]`` (frame px); NaN where the mesh is
    absent (NaN) or narrower than :data:`MIN_BLEND_PX`."""
    left, right = (_ramp(eye_aspect_ratio(mesh_xy, eye), EAR_OPEN, EAR_CLOSED) for eye in (EYE_LEFT, EYE_RIGHT))
    shapes = np.stack([left, right, _ramp(mouth_ratio(mesh_xy), MOUTH_CLOSED, MOUTH_OPEN)], axis=-1)
    breadth = np.linalg.norm(mesh_xy[..., FACE_BREADTH[0], :2] - mesh_xy[..., FACE_BREADTH[1], :2], axis=-1)
    return np.where((breadth >= MIN_BLEND_PX)[..., None], shapes, np.nan)


def smooth_step(previous: np.ndarray, value: np.ndarray, dt_s: float,
                rise_s: float = RISE_S, fall_s: float = FALL_S) -> np.ndarray:
    """One step of the fast-attack exponential (module docstring): ``value [...]`` (0–1) after ``previous
    [...]`` (the smoothed values ``dt_s`` seconds before), time constants ``rise_s``/``fall_s`` (s). Where
    either is NaN (no face then or now) the value itself."""
    tau = np.where(value > previous, rise_s, fall_s)
    weight = 1.0 - np.exp(-max(dt_s, 0.0) / tau)
    smoothed = previous + weight * (value - previous)
    return np.where(np.isfinite(smoothed), smoothed, value)


class BlendSmoother:
    """A track's blend shapes smoothed causally by :func:`smooth_step`, frame by frame at times ``t_s``."""

    def __init__(self, rise_s: float = RISE_S, fall_s: float = FALL_S) -> None:
        self.rise_s, self.fall_s = rise_s, fall_s
        self.last: np.ndarray | None = None
        self.last_s = 0.0

    def __call__(self, shapes: np.ndarray, t_s: float) -> np.ndarray:
        """The smoothed ``shapes [...]`` (0–1; NaN stays NaN and restarts the filter) at time ``t_s`` (s)."""
        shapes = np.asarray(shapes, dtype=np.float64)
        out = shapes if self.last is None else smooth_step(self.last, shapes, t_s - self.last_s,
                                                           self.rise_s, self.fall_s)
        self.last, self.last_s = out, t_s
        return out
