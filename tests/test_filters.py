"""1€ filters against hand-computed values, closed forms and measured jitter/lag."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.geometry import quat_geodesic
from mocapdb.runtime.filters import OneEuroFilter, OneEuroParams, QuaternionOneEuroFilter

RNG = np.random.default_rng(11)


def _run(f, xs, ts):
    return np.array([f(x, t) for x, t in zip(xs, ts)])


def test_first_three_outputs_by_hand():
    # Rate r = 10 Hz; min_cutoff = d_cutoff = 5/π Hz gives 2π f = 10, so a(d_cutoff) = 1/(1 + 10/10) = 1/2;
    # beta = 1/π gives 2π f_c = 10 + 2 |dx̂|.
    f = OneEuroFilter(OneEuroParams(min_cutoff_hz=5 / np.pi, beta=1 / np.pi, d_cutoff_hz=5 / np.pi))
    # Sample 0 (x = 0, t = 0) passes through: x̂ = 0, dx̂ = 0.
    # Sample 1 (x = 1, t = 0.1): dx = (1 - 0)·10 = 10; dx̂ = ½·10 + ½·0 = 5; 2π f_c = 10 + 2·5 = 20;
    #   a = 1/(1 + 10/20) = 2/3; x̂ = ⅔·1 + ⅓·0 = 2/3.
    # Sample 2 (x = 3, t = 0.2): dx = (3 - 2/3)·10 = 70/3; dx̂ = ½·70/3 + ½·5 = 85/6;
    #   2π f_c = 10 + 85/3 = 115/3; a = 1/(1 + 30/115) = 23/29; x̂ = 23/29·3 + 6/29·2/3 = 73/29.
    out = _run(f, [0.0, 1.0, 3.0], [0.0, 0.1, 0.2])
    np.testing.assert_allclose(out, [0.0, 2 / 3, 73 / 29], rtol=1e-12)


def test_beta_zero_is_a_first_order_low_pass():
    fps, cutoff = 30.0, 1.5
    alpha = 1.0 / (1.0 + fps / (2 * np.pi * cutoff))
    gain = np.array([[1.0, -2.0], [0.5, 3.0], [0.0, 7.0]])  # any shape: a step of a different height per component
    n = np.arange(60)
    xs = np.where(n[:, None, None] == 0, 0.0, gain)
    out = _run(OneEuroFilter(OneEuroParams(min_cutoff_hz=cutoff, beta=0.0)), xs, n / fps)
    expected = (1.0 - (1.0 - alpha) ** n)[:, None, None] * gain  # step response y_n = 1 - (1 - a)^n
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-15)


def test_constant_input_stays_constant():
    x = RNG.normal(size=(5, 3))
    ts = np.cumsum(RNG.uniform(0.01, 0.05, 50))
    out = _run(OneEuroFilter(OneEuroParams(beta=2.0)), [x] * 50, ts)
    np.testing.assert_allclose(out, np.broadcast_to(x, out.shape), rtol=0, atol=1e-12)


def test_jitter_variance_drops_tenfold():
    fps, sigma = 60.0, 0.01
    noisy = 1.0 + RNG.normal(0.0, sigma, 4000)
    out = _run(OneEuroFilter(OneEuroParams(min_cutoff_hz=1.0, beta=0.05)), noisy, np.arange(4000) / fps)
    # beta = 0 would give a/(2 - a) = 0.05 of the input variance (a = 0.095); ask for at most a tenth.
    assert np.var(out[200:]) < 0.1 * sigma ** 2
    assert abs(np.mean(out[200:]) - 1.0) < 0.002


def test_beta_bounds_the_lag_on_a_ramp():
    fps, speed, cutoff, beta = 60.0, 1.0, 1.0, 1.0
    ts = np.arange(600) / fps
    lag = {b: speed * ts[-1] - _run(OneEuroFilter(OneEuroParams(min_cutoff_hz=cutoff, beta=b)), speed * ts, ts)[-1]
           for b in (0.0, beta)}
    # beta = 0, steady state: L = (1 - a) v dt / a with a = 1/(1 + fps/(2π f)), i.e. L = v / (2π f).
    np.testing.assert_allclose(lag[0.0], speed / (2 * np.pi * cutoff), rtol=1e-9)
    # beta > 0: the smoothed speed is at least v, so f_c >= f + beta v and L <= v / (2π (f + beta v)): half here.
    assert 0 < lag[beta] <= speed / (2 * np.pi * (cutoff + beta * speed))


@pytest.mark.parametrize("make", [lambda: OneEuroFilter(), lambda: QuaternionOneEuroFilter()])
def test_non_increasing_timestamp_is_skipped(make):
    samples = Rotation.random(4, random_state=1).as_quat()[:, [3, 0, 1, 2]]
    reference, skipping = make(), make()
    expected = [reference(samples[i], t) for i, t in enumerate([0.0, 0.1, 0.2])]
    got = [skipping(samples[0], 0.0), skipping(samples[1], 0.1), skipping(samples[3], 0.1),
           skipping(samples[3], 0.05), skipping(samples[2], 0.2)]
    np.testing.assert_array_equal(got[2], got[1])
    np.testing.assert_array_equal(got[3], got[1])
    np.testing.assert_allclose(got[4], expected[2], rtol=0, atol=1e-15)


def test_reset_lets_the_next_sample_through():
    f = OneEuroFilter()
    f(np.zeros(3), 0.0)
    f(np.ones(3), 0.1)
    f.reset()
    np.testing.assert_array_equal(f(np.full(3, 5.0), 0.2), np.full(3, 5.0))


def _quats(rotations: Rotation) -> np.ndarray:
    """(w, x, y, z) with w >= 0, as a pose pipeline would typically deliver them."""
    q = rotations.as_quat()[..., [3, 0, 1, 2]]
    return np.where(q[..., :1] < 0, -q, q)


def test_quaternion_step_by_hand_uses_the_angular_speed_per_joint():
    # Same numbers as the scalar case: r = 10 Hz, a(d_cutoff) = 1/2, 2π f_c = 10 + 2 |ω̂|.
    f = QuaternionOneEuroFilter(OneEuroParams(min_cutoff_hz=5 / np.pi, beta=1 / np.pi, d_cutoff_hz=5 / np.pi))
    identity = np.array([[1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
    turned = identity.copy()
    turned[0] = [np.cos(0.5), 0.0, 0.0, np.sin(0.5)]  # joint 0 turns 1 rad about z, joint 1 stays
    f(identity, 0.0)
    out = f(-turned, 0.1)  # the sign of the input is irrelevant
    # Joint 0: |ω| = 1 rad · 10 Hz = 10 rad/s; ω̂ = ½·10 = 5; 2π f_c = 20; a = 1/(1 + 10/20) = 2/3;
    # output = normalise(⅓ · identity + ⅔ · turned).
    blend = np.array([1 / 3 + 2 / 3 * np.cos(0.5), 0.0, 0.0, 2 / 3 * np.sin(0.5)])
    np.testing.assert_allclose(out[0], blend / np.linalg.norm(blend), rtol=1e-12)
    np.testing.assert_array_equal(out[1], identity[1])


def test_sign_alternation_never_flips_the_output():
    q = _quats(Rotation.random(3, random_state=2))
    f = QuaternionOneEuroFilter()
    out = np.array([f(q * (-1) ** k, k / 30) for k in range(40)])
    assert np.max(quat_geodesic(out, q)) < 1e-7
    np.testing.assert_allclose(out, np.broadcast_to(q, out.shape), atol=1e-7)  # the first sign is kept


def test_sweep_past_180_degrees_is_followed_without_a_jump():
    fps, omega = 30.0, 2.0  # rad/s about a tilted axis, from 0 to 330°
    axis = np.array([1.0, 2.0, 2.0]) / 3.0
    ts = np.arange(int(np.radians(330) / omega * fps)) / fps
    inputs = _quats(Rotation.from_rotvec(np.outer(omega * ts, axis)))[:, None]  # hemisphere flip at 180°
    assert np.min(np.sum(inputs[1:] * inputs[:-1], axis=-1)) < -0.9
    f = QuaternionOneEuroFilter(OneEuroParams(min_cutoff_hz=1.0, beta=0.3))
    out = np.array([f(q, t) for q, t in zip(inputs, ts)])
    step = 2 * quat_geodesic(out[1:], out[:-1])  # rotation between successive outputs, radians
    assert np.max(step) <= 1.2 * omega / fps  # catching up may outpace the input a little; never a jump
    assert np.min(np.sum(out[1:] * out[:-1], axis=-1)) > 0.99  # components continuous, no sign flip
    # Beyond the warm-up the output trails the input by less than beta = 0 would (ω / (2π f_min)).
    assert np.max(2 * quat_geodesic(out[30:], inputs[30:])) < omega / (2 * np.pi * 1.0)
    assert out[-1, 0, 0] < 0  # past 180° the output keeps going with w < 0: w >= 0 is not enforced


def test_outputs_are_unit_and_jitter_is_reduced():
    base = Rotation.random(5, random_state=3)
    noise = Rotation.from_rotvec(RNG.normal(0.0, np.radians(2.0), (300, 5, 3)))
    inputs = _quats(noise * base)  # unit, random hemispheres
    f = QuaternionOneEuroFilter()
    out = np.array([f(q, k / 30) for k, q in enumerate(inputs)])
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-12)
    truth = _quats(base)
    error_in = np.sqrt(np.mean(quat_geodesic(inputs[60:], truth) ** 2))
    error_out = np.sqrt(np.mean(quat_geodesic(out[60:], truth) ** 2))
    assert error_out < error_in / 2.5


def test_constant_rotation_stays_constant():
    q = _quats(Rotation.random(7, random_state=4))
    f = QuaternionOneEuroFilter()
    out = np.array([f(q, t) for t in np.cumsum(RNG.uniform(0.01, 0.05, 30))])
    np.testing.assert_allclose(out, np.broadcast_to(q, out.shape), rtol=0, atol=1e-12)


def _standing_keypoints():
    from mocapdb.core.skeleton import KP
    px = np.zeros((14, 2))
    for name, (x, y) in {"head": (500, 100), "neck": (500, 160), "r_shoulder": (460, 165), "l_shoulder": (540, 165),
                         "r_elbow": (440, 240), "l_elbow": (560, 240), "r_wrist": (430, 310), "l_wrist": (570, 310),
                         "r_hip": (475, 330), "l_hip": (525, 330), "r_knee": (470, 430), "l_knee": (530, 430),
                         "r_ankle": (468, 530), "l_ankle": (532, 530)}.items():
        px[KP[name]] = (x, y)
    return px


def test_keypoint_filter_undoes_a_left_right_swap_of_the_arms():
    from mocapdb.runtime.filters import ARM_PAIRS, KeypointFilter, KeypointFilterParams
    f = KeypointFilter(KeypointFilterParams(), 14)
    px, conf = _standing_keypoints(), np.ones(14)
    for i in range(5):
        np.testing.assert_allclose(f(px, conf, i / 30.0), px)  # a still person passes unchanged
    swapped = px.copy()
    for right, left in ARM_PAIRS:
        swapped[[right, left]] = px[[left, right]]
    np.testing.assert_allclose(f(swapped, conf, 5 / 30.0), px, atol=1e-9)
    assert f.swaps == 1
    off = KeypointFilter(KeypointFilterParams(undo_swaps=False, min_cutoff_hz=1e6, max_cutoff_hz=1e6), 14)
    for i in range(5):
        off(px, conf, i / 30.0)
    np.testing.assert_allclose(off(swapped, conf, 5 / 30.0), swapped, atol=0.01)


def _arms_swapped(px):
    from mocapdb.runtime.filters import ARM_PAIRS
    swapped = px.copy()
    for right, left in ARM_PAIRS:
        swapped[[right, left]] = px[[left, right]]
    return swapped


def test_keypoint_filter_undoes_a_run_of_swaps_but_not_a_wrong_labelling_for_ever():
    """By hand, without smoothing (value = output): frame 5 is a detector mid-flip (shoulders exchanged,
    elbows and wrists on the body's mid-line): keep 420 px against swap 260 px, not undone (260 > 0.5 x
    420); frame 6 has the arms fully exchanged: against frame 5, keep 260 against swap 420, not undone:
    the estimate now holds the exchanged labelling, and every later (right) frame fits it exchanged
    (keep 680, swap 0). Without a bound every later frame is exchanged; with max_swap_s = 0.25 s (30 fps)
    frames 7-14 are (t - 7/30 <= 0.25 s), from frame 15 on the detector's labelling is taken."""
    from mocapdb.core.skeleton import KP
    from mocapdb.runtime.filters import KeypointFilter, KeypointFilterParams
    px, conf, fps = _standing_keypoints(), np.ones(14), 30.0
    swapped = _arms_swapped(px)
    mid_flip = swapped.copy()
    for part, y in (("elbow", 240.0), ("wrist", 310.0)):
        mid_flip[KP[f"r_{part}"]] = mid_flip[KP[f"l_{part}"]] = (500.0, y)
    frames = [px] * 5 + [mid_flip, swapped] + [px] * 23
    unsmoothed = dict(min_cutoff_hz=1e6, max_cutoff_hz=1e6)
    unbounded = KeypointFilter(KeypointFilterParams(max_swap_s=np.inf, **unsmoothed), 14)
    bounded = KeypointFilter(KeypointFilterParams(**unsmoothed), 14)
    for i, points in enumerate(frames):
        locked, freed = unbounded(points, conf, i / fps), bounded(points, conf, i / fps)
        if i >= 7:
            np.testing.assert_allclose(locked, swapped, atol=0.01)
            np.testing.assert_allclose(freed, swapped if i <= 14 else px, atol=0.01)
    assert unbounded.swaps == 23 and bounded.swaps == 8
    # a run of swaps shorter than the bound is undone throughout
    short = KeypointFilter(KeypointFilterParams(**unsmoothed), 14)
    for i, points in enumerate([px] * 5 + [swapped] * 3 + [px] * 5):
        np.testing.assert_allclose(short(points, conf, i / fps), px, atol=0.01)
    assert short.swaps == 3


def test_keypoint_filter_smooths_jitter_and_follows_motion():
    from mocapdb.runtime.filters import KeypointFilter, KeypointFilterParams
    rng = np.random.default_rng(0)
    px, conf, fps = _standing_keypoints(), np.ones(14), 30.0
    f = KeypointFilter(KeypointFilterParams(), 14)
    out = np.array([f(px + rng.normal(scale=5.0, size=px.shape), conf, i / fps) for i in range(300)])
    assert np.std(out[50:] - px, axis=0).mean() < 0.7 * 5.0  # jitter cut by a third (6 Hz at 30 fps)
    # A steady sideways walk at 1 box height per second: the lag stays within 5 % of the box.
    g = KeypointFilter(KeypointFilterParams(), 14)
    box = np.ptp(px[:, 1])
    for i in range(60):
        moved = px + [box * i / fps, 0.0]
        result = g(moved, conf, i / fps)
    assert np.abs(result - moved).max() < 0.05 * box


def test_keypoint_filter_holds_unseen_points_and_ignores_repeated_times():
    from mocapdb.runtime.filters import KeypointFilter, KeypointFilterParams
    px, conf = _standing_keypoints(), np.ones(14)
    f = KeypointFilter(KeypointFilterParams(), 14, reset_s=0.5)
    f(px, conf, 0.0)
    f(px + 10.0, conf, 0.1)
    before = f.value.copy()
    np.testing.assert_allclose(f(px + 50.0, conf, 0.1), before)  # same time: no update
    np.testing.assert_allclose(f.value, before)
    hidden = conf.copy()
    hidden[3] = 0.0
    f(px, hidden, 0.2)
    np.testing.assert_allclose(f.value[3], before[3])  # unseen: held
    out = f(px + [300.0, 0.0], conf, 1.0)  # seen again after 0.8 s: starts afresh
    np.testing.assert_allclose(out[3], px[3] + [300.0, 0.0])


def test_keypoint_filter_measures_jitter_and_only_smooths_noisy_tracks():
    from mocapdb.runtime.filters import KeypointFilter, KeypointFilterParams
    rng = np.random.default_rng(1)
    px, conf, fps = _standing_keypoints(), np.ones(14), 30.0
    box = np.ptp(px[:, 1])
    noisy, clean = KeypointFilter(KeypointFilterParams(), 14), KeypointFilter(KeypointFilterParams(), 14)
    for i in range(120):
        noisy(px + rng.normal(scale=5.0, size=px.shape), conf, i / fps)
        clean(px + [2.0 * i, 0.0], conf, i / fps)  # steady motion, no jitter
    assert noisy.noise[0] == pytest.approx(5.0 / box, rel=0.25)
    assert clean.noise[0] < 0.001
    next_noisy, next_clean = px + rng.normal(scale=5.0, size=px.shape), px + [2.0 * 120, 0.0]
    assert noisy._cutoff(next_noisy, conf > 0) < 1.5 * KeypointFilterParams().min_cutoff_hz
    assert clean._cutoff(next_clean, conf > 0) == KeypointFilterParams().max_cutoff_hz
