"""The 1€ filter (Casiez, Roussel & Vogel, CHI 2012) for runtime poses: vectors and joint rotations.

Per sample ``x_i`` at time ``t_i`` with rate ``r = 1 / (t_i - t_{i-1})``::

    dx_i  = (x_i - x̂_{i-1}) · r                      speed against the previous estimate
    dx̂_i = a(d_cutoff) · dx_i + (1 - a(d_cutoff)) · dx̂_{i-1}
    f_c   = min_cutoff + beta · |dx̂_i|
    x̂_i  = a(f_c) · x_i + (1 - a(f_c)) · x̂_{i-1},   a(f) = 1 / (1 + r / (2π f))

The first sample passes through unchanged (with ``dx̂ = 0``). A sample whose timestamp is not
after the previous one (a duplicate or out-of-order frame) is skipped: the call returns the
current estimate and leaves the state untouched, so no rate is ever infinite or negative.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocapdb.geometry import quat_conj, quat_geodesic, quat_mul


@dataclass(frozen=True)
class OneEuroParams:
    """Tuning of a 1€ filter; ``beta`` is in Hz per unit of speed (units/s of the filtered value).

    The defaults target joint rotations through :class:`QuaternionOneEuroFilter`, whose speed is
    the joint's angular speed in rad/s, at 24–60 fps:

    * ``min_cutoff_hz = 1.0``: a still joint is smoothed with a 0.16 s time constant, which cuts
      per-frame retrieval jitter about 3× (24 fps) to 4.4× (60 fps) in standard deviation;
    * ``beta = 0.3``: a limb swinging at 5 rad/s (a knee when walking) lifts the cutoff to a few
      Hz, keeping the lag at 9–12° instead of ~47° with ``beta = 0``; jitter alone (whose smoothed
      angular velocity averages out) lifts it by less than 0.1 Hz;
    * ``d_cutoff_hz = 1.0``: the paper's recommendation for the speed estimate.
    """

    min_cutoff_hz: float = 1.0
    beta: float = 0.3
    d_cutoff_hz: float = 1.0

    def __post_init__(self) -> None:
        if self.min_cutoff_hz <= 0 or self.d_cutoff_hz <= 0 or self.beta < 0:
            raise ValueError(f"cutoffs must be positive and beta non-negative: {self}")


# Root (pelvis) translation in metres: the 0.5 Hz floor cuts a still subject's root jitter
# (centimetres of monocular depth noise) 3.5× (24 fps) to 5× (60 fps) in standard deviation;
# beta = 1 Hz per m/s keeps a walker (1.4 m/s) within 5–6.5 cm of lag.
ROOT_DEFAULTS = OneEuroParams(min_cutoff_hz=0.5, beta=1.0, d_cutoff_hz=1.0)


def _alpha(rate_hz: float, cutoff_hz: float | np.ndarray) -> float | np.ndarray:
    """The 1€ low-pass weight ``a = 1 / (1 + r / (2π f_c))`` of a new sample."""
    return 1.0 / (1.0 + rate_hz / (2.0 * np.pi * cutoff_hz))


@dataclass
class _State:
    """Estimate, smoothed speed and time of the last accepted sample."""

    value: np.ndarray
    speed: np.ndarray
    t_s: float


@dataclass
class OneEuroFilter:
    """1€ filter of an array of any shape, each component with its own speed and cutoff."""

    params: OneEuroParams = field(default_factory=OneEuroParams)
    _state: _State | None = field(default=None, init=False, repr=False)

    def reset(self) -> None:
        """Forget the past: the next sample passes through unchanged."""
        self._state = None

    def __call__(self, x: np.ndarray, t_s: float) -> np.ndarray:
        """Filter sample ``x`` taken at ``t_s`` seconds; returns the new estimate (same shape)."""
        x = np.array(x, dtype=np.float64)
        s = self._state
        if s is None:
            self._state = _State(x, np.zeros_like(x), t_s)
            return x.copy()
        if t_s <= s.t_s:
            return s.value.copy()
        rate = 1.0 / (t_s - s.t_s)
        p = self.params
        s.speed = s.speed + _alpha(rate, p.d_cutoff_hz) * ((x - s.value) * rate - s.speed)
        a = _alpha(rate, p.min_cutoff_hz + p.beta * np.abs(s.speed))
        s.value = s.value + a * (x - s.value)
        s.t_s = t_s
        return s.value.copy()


@dataclass
class QuaternionOneEuroFilter:
    """1€ filter of joint rotations ``[J, 4]`` (unit quaternions, w, x, y, z).

    Each incoming quaternion is first negated if needed to lie in the hemisphere of the previous
    estimate, so the double cover (``q`` and ``-q``) never causes a flip. The speed driving the
    cutoff is per joint: the angular velocity ``2 log(q̂⁻¹ q) · r`` (rad/s of the full rotation
    angle; its norm is ``2 · quat_geodesic · r``), low-passed as a 3-vector so that jitter averages
    out instead of reading as motion; its norm sets the joint's cutoff. The four components are
    then blended with the joint's weight and renormalised. Outputs are unit but ``w >= 0`` is
    NOT enforced: a rotation sweeping past 180° keeps going continuously with ``w < 0``.
    """

    params: OneEuroParams = field(default_factory=OneEuroParams)
    _state: _State | None = field(default=None, init=False, repr=False)

    def reset(self) -> None:
        """Forget the past: the next sample passes through (normalised)."""
        self._state = None

    def __call__(self, q: np.ndarray, t_s: float) -> np.ndarray:
        """Filter rotations ``q [J, 4]`` taken at ``t_s`` seconds; returns unit ``[J, 4]``."""
        q = np.asarray(q, dtype=np.float64)
        q = q / np.linalg.norm(q, axis=-1, keepdims=True)
        s = self._state
        if s is None:
            self._state = _State(q, np.zeros(q.shape[:-1] + (3,)), t_s)
            return q.copy()
        if t_s <= s.t_s:
            return s.value.copy()
        rate = 1.0 / (t_s - s.t_s)
        q = np.where(np.sum(q * s.value, axis=-1, keepdims=True) < 0, -q, q)
        p = self.params
        omega = _rotation_vector(s.value, q) * rate
        s.speed = s.speed + _alpha(rate, p.d_cutoff_hz) * (omega - s.speed)
        a = _alpha(rate, p.min_cutoff_hz + p.beta * np.linalg.norm(s.speed, axis=-1))
        blend = s.value + a[..., None] * (q - s.value)
        s.value = blend / np.linalg.norm(blend, axis=-1, keepdims=True)
        s.t_s = t_s
        return s.value.copy()


def _rotation_vector(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Axis × angle ``[..., 3]`` (radians, in ``a``'s frame) of the rotation from ``a`` to ``b``."""
    axis = quat_mul(quat_conj(a), b)[..., 1:]
    norm = np.linalg.norm(axis, axis=-1, keepdims=True)
    angle = 2.0 * quat_geodesic(a, b)[..., None]
    return np.where(norm > 0, axis * (angle / np.where(norm > 0, norm, 1.0)), 0.0)
