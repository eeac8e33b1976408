"""The feet's directions in the stream at lag 0 (runtime/online_ends.DirectionKalman, SteadyFeet): a direction
turning in one plane is the constant-velocity Kalman filter of its angle, written out here with NumPy (F, Q, H, R
of the textbook's white-acceleration model), each frame's confidence weighing it; a clean steady turn gets the
Kalman's lag-free answer, a scattered one the 1€ filter's, the share between them moving without a step; the
scatter of a vector measure (hand_pose.steadiness) the root-sum-square of its components'."""
import numpy as np
import pytest

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.runtime.filters import OneEuroFilter, OneEuroParams
from mocapdb.runtime.hand_pose import steadiness
from mocapdb.runtime.online_ends import (
    EASE_S,
    FOOT_ACCEL_RAD_S2,
    FOOT_FIT_SD_DEG,
    DirectionKalman,
    SteadyFeet,
    foot_confidence,
)
from mocapdb.runtime.rotation_kalman import ACCEL_FRAME_S, FIRST_TURN_SD_RAD_S, MIN_CONFIDENCE

FPS = 24.0
ACCEL, FIT_SD = 48.0, np.radians(10.0)
NORMAL = np.array([0.3, 0.9, -0.2]) / np.linalg.norm([0.3, 0.9, -0.2])   # the plane the direction turns in
_U = np.cross(NORMAL, [1.0, 0.0, 0.0]) / np.linalg.norm(np.cross(NORMAL, [1.0, 0.0, 0.0]))
_V = np.cross(NORMAL, _U)


def _in_plane(angle_rad: np.ndarray) -> np.ndarray:
    """``[..., 3]`` the unit direction at ``angle_rad`` in the plane of :data:`NORMAL`."""
    a = np.asarray(angle_rad)[..., None]
    return np.cos(a) * _U + np.sin(a) * _V


def _angle_of(direction: np.ndarray) -> float:
    return float(np.arctan2(direction @ _V, direction @ _U))


def _off_rad(direction: np.ndarray, angle_rad: float) -> float:
    """How far (radians, 0 … π) ``direction`` is turned from the plane's ``angle_rad``."""
    return abs(float(np.angle(np.exp(1j * (_angle_of(direction) - angle_rad)))))


def _linear_kalman(z: np.ndarray, confidence: np.ndarray, accel: float, fit_sd: float) -> np.ndarray:
    """The angle's filtered estimates: state (angle, rate), the first frame the measure with the rate unknown."""
    dt = 1.0 / FPS
    f = np.array([[1.0, dt], [0.0, 1.0]])
    q = accel ** 2 * ACCEL_FRAME_S * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    r = (fit_sd / confidence) ** 2
    x, p = np.array([z[0], 0.0]), np.diag([r[0], FIRST_TURN_SD_RAD_S ** 2])
    out = [x[0]]
    for k in range(1, len(z)):
        x, p = f @ x, f @ p @ f.T + q
        gain = p[:, 0] / (p[0, 0] + r[k])
        x, p = x + gain * (z[k] - x[0]), p - np.outer(gain, p[0])
        out.append(x[0])
    return np.array(out)


def test_a_turn_in_one_plane_is_the_linear_kalman_filter_of_its_angle():
    rng = np.random.default_rng(3)
    t = np.arange(48) / FPS
    truth = 0.4 + 2.0 * t + 1.5 * np.sin(3.0 * t)
    z = truth + rng.normal(0.0, 0.05, len(t))
    confidence = rng.uniform(0.3, 1.0, len(t))
    kalman = DirectionKalman(1, FPS, ACCEL, FIT_SD)
    got = [_angle_of(kalman(i, _in_plane(z[i])[None], confidence[i:i + 1])[0]) for i in range(len(t))]
    assert np.allclose(np.unwrap(got), _linear_kalman(z, confidence, ACCEL, FIT_SD), atol=1e-9)


def test_an_unseen_direction_keeps_its_estimate():
    kalman = DirectionKalman(2, FPS, ACCEL, FIT_SD)
    for i in range(12):
        estimate = kalman(i, np.stack([_in_plane(0.1 * i), _in_plane(-0.5)]), np.ones(2))
    kept = estimate[1].copy()
    assert np.array_equal(kalman(12, np.stack([_in_plane(1.2), np.full(3, np.nan)]), np.ones(2))[1], kept)


def _run_feet(angles_rad: np.ndarray, planted: np.ndarray = np.zeros(2, bool)
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[np.ndarray]]:
    """Both feet measured at ``angles_rad [F]`` through :class:`SteadyFeet`, the 1€ filter (0.5 Hz, 0.3) given
    as its smoothed directions, ``planted [2]`` throughout: (its outputs [F, 2, 3], the 1€'s [F, 2, 3], the
    linear Kalman's angles [F], the Kalman's share each frame)."""
    feet, euro = SteadyFeet(FPS), OneEuroFilter(OneEuroParams(min_cutoff_hz=0.5, beta=0.3))
    outputs, smoothed, shares = [], [], []
    for i, angle in enumerate(angles_rad):
        measured = np.stack([_in_plane(angle)] * 2)
        smoothed.append(euro(measured, i / FPS))
        outputs.append(feet(i, measured, smoothed[-1], np.ones(2), planted))
        shares.append(feet.share.copy())
    reference = _linear_kalman(angles_rad, np.ones(len(angles_rad)), FOOT_ACCEL_RAD_S2, np.radians(FOOT_FIT_SD_DEG))
    return np.array(outputs), np.array(smoothed), reference, shares


def test_a_clean_steady_turn_gets_the_kalmans_lag_free_answer():
    angles = np.radians(120.0) * np.arange(48) / FPS                      # 120 °/s, measured exactly
    outputs, smoothed, reference, shares = _run_feet(angles)
    assert np.array_equal(shares[-1], [1.0, 1.0])
    for foot in range(2):
        assert _off_rad(outputs[-1, foot], reference[-1]) < 1e-9
        assert _off_rad(outputs[-1, foot], angles[-1]) < np.radians(0.1)
    assert _off_rad(smoothed[-1, 0], angles[-1]) > np.radians(5.0)          # the 1€'s delay


def test_a_planted_foot_gets_the_one_euro_filters_answer():
    outputs, smoothed, _, shares = _run_feet(np.radians(30.0) * np.arange(48) / FPS, np.array([True, False]))
    assert np.array_equal(shares[-1], [0.0, 1.0]) and np.array_equal(outputs[-1, 0], smoothed[-1, 0])


def test_a_scattered_turn_gets_the_one_euro_filters_answer_and_the_share_moves_without_a_step():
    rng = np.random.default_rng(5)
    steady = np.radians(60.0) * np.arange(72) / FPS
    scattered = np.radians(60.0) * np.arange(72, 144) / FPS + rng.normal(0.0, np.radians(10.0), 72)
    outputs, smoothed, _, shares = _run_feet(np.concatenate([steady, scattered]))
    assert np.array_equal(shares[71], [1.0, 1.0]) and np.array_equal(shares[-1], [0.0, 0.0])
    assert np.array_equal(outputs[-1], smoothed[-1])
    assert np.max(np.abs(np.diff(shares, axis=0))) <= 1.0 / (EASE_S * FPS) + 1e-12


def test_a_vector_measures_scatter_is_its_components_root_sum_square():
    """An alternating ±a (second differences ±4a) scatters 1.4826 × 4a / √6; along x by 6 and y by 8 it
    scatters 10: of thresholds 8 and 12 half is kept, a frame with a NaN component left out."""
    t = np.arange(40)
    unit = np.sqrt(6.0) / (4.0 * 1.4826)                                  # the amplitude scattering 1
    values = np.stack([6.0 * unit * (-1.0) ** t, 8.0 * unit * (-1.0) ** t, np.full(40, 3.0)], axis=1)
    assert steadiness(values, 8.0, 12.0) == pytest.approx(0.5, abs=1e-9)
    values[::2, 2] = np.nan                                                # the odd frames: alternating no more
    assert steadiness(values, 8.0, 12.0) == 1.0


def test_a_foots_confidence_is_its_heel_and_big_toes_mean():
    points = np.zeros((len(EXTREMITIES), 3))
    points[:4, 2] = [0.8, 0.6, 0.1, 0.0]            # right heel, right big toe, left heel, left big toe
    assert np.allclose(foot_confidence(points), [0.7, MIN_CONFIDENCE])
