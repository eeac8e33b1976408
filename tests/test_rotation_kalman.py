"""The stream's rotation filter (runtime/rotation_kalman.py) against independent references: the
steady-state gain of the discrete algebraic Riccati equation (SciPy), a linear Kalman filter and
Rauch–Tung–Striebel smoother written here in matrix form for rotations about one axis, SciPy's
rotations for a constant angular velocity, and a step in the fits."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.spatial.transform import Rotation

from mocapdb.core.skeleton import KP, N_RIG_JOINTS, RIG_JOINTS
from mocapdb.runtime.rotation_kalman import (
    ACCEL_FRAME_S,
    MIN_CONFIDENCE,
    ROTATION_ACCEL_RAD_S2,
    RotationKalman,
    RotationNoise,
    joint_confidence,
    process_noise,
    spectral_density,
)

FPS = 60.0
NOISE = RotationNoise(fit_sd_rad=np.radians(6.0), accel_factor=1.0)
ONES = np.ones(N_RIG_JOINTS)


def _quats(rotvecs: np.ndarray) -> np.ndarray:
    """``[..., 4]`` (w, x, y, z) of rotation vectors ``[..., 3]`` (SciPy's, reordered)."""
    xyzw = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_quat()
    return np.roll(xyzw, 1, axis=-1).reshape(rotvecs.shape[:-1] + (4,))


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per joint the angle (degrees) between unit quaternions ``a`` and ``b`` ``[R, 4]``."""
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


def _about_x(angles_rad: np.ndarray) -> np.ndarray:
    """``[T, R, 4]``: every joint turned by ``angles_rad [T]`` about x."""
    vecs = np.zeros((len(angles_rad), N_RIG_JOINTS, 3))
    vecs[..., 0] = angles_rad[:, None]
    return _quats(vecs)


def _linear_filter_and_smoother(z: np.ndarray, q_c: float, r2: float, dt: float, lag: int) -> tuple:
    """The textbook linear Kalman filter (state angle, rate) and its fixed-lag RTS estimates for a scalar
    measurement sequence ``z [T]`` (first state: z[0], rate 0 with SD 3 rad/s, as the filter starts)."""
    f = np.array([[1.0, dt], [0.0, 1.0]])
    h = np.array([[1.0, 0.0]])
    q = q_c * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    x, p = np.array([z[0], 0.0]), np.diag([r2, 9.0])
    xs, ps, xps, pps = [x], [p], [x], [p]
    for value in z[1:]:
        xp, pp = f @ x, f @ p @ f.T + q
        k = pp @ h.T / (h @ pp @ h.T + r2)
        x = xp + (k * (value - xp[0])).ravel()
        p = (np.eye(2) - k @ h) @ pp
        for kept, value_now in ((xs, x), (ps, p), (xps, xp), (pps, pp)):
            kept.append(value_now)
    filtered = np.array([s[0] for s in xs])
    lagged = np.full(len(z), np.nan)
    for t in range(lag, len(z)):          # estimate of t - lag given frames up to t
        smoothed = xs[t]
        for k in range(t - 1, t - lag - 1, -1):
            c = ps[k] @ f.T @ np.linalg.inv(pps[k + 1])
            smoothed = xs[k] + c @ (smoothed - xps[k + 1])
        lagged[t - lag] = smoothed[0]
    return filtered, lagged


def test_steady_state_gain_is_the_riccati_equations():
    """Held still, the filter's gain settles to the one of SciPy's discrete algebraic Riccati solution."""
    kalman = RotationKalman(FPS, 0, NOISE)
    still = _about_x(np.zeros(1))[0]
    for index in range(600):
        kalman.add(index, still, ONES)
    entry = kalman.history[-1]
    gain = entry.cov_pred[:, :, 0] / (entry.cov_pred[:, 0, 0] + NOISE.fit_sd_rad ** 2)[:, None]   # [R, 2]
    f = np.array([[1.0, 1.0 / FPS], [0.0, 1.0]])
    h = np.array([[1.0, 0.0]])
    spectral = spectral_density(NOISE)
    for j in range(N_RIG_JOINTS):
        q = process_noise(spectral[j:j + 1], 1.0 / FPS)[0]
        p = solve_discrete_are(f.T, h.T, q, np.array([[NOISE.fit_sd_rad ** 2]]))   # a priori covariance
        expected = (p @ h.T / (h @ p @ h.T + NOISE.fit_sd_rad ** 2)).ravel()
        np.testing.assert_allclose(gain[j], expected, rtol=1e-6)
    assert 0.05 < gain[:, 0].min() < gain[:, 0].max() < 0.9   # neither ignoring the fits nor copying them


@pytest.mark.parametrize("lag", [0, 3, 6])
def test_one_axis_is_the_linear_filter_and_smoother(lag):
    """Rotations about one axis are linear in their angle: the filter and its fixed-lag smoother give the
    textbook matrix filter's and smoother's angles."""
    rng = np.random.default_rng(3)
    t = np.arange(180) / FPS
    angles = 0.8 * np.sin(2 * np.pi * 0.7 * t) + rng.normal(0.0, np.radians(2.0), len(t))
    fits = _about_x(angles)
    kalman = RotationKalman(FPS, lag, NOISE)
    got = np.full(len(t), np.nan)
    for index, fit in enumerate(fits):
        kalman.add(index, fit, ONES)
        if index >= lag:
            q = kalman.estimate(index - lag)[RIG_JOINTS.index("r_elbow")]
            got[index - lag] = 2.0 * np.arctan2(q[1], q[0])
    j = RIG_JOINTS.index("r_elbow")   # any joint: its own process noise
    spectral = spectral_density(NOISE)[j]
    filtered, lagged = _linear_filter_and_smoother(angles, spectral, NOISE.fit_sd_rad ** 2, 1.0 / FPS, lag)
    expected = filtered if lag == 0 else lagged
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok], expected[ok], atol=1e-9)


def test_a_constant_angular_velocity_is_tracked_without_lag():
    """A joint turning at 3 rad/s about a tilted axis, fitted exactly: after a settling second the causal
    estimate is within 0.05° of the fit (a first-order low-pass would trail by rate × its time constant)."""
    axis = np.array([0.3, 0.8, -0.52]) / np.linalg.norm([0.3, 0.8, -0.52])
    base = Rotation.from_rotvec([0.2, -0.4, 0.1])
    kalman = RotationKalman(FPS, 0, NOISE)
    errors = []
    for index in range(120):
        turned = base * Rotation.from_rotvec(axis * 3.0 * index / FPS)
        fit = np.tile(np.roll(turned.as_quat(), 1), (N_RIG_JOINTS, 1))
        kalman.add(index, fit, ONES)
        errors.append(_angle_deg(kalman.estimate(index), fit).max())
    assert max(errors[60:]) < 0.05
    assert max(errors[:5]) > 0.5   # it does start behind (the first frame's turning rate is unknown)


def test_a_step_is_followed_within_a_tenth_of_a_second():
    """The fits jump by 40° and stay: every joint comes within 2° of them within 8 frames (0.13 s at
    60 fps), overshoots by less than a fifth of the step (the price of predicting at constant angular
    velocity) and settles within 1.5° by 0.5 s; the first frame after the jump moves only part-way
    (the gate caps a pop's pull)."""
    angles = np.where(np.arange(90) < 30, 0.0, np.radians(40.0))
    fits = _about_x(angles)
    kalman = RotationKalman(FPS, 0, NOISE)
    errors = []
    for index, fit in enumerate(fits):
        kalman.add(index, fit, ONES)
        q = kalman.estimate(index)
        errors.append(np.degrees(2.0 * np.arctan2(q[:, 1], q[:, 0])) - np.degrees(angles[index]))
    errors = np.array(errors)[30:]          # [frames since the step, R]
    assert np.abs(errors[0]).min() > 20.0
    reached = np.argmax(np.abs(errors) < 2.0, axis=0)
    assert (np.abs(errors) < 2.0).any(axis=0).all() and reached.max() <= 8
    assert errors.max() < 0.2 * 40.0
    assert np.abs(errors[30:]).max() < 1.5


def test_the_shoulders_noise_is_their_measured_acceleration_times_both_factors():
    """Each joint's spectral density is (factor × its RMS angular acceleration)² × the frame time it was
    measured at; the shoulders' acceleration also times ``shoulder_factor``."""
    noise = RotationNoise(accel_factor=2.0, shoulder_factor=0.25)
    got = dict(zip(RIG_JOINTS, spectral_density(noise)))
    assert got["r_shoulder"] == pytest.approx((2.0 * 0.25 * 31.4) ** 2 / 24.0)
    assert got["l_elbow"] == pytest.approx((2.0 * ROTATION_ACCEL_RAD_S2["l_elbow"]) ** 2 * ACCEL_FRAME_S)


def test_each_frame_of_lag_buys_accuracy():
    """Noisy fits (5° SD) of a motion within the model's accelerations (a 0.5 Hz swing of ±34°, at most
    6 rad/s²): the error falls from lag 0 to 3 to 6 frames."""
    rng = np.random.default_rng(7)
    t = np.arange(300) / FPS
    truth = 0.6 * np.sin(2 * np.pi * 0.5 * t)
    fits = _about_x(truth + rng.normal(0.0, np.radians(5.0), len(t)))
    rms = {}
    for lag in (0, 3, 6):
        kalman = RotationKalman(FPS, lag, NOISE)
        err = []
        for index, fit in enumerate(fits):
            kalman.add(index, fit, ONES)
            if index >= lag:
                err.append(_angle_deg(kalman.estimate(index - lag), _about_x(truth[[index - lag]])[0]))
        rms[lag] = float(np.sqrt(np.mean(np.square(err[30:]))))
    assert rms[6] < 0.9 * rms[3] < 0.9 * 0.9 * rms[0]


def test_confidence_weighs_each_frame_and_unseen_keypoints_count_least():
    """A joint's confidence is its keypoints' mean, floored; a low one moves the estimate less."""
    kp = np.ones((14, 3))
    kp[KP["r_wrist"], 2] = 0.0
    kp[KP["r_knee"], 2] = 0.5
    conf = joint_confidence(kp)
    assert conf[RIG_JOINTS.index("r_elbow")] == MIN_CONFIDENCE
    assert conf[RIG_JOINTS.index("r_hip")] == 0.5
    assert conf[RIG_JOINTS.index("l_elbow")] == 1.0
    np.testing.assert_array_equal(joint_confidence(None), ONES)
    moves = []
    for weight in (1.0, 0.5):
        kalman = RotationKalman(FPS, 0, NOISE)
        for index in range(30):
            kalman.add(index, _about_x(np.zeros(1))[0], ONES)
        kalman.add(30, _about_x(np.radians([5.0]))[0], ONES * weight)
        moves.append(_angle_deg(kalman.estimate(30), _about_x(np.zeros(1))[0]).max())
    assert moves[1] < 0.5 * moves[0]


def test_rotation_noise_refuses_bad_settings():
    with pytest.raises(ValueError):
        RotationNoise(fit_sd_rad=0.0)
    with pytest.raises(ValueError):
        RotationNoise(accel_factor=-1.0)
    with pytest.raises(ValueError):
        RotationNoise(shoulder_factor=0.0)
