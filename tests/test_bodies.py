"""Varied bodies for the evaluation, bone lengths, and the foot metrics (hand-computed references)."""
import numpy as np
import pytest

from mocapdb.core.anthropometry import PROPORTION_CORRELATION, PROPORTION_SD
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    KP,
    MEASURED_BONE_NAMES,
    PELVIS,
    bone_lengths_m,
    rest_positions_m,
    stature_m,
    universal_bone_lengths_m,
)
from mocapdb.evaluation.bodies import (
    HEIGHT_RANGE_M,
    reshape_body,
    sample_body,
)
from mocapdb.evaluation.heldout import Scenario, Truth, camera_to_world, camera_view, scenario_positions
from mocapdb.evaluation.metrics import foot_height_error_m, foot_skating_mps, planted_feet, speeds_mps

from .conftest import SAMPLE_BVH


@pytest.fixture(scope="module")
def source_walk():
    clip = process_clip(SAMPLE_BVH / "002_01.bvh", SAMPLE_BVH, ClipOptions())
    return clip.source_m.astype(np.float64)


def test_bone_lengths_of_the_rest_pose_are_the_universal_bones():
    lengths = dict(zip(MEASURED_BONE_NAMES, universal_bone_lengths_m()))
    assert lengths["thigh"] == pytest.approx(0.43) and lengths["shank"] == pytest.approx(0.42)
    assert lengths["hip_width"] == pytest.approx(0.20) and lengths["shoulder_width"] == pytest.approx(0.38)
    assert lengths["neck_nose"] == pytest.approx(np.hypot(0.19, 0.08))
    # a hand-made skeleton: one thigh 0.3 m, the other 0.5 m → their mean
    points = rest_positions_m()
    points[KP["r_knee"]] = points[KP["r_hip"]] + [0.0, -0.3, 0.0]
    points[KP["l_knee"]] = points[KP["l_hip"]] + [0.0, -0.5, 0.0]
    assert bone_lengths_m(points)[MEASURED_BONE_NAMES.index("thigh")] == pytest.approx(0.4)


def test_source_joints_keep_their_own_bones(source_walk):
    lengths = bone_lengths_m(source_walk)
    assert np.ptp(lengths[:, :6], axis=0).max() < 1e-3          # rigid limbs: constant over the clip
    # the CMU clips' own body is not the universal skeleton's proportions
    ratio = lengths.mean(axis=0) / universal_bone_lengths_m()
    assert np.ptp(ratio) > 0.15
    assert source_walk[:, [KP["r_ankle"], KP["l_ankle"]], 1].min() > 0.05  # standing on the floor


def test_reshaped_body_has_the_asked_bones_the_source_directions_and_stands_on_the_floor(source_walk):
    target = universal_bone_lengths_m() * [1.1, 0.9, 1.2, 0.8, 1.0, 1.05, 0.95, 1.0]
    body = reshape_body(source_walk, target)
    np.testing.assert_allclose(bone_lengths_m(body), np.broadcast_to(target, (len(body), 8)), atol=1e-9)
    for a, b in (("r_knee", "r_ankle"), ("l_elbow", "l_wrist"), ("pelvis", "neck")):
        d_src = source_walk[:, KP[b]] - source_walk[:, KP[a]]
        d_new = body[:, KP[b]] - body[:, KP[a]]
        cos = np.sum(d_src * d_new, axis=-1) / np.linalg.norm(d_src, axis=-1) / np.linalg.norm(d_new, axis=-1)
        assert cos.min() > 1 - 1e-9
    leg = target[0] + target[1]
    assert body[:, [KP["r_ankle"], KP["l_ankle"]], 1].min() == pytest.approx(ANKLE_HEIGHT_M * leg / 0.85)
    # the pelvis path scales with the leg (a longer leg takes longer strides)
    src_leg = bone_lengths_m(source_walk).mean(axis=0)[:2].sum()
    travel = np.ptp(body[:, PELVIS, [0, 2]], axis=0)
    np.testing.assert_allclose(travel, np.ptp(source_walk[:, PELVIS, [0, 2]], axis=0) * leg / src_leg, rtol=1e-9)


def test_sampled_bodies_follow_the_documented_distribution():
    rng = np.random.default_rng(1)
    bodies = [sample_body(rng) for _ in range(4000)]
    heights = np.array([b.height_m for b in bodies])
    assert heights.min() >= HEIGHT_RANGE_M[0] and heights.max() <= HEIGHT_RANGE_M[1]
    logs = np.log([b.factors for b in bodies])
    sd = np.array([PROPORTION_SD[n] for n in MEASURED_BONE_NAMES])
    np.testing.assert_allclose(logs.std(axis=0), sd, rtol=0.06)
    np.testing.assert_allclose(np.corrcoef(logs.T), PROPORTION_CORRELATION, atol=0.05)
    # a body's bones at its stature: the stature of the result is the sampled one when factors are 1
    src = universal_bone_lengths_m() * 1.1
    b = bodies[0]
    unit = type(b)(b.height_m, np.ones(8))
    assert stature_m(unit.bone_lengths_m(src)) == pytest.approx(b.height_m)


def test_varied_scenario_draws_one_body_per_clip_and_yaw(source_walk):
    truth = Truth("walk", source_walk, (6.0, 51.0), source_walk)
    clean = Scenario("v", body="varied")
    pitched = Scenario("p", body="varied", pitch_deg=15.0)
    a, ha = scenario_positions(truth, clean, 0, 0, seed=3)
    b, hb = scenario_positions(truth, pitched, 0, 0, seed=3)
    c, hc = scenario_positions(truth, clean, 0, 1, seed=3)
    np.testing.assert_array_equal(a, b)          # the same body in every scenario
    assert ha == hb != hc
    with pytest.raises(ValueError, match="varied body"):
        Scenario("x", body="varied", subject_height_m=1.6)


def test_camera_to_world_inverts_camera_view(source_walk):
    for pitch in (0.0, 15.0, -20.0):
        cam = camera_view(source_walk, 51.0, 1.5, 5.0, pitch)
        world = camera_to_world(cam, 1.5, 5.0, pitch)
        # heights and horizontal distances are the source's (the turn about the vertical keeps them)
        np.testing.assert_allclose(world[..., 1], source_walk[..., 1], atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(np.diff(world[..., [0, 2]], axis=0), axis=-1),
                                   np.linalg.norm(np.diff(source_walk[..., [0, 2]], axis=0), axis=-1), atol=1e-9)


def test_speeds_and_foot_metrics_by_hand():
    fps = 10.0
    # an ankle at rest for 5 frames, then moving 0.1 m per frame (1 m/s) along x, 0.08 m high
    x = np.concatenate([np.zeros(5), 0.1 * np.arange(1, 6)])
    ankle = np.stack([x, np.full(10, 0.08), np.zeros(10)], axis=-1)
    ankles = np.stack([ankle, ankle + [0.0, 0.0, 0.3]], axis=1)      # [F, 2, 3]
    speed = speeds_mps(ankles, fps)
    np.testing.assert_allclose(speed[:4, 0], 0.0)
    np.testing.assert_allclose(speed[4, 0], 0.5)                     # central difference at the corner
    np.testing.assert_allclose(speed[6:, 0], 1.0)
    planted = planted_feet(ankles, fps)
    assert planted[:4].all() and not planted[4:].any()
    # a prediction sliding 0.02 m per frame (0.2 m/s) and 3 cm into the floor while the truth stands
    pred = ankles.copy()
    pred[:, :, 0] += 0.02 * np.arange(10)[:, None]
    pred[:, :, 1] -= 0.03
    np.testing.assert_allclose(foot_skating_mps(pred, planted, fps), 0.2)
    np.testing.assert_allclose(foot_height_error_m(pred, ankles, planted), -0.03)
    # frames without output (NaN) are left out
    pred[2] = np.nan
    assert len(foot_skating_mps(pred, planted, fps)) == 2 and np.isfinite(foot_skating_mps(pred, planted, fps)).all()
