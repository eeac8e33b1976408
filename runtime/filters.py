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
from numba import njit

from mocapdb.core import domains as D
from mocapdb.core.kernels import quat_relative_log_into
from mocapdb.core.skeleton import KP


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

    min_cutoff_hz: float = D.RETRIEVED_MIN_CUTOFF_HZ.default
    beta: float = D.RETRIEVED_BETA.default
    d_cutoff_hz: float = 1.0

    def __post_init__(self) -> None:
        D.CUTOFF_HZ.check(self.min_cutoff_hz, "min_cutoff_hz")
        D.CUTOFF_HZ.check(self.d_cutoff_hz, "d_cutoff_hz")
        D.BETA.check(self.beta, "beta")


# Root (pelvis) translation in metres: the 0.5 Hz floor cuts a still subject's root jitter
# (centimetres of monocular depth noise) 3.5× (24 fps) to 5× (60 fps) in standard deviation;
# beta = 1 Hz per m/s keeps a walker (1.4 m/s) within 5–6.5 cm of lag.
ROOT_DEFAULTS = OneEuroParams(min_cutoff_hz=0.5, beta=1.0, d_cutoff_hz=1.0)

# After the 2D refinement (runtime/refine.py) poses jitter far less than retrieved ones, and the
# retrieval defaults' lag (~9–12° on a walking knee) became the largest error left: on held-out
# walking at 24 fps they took clean-input MPJPE from 2.1 cm (unfiltered) to 4.4 cm and the
# re-projection error from 0.3 % to 3.8 % of the box height. Most jitter is now removed from the
# 2D keypoints before the fit (KeypointFilter, below), so the output filters only smooth what the
# fit adds: an 8 Hz floor (β = 2). On held-out basketball (subject 6, 24 fps) with both filters:
# clean 3.5 cm / 1.3 %, σ 5 px + dropout + swaps 5.6 cm; without the keypoint filter and with a
# 4 Hz output floor: 3.3 cm / 1.1 % and 6.0 cm.
REFINED_ROTATION_DEFAULTS = OneEuroParams(min_cutoff_hz=D.REFINED_MIN_CUTOFF_HZ.default, beta=D.REFINED_BETA.default,
                                           d_cutoff_hz=1.0)
REFINED_ROOT_DEFAULTS = OneEuroParams(min_cutoff_hz=8.0, beta=6.0, d_cutoff_hz=1.0)


@njit(cache=True)
def _alpha(rate_hz: float, cutoff_hz: float) -> float:
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
        p = self.params
        _vector_step(s.value.reshape(-1), s.speed.reshape(-1), x.reshape(-1), 1.0 / (t_s - s.t_s),
                     p.min_cutoff_hz, p.beta, p.d_cutoff_hz)
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
        s = self._state
        if s is None:
            q = q / np.linalg.norm(q, axis=-1, keepdims=True)
            self._state = _State(q, np.zeros(q.shape[:-1] + (3,)), t_s)
            return q.copy()
        if t_s <= s.t_s:
            return s.value.copy()
        p = self.params
        _quaternion_step(s.value.reshape(-1, 4), s.speed.reshape(-1, 3), q.reshape(-1, 4), 1.0 / (t_s - s.t_s),
                         p.min_cutoff_hz, p.beta, p.d_cutoff_hz)
        s.t_s = t_s
        return s.value.copy()


@njit(cache=True)
def _vector_step(value, speed, x, rate, min_cutoff, beta, d_cutoff):
    """One 1€ update of flat arrays ``value`` and ``speed`` (in place) with sample ``x``."""
    a_d = _alpha(rate, d_cutoff)
    for i in range(x.shape[0]):
        speed[i] += a_d * ((x[i] - value[i]) * rate - speed[i])
        value[i] += _alpha(rate, min_cutoff + beta * abs(speed[i])) * (x[i] - value[i])


@njit(cache=True)
def _quaternion_step(value, speed, q, rate, min_cutoff, beta, d_cutoff):
    """One 1€ update of unit quaternions ``value [J, 4]`` and angular velocities ``speed [J, 3]``."""
    a_d = _alpha(rate, d_cutoff)
    r = np.empty(3)
    for j in range(q.shape[0]):
        v = value[j]
        qj = q[j] / np.sqrt(np.sum(q[j] ** 2))
        if v[0] * qj[0] + v[1] * qj[1] + v[2] * qj[2] + v[3] * qj[3] < 0:
            qj = -qj
        quat_relative_log_into(v, qj, r)  # log(v⁻¹ q): the rotation vector from v to q (radians)
        speed[j] += a_d * (r * rate - speed[j])
        a = _alpha(rate, min_cutoff + beta * np.sqrt(np.sum(speed[j] ** 2)))
        blend = v + a * (qj - v)
        value[j] = blend / np.sqrt(np.sum(blend ** 2))


ARM_PAIRS = tuple((KP[f"r_{part}"], KP[f"l_{part}"]) for part in ("shoulder", "elbow", "wrist"))
LEG_PAIRS = tuple((KP[f"r_{part}"], KP[f"l_{part}"]) for part in ("hip", "knee", "ankle"))
SWAP_MARGIN = 0.5  # a side swap is undone when swapping back makes the group this much closer


@dataclass(frozen=True)
class KeypointFilterParams:
    """2D keypoint clean-up before the fit; speeds and jitter in box heights (per second).

    The 1€ floor adapts to the track's measured jitter σ: ``min_cutoff_hz`` at ``noise_ref`` or
    more, rising in proportion as σ falls, up to ``max_cutoff_hz`` (clean input: almost no lag).
    """

    min_cutoff_hz: float = 6.0
    max_cutoff_hz: float = 30.0
    noise_ref: float = 0.014   # σ where the floor is min_cutoff_hz (5 px on a 350 px person)
    beta: float = 4.0
    d_cutoff_hz: float = 1.0
    undo_swaps: bool = True
    max_swap_s: float = 0.25   # a group undone this long in a row is the detector's own labelling: kept from then

    def __post_init__(self) -> None:
        if not 0 < self.min_cutoff_hz <= self.max_cutoff_hz or self.noise_ref <= 0 or self.beta < 0:
            raise ValueError(f"keypoint filter needs 0 < min_cutoff <= max_cutoff, noise_ref > 0, beta >= 0: {self}")
        if not self.max_swap_s >= 0:
            raise ValueError(f"keypoint filter needs max_swap_s >= 0: {self}")


class KeypointFilter:
    """One track's 2D keypoints cleaned before the fit: side swaps undone, then a 1€ filter.

    A detector that swaps a person's left and right arms (or legs) for a frame makes every joint
    of that limb pair wrong at once, more than a robust loss can ignore. Each group (arms, legs)
    whose keypoints lie closer to the track's current estimate with right and left exchanged
    (by :data:`SWAP_MARGIN`) is exchanged back, for at most ``max_swap_s`` in a row: a longer run
    means the estimate holds the wrong labelling (a swap of part of a group, a turn), and the detector's
    is taken from then on (otherwise every later, right, frame would be exchanged). Then each
    keypoint is 1€-filtered in pixels, with
    speeds measured in the person's box heights per second so the tuning does not depend on the
    image size or distance: detector jitter is removed before the fit turns it into depth errors
    (a 5 px error along a limb reads as a tilt of the limb out of the image plane). Unseen
    keypoints keep their estimate; a keypoint unseen for ``reset_s`` starts afresh when seen.
    """

    def __init__(self, params: KeypointFilterParams, n_keypoints: int, reset_s: float = 0.5):
        self.params = params
        self.reset_s = reset_s
        self.value = np.zeros((n_keypoints, 2))
        self.speed = np.zeros((n_keypoints, 2))
        self.seen_s = np.full(n_keypoints, -np.inf)
        self.last_s = np.array([np.nan])
        self.out = np.zeros((n_keypoints, 2))
        self.raw = np.zeros((2, n_keypoints, 2))      # the last two frames' input, newest first
        self.raw_seen = np.zeros((2, n_keypoints), dtype=np.bool_)
        self.noise = np.array([params.noise_ref])    # running jitter σ (box heights)
        self.swap_run_s = np.full(len(_SWAP_GROUPS), np.nan)  # per group: when its run of undone swaps began
        self.swaps = 0

    def __call__(self, points_px: np.ndarray, confidence: np.ndarray, t_s: float) -> np.ndarray:
        """Cleaned keypoints ``[K, 2]`` (pixels) for ``points_px`` seen where ``confidence > 0``."""
        p = self.params
        points, seen = np.asarray(points_px, dtype=np.float64), confidence > 0
        self.swaps += _keypoint_step(self.value, self.speed, self.seen_s, self.last_s, self.out, points, seen, t_s,
                                     self.reset_s, self._cutoff(points, seen), p.beta, p.d_cutoff_hz, p.undo_swaps,
                                     _SWAP_GROUPS, self.swap_run_s, p.max_swap_s)
        return self.out.copy()

    def _cutoff(self, points: np.ndarray, seen: np.ndarray) -> float:
        """The 1€ floor for this frame from the track's jitter (updated with this frame)."""
        p = self.params
        _update_jitter(self.raw, self.raw_seen, points, seen, self.noise)
        return float(np.clip(p.min_cutoff_hz * p.noise_ref / max(self.noise[0], 1e-9), p.min_cutoff_hz,
                             p.max_cutoff_hz))


_SWAP_GROUPS = np.array([ARM_PAIRS, LEG_PAIRS], dtype=np.int64)  # [group, pair, right/left]
JITTER_RATE = 0.1  # weight of a new frame in the running jitter estimate


@njit(cache=True)
def _update_jitter(raw, raw_seen, points, seen, noise) -> None:
    """Running jitter σ (box heights) from second differences of the raw keypoints.

    For white noise σ the second difference has standard deviation σ√6 and median absolute value
    1.65σ; the median over keypoints and axes ignores the few joints that really accelerate.
    """
    values = np.empty(2 * points.shape[0])
    n = 0
    lo, hi = np.inf, -np.inf
    for k in range(points.shape[0]):
        if seen[k]:
            lo, hi = min(lo, points[k, 1]), max(hi, points[k, 1])
        if seen[k] and raw_seen[0, k] and raw_seen[1, k]:
            for c in range(2):
                values[n] = abs(points[k, c] - 2.0 * raw[0, k, c] + raw[1, k, c])
                n += 1
    if n >= 8 and hi - lo > 1.0:
        sigma = np.median(values[:n]) / (1.65 * (hi - lo))
        noise[0] += JITTER_RATE * (sigma - noise[0])
    raw[1] = raw[0]
    raw_seen[1] = raw_seen[0]
    raw[0] = points
    raw_seen[0] = seen


@njit(cache=True)
def _keypoint_step(value, speed, seen_s, last_s, out, points, seen, t_s, reset_s, min_cutoff, beta, d_cutoff,
                   undo_swaps, groups, swap_run_s, max_swap_s) -> int:
    """One :class:`KeypointFilter` update (state in place, result in ``out``); returns swaps undone."""
    out[:] = points
    if np.isfinite(last_s[0]) and t_s <= last_s[0]:  # not after the last frame: no update
        for k in range(seen.shape[0]):
            if seen[k] and np.isfinite(seen_s[k]):
                out[k] = value[k]
        return 0
    first = not np.isfinite(last_s[0])
    fresh = np.empty(seen.shape[0], dtype=np.bool_)
    for k in range(seen.shape[0]):
        fresh[k] = seen[k] and (first or t_s - seen_s[k] > reset_s)
    swaps = 0
    if undo_swaps and not first:
        swaps = _undo_swaps(out, value, seen, fresh, groups, t_s, swap_run_s, max_swap_s)
    if not first:
        lo, hi, n = np.inf, -np.inf, 0
        for k in range(seen.shape[0]):
            if seen[k]:
                lo, hi, n = min(lo, out[k, 1]), max(hi, out[k, 1]), n + 1
        box = max(hi - lo, 1.0) if n > 1 else 1.0
        rate = 1.0 / (t_s - last_s[0])
        a_d = _alpha(rate, d_cutoff)
        for k in range(seen.shape[0]):
            if seen[k] and not fresh[k]:
                for c in range(2):
                    speed[k, c] += a_d * ((out[k, c] - value[k, c]) * rate - speed[k, c])
                    value[k, c] += _alpha(rate, min_cutoff + beta / box * abs(speed[k, c])) * (out[k, c] - value[k, c])
    last_s[0] = t_s
    for k in range(seen.shape[0]):
        if fresh[k]:
            value[k] = out[k]
            speed[k] = 0.0
        if seen[k]:
            seen_s[k] = t_s
            out[k] = value[k]
    return swaps


@njit(cache=True)
def _undo_swaps(points, value, seen, fresh, groups, t_s, run_s, max_run_s) -> int:
    """Exchange right and left in each group of pairs that fits the estimate that way (in place), unless
    the group's run of exchanges (begun at ``run_s[g]``, NaN: none; updated) has lasted over ``max_run_s``:
    the estimate, not the detector, then holds the wrong labelling; its points start afresh from the
    detector's."""
    swaps = 0
    for g in range(groups.shape[0]):
        keep, swap = 0.0, 0.0
        for i in range(groups.shape[1]):
            right, left = groups[g, i, 0], groups[g, i, 1]
            if seen[right] and seen[left] and not fresh[right] and not fresh[left]:
                keep += _dist(points[right], value[right]) + _dist(points[left], value[left])
                swap += _dist(points[right], value[left]) + _dist(points[left], value[right])
        if not swap < SWAP_MARGIN * keep:
            run_s[g] = np.nan
            continue
        if np.isnan(run_s[g]):
            run_s[g] = t_s
        if t_s - run_s[g] > max_run_s:
            for i in range(groups.shape[1]):
                fresh[groups[g, i, 0]] = seen[groups[g, i, 0]]
                fresh[groups[g, i, 1]] = seen[groups[g, i, 1]]
            continue
        swaps += 1
        for i in range(groups.shape[1]):
            right, left = groups[g, i, 0], groups[g, i, 1]
            if seen[right] and seen[left]:
                for c in range(2):
                    points[right, c], points[left, c] = points[left, c], points[right, c]
    return swaps


@njit(cache=True)
def _dist(a, b) -> float:
    return np.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2)
