"""The whole-take fit: zero-phase smoothing against a known trajectory, pops, contact locking, leg IK,
the floor plane (hand-made cases with known answers)."""
from functools import partial

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from mocapdb.core.geometry import quat_geodesic
from mocapdb.core.skeleton import KP, N_RIG_JOINTS, bone_lengths_m, pose_from_rotations
from mocapdb.runtime.foot_contacts import planted_ankles
from mocapdb.runtime.take import (
    REACH_SMOOTHING_FRAMES,
    contact_targets,
    fit_root_path,
    plant_feet,
    refit_to_image,
    smooth_rotations,
    smoothed_keypoints,
    within_reach,
)
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.world.contact_floor import floor_plane

FPS = 30.0


def _turns(angles_rad: np.ndarray, axis=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Quaternions ``[F, 4]`` of rotations by ``angles_rad`` about ``axis``."""
    axis = np.asarray(axis) / np.linalg.norm(axis)
    return np.column_stack([np.cos(angles_rad / 2), np.outer(np.sin(angles_rad / 2), axis)])


def test_zero_phase_smoothing_removes_jitter_without_lag_and_pops_without_trace():
    t = np.arange(240) / FPS
    truth_angle = 0.8 * np.sin(2 * np.pi * 0.5 * t)          # a 0.5 Hz swing of one joint
    rng = np.random.default_rng(0)
    noisy_angle = truth_angle + rng.normal(scale=0.05, size=len(t))
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), N_RIG_JOINTS, 1))
    quats[:, 3] = _turns(noisy_angle)
    quats[100, 3] = _turns(np.array([truth_angle[100] + 1.5]))[0]  # a one-frame pop of 86°
    quats[50:, 3] *= -1.0                                          # the same rotations, other sign
    out = smooth_rotations(quats, FPS, TakeParams(smoothing_hz=3.0))
    truth = _turns(truth_angle)
    err_in = quat_geodesic(np.delete(quats[:, 3], 100, axis=0), np.delete(truth, 100, axis=0))
    err_out = quat_geodesic(out[:, 3], truth)
    assert np.mean(err_out[10:-10]) < 0.6 * np.mean(err_in[10:-10])
    assert err_out[100] < 0.05                                     # the pop is gone
    # no lag: the smoothed angle's best match with the truth is at zero shift
    angle = 2 * np.arctan2(out[:, 3, 3] * np.sign(out[:, 3, 0]), np.abs(out[:, 3, 0]))
    shifts = range(-5, 6)
    best = min(shifts, key=lambda s: np.mean((np.roll(angle, s) - truth_angle)[10:-10] ** 2))
    assert best == 0
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0)


def test_root_path_locks_planted_ankles_and_keeps_the_image_across_the_ray():
    n = 90
    rng = np.random.default_rng(1)
    true_root = np.column_stack([np.linspace(-0.5, 0.5, n), np.full(n, -0.5), np.full(n, -5.0)])
    # ankle relative to the root: the planted foot's offset moves back as the body passes over it
    offsets = np.zeros((n, 2, 3))
    offsets[:, 0] = np.column_stack([-0.2 - true_root[:, 0], np.full(n, -0.85), np.zeros(n)])
    offsets[:, 1] = offsets[:, 0] + [0.0, 0.1, 0.0]
    planted = np.zeros((n, 2), dtype=bool)
    planted[:, 0] = True
    # per-frame roots: depth (along the ray, ~z) off by 15 cm of noise, the image direction exact
    ray = true_root / np.linalg.norm(true_root, axis=-1, keepdims=True)
    noisy = true_root + ray * rng.normal(scale=0.15, size=(n, 1))
    before = noisy[:, None] + offsets
    root, anchors = fit_root_path(noisy, offsets, planted, FPS, TakeParams())
    ankle = root + offsets[:, 0]
    assert np.ptp(ankle, axis=0).max() < 0.01                 # the planted ankle stays put …
    assert np.ptp(before[:, 0], axis=0).max() > 0.2            # … where the per-frame roots slid
    np.testing.assert_allclose(anchors[:, 0], np.broadcast_to(ankle.mean(axis=0), (n, 3)), atol=0.01)
    assert np.isnan(anchors[:, 1]).all()
    # the root stays on the per-frame roots' viewing rays (the image) within a centimetre
    across = root - np.sum(root * ray, axis=-1, keepdims=True) * ray
    assert np.linalg.norm(across, axis=-1).max() < 0.01 + 1e-3
    assert np.abs(root[:, 2] - true_root[:, 2]).mean() < np.abs(noisy[:, 2] - true_root[:, 2]).mean()


def _walk_away_with_short_strides(n: int, contact: int, short: float):
    """A root walking 4 m straight away from the camera, feet planted in turn for ``contact`` frames
    each, and the ankle offsets a pose gives whose legs are ``short`` too short along the ray."""
    root = np.column_stack([np.full(n, 0.2), np.full(n, -0.4), np.linspace(-5.0, -9.0, n)])
    ray = root / np.linalg.norm(root, axis=-1, keepdims=True)
    planted = np.zeros((n, 2), dtype=bool)
    offsets = np.zeros((n, 2, 3))
    for c, start in enumerate(range(0, n, contact)):
        t, k = np.arange(start, min(start + contact, n)), c % 2
        true_offset = root[(t[0] + t[-1]) // 2] + [0.1 * (2 * k - 1), -0.85, 0.0] - root[t]  # foot under mid-contact
        along = np.sum(true_offset * ray[t], axis=1, keepdims=True)
        planted[t, k] = True
        offsets[t, k] = true_offset - short * along * ray[t]
        offsets[t, 1 - k] = true_offset + [0.0, 0.1, 0.0]
    return root, ray, planted, offsets


def test_root_path_follows_the_depth_where_the_legs_are_short_in_depth():
    # the pose's stride 20 % short along the ray: held rigidly, each contact drags the root back
    # towards the camera and the walk ends ~0.25 m short; the contacts' depth slack lets the
    # (unbiased, noisy) per-frame depth keep the root where it is
    root, ray, planted, offsets = _walk_away_with_short_strides(150, 15, 0.2)
    noisy = root + ray * np.random.default_rng(3).normal(scale=0.15, size=(len(root), 1))
    rigid, _ = fit_root_path(noisy, offsets, planted, FPS, TakeParams(contact_depth_m=TakeParams().contact_m))
    path, _ = fit_root_path(noisy, offsets, planted, FPS, TakeParams())
    ends = np.r_[0:10, -10:0]
    rigid_error = np.linalg.norm(rigid - root, axis=1)[ends].mean()
    error = np.linalg.norm(path - root, axis=1)[ends].mean()
    assert rigid_error > 0.2
    assert error < 0.06 and error < 0.25 * rigid_error
    across = path - np.sum(path * ray, axis=-1, keepdims=True) * ray
    assert np.linalg.norm(across, axis=-1).max() < 0.02       # the image still fixes it across the ray


def test_the_root_moves_by_what_a_stretched_leg_falls_short_of_its_anchor():
    root = np.zeros((6, 3))
    ankles = np.zeros((6, 2, 3))
    planted = np.zeros((6, 2), dtype=bool)
    anchors = np.full((6, 2, 3), np.nan)
    planted[1, 0] = True                                   # short by 4 cm in depth
    anchors[1, 0] = [0.0, 0.0, -0.04]
    planted[4] = True                                      # both feet: short by 2 and 0 cm, the mean
    anchors[4] = [[0.02, 0.0, 0.0], [0.0, 0.0, 0.0]]
    moved = within_reach(root, ankles, planted, anchors)
    expected_z = [-0.04, -0.04, -0.04 * 2 / 3, -0.04 / 3, 0.0, 0.0]   # held, then linear from frame 1 to 4
    expected_x = [0.0, 0.0, 0.01 / 3, 0.02 / 3, 0.01, 0.01]
    smooth = partial(gaussian_filter1d, sigma=REACH_SMOOTHING_FRAMES, mode="nearest")  # scipy's, as the reference
    np.testing.assert_allclose(moved[:, 2], smooth(np.array(expected_z)), atol=1e-12)
    np.testing.assert_allclose(moved[:, 0], smooth(np.array(expected_x)), atol=1e-12)
    np.testing.assert_array_equal(within_reach(root, ankles, np.zeros((6, 2), dtype=bool), anchors), root)


def test_leg_ik_puts_a_planted_ankle_on_its_anchor_and_keeps_the_bones():
    n = 16
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, N_RIG_JOINTS, 1))
    quats[:, 0] = _turns(np.linspace(0.0, 0.3, n), axis=(0, 1, 0))  # the body turning
    root = np.column_stack([np.linspace(0, 0.2, n), np.full(n, 0.9), np.full(n, -4.0)])
    joints = pose_from_rotations(quats, root)
    anchor = joints[0, KP["r_ankle"]] + [0.05, 0.08, 0.1]      # within reach: the knee must bend
    planted = np.zeros((n, 2), dtype=bool)
    planted[2:9, 0] = True
    anchors = np.full((n, 2, 3), np.nan)
    anchors[planted[:, 0], 0] = anchor
    out = plant_feet(quats, root, 1.0, None, *contact_targets(planted, anchors))
    fixed = pose_from_rotations(out, root)
    np.testing.assert_allclose(fixed[2:9, KP["r_ankle"]], np.broadcast_to(anchor, (7, 3)), atol=1e-6)
    np.testing.assert_allclose(bone_lengths_m(fixed), bone_lengths_m(joints), atol=1e-9)
    np.testing.assert_allclose(fixed[:, KP["l_ankle"]], joints[:, KP["l_ankle"]], atol=1e-9)  # other leg untouched
    assert np.abs(fixed[12:] - joints[12:]).max() < 1e-9       # beyond the easing frames: unchanged
    moved = np.linalg.norm(fixed[:, KP["r_ankle"]] - joints[:, KP["r_ankle"]], axis=-1)
    assert 0 < moved[10] < moved[8]                              # eased out


def test_floor_plane_from_planted_ankles_on_a_tilted_floor():
    rng = np.random.default_rng(2)
    tilt = np.radians(10.0)
    normal_true = np.array([0.0, np.cos(tilt), np.sin(tilt)])
    xz = rng.uniform(-2, 2, size=(200, 2))
    # points p with normal_true · p = -1.4 + 0.08 (ankles 8 cm above a floor 1.4 m below the camera)
    base = np.column_stack([xz[:, 0], np.zeros(200), xz[:, 1] - 5])
    base[:, 1] = (-1.32 - base[:, 2] * normal_true[2]) / normal_true[1]
    ankles = np.stack([base, base + [0.0, 0.5, 0.0]], axis=1)
    planted = np.zeros((200, 2), dtype=bool)
    planted[:, 0] = True
    normal, offset = floor_plane(ankles, planted, np.array([0.0, 1.0, 0.0]), 0.08)
    assert np.degrees(np.arccos(normal @ normal_true)) < 0.5
    assert offset == pytest.approx(-1.40, abs=0.005)
    # few contacts in one spot: the camera's up is kept
    normal, offset = floor_plane(ankles[:5], planted[:5], np.array([0.0, 1.0, 0.0]), 0.08)
    np.testing.assert_allclose(normal, [0.0, 1.0, 0.0])


def test_refit_pulls_a_smoothed_pose_back_onto_the_image_and_keeps_frames_without_keypoints():
    """Keypoints rendered by a pinhole from a known pose; the 'smoothed' pose has the right elbow
    and left knee 25° off in the image plane: the re-fit turns both back towards the image, the further the weaker its
    pull to the smoothed pose, while a frame without keypoints keeps its pose."""
    from mocapdb.core.skeleton import N_KEYPOINTS_2D, RIG_JOINTS

    focal, centre = 1000.0, (960.0, 540.0)
    truth = np.tile([1.0, 0.0, 0.0, 0.0], (2, N_RIG_JOINTS, 1))
    truth[:, RIG_JOINTS.index("r_elbow")] = _turns(np.array([0.6]))[0]
    truth[:, RIG_JOINTS.index("l_knee")] = _turns(np.array([-0.4]))[0]
    root = np.array([[0.2, 0.1, -4.0]] * 2)
    joints = pose_from_rotations(truth, root)[:, :N_KEYPOINTS_2D]
    pixels = np.stack([centre[0] + focal * joints[..., 0] / -joints[..., 2],
                       centre[1] - focal * joints[..., 1] / -joints[..., 2]], axis=-1)
    keypoints = np.concatenate([pixels, np.full(pixels.shape[:2] + (1,), 0.9)], axis=-1)
    keypoints[1, :, 2] = 0.0                                   # frame 1: the track missed it
    off = truth.copy()
    off[:, RIG_JOINTS.index("r_elbow")] = _turns(np.array([0.6 + np.radians(25.0)]))[0]
    off[:, RIG_JOINTS.index("l_knee")] = _turns(np.array([-0.4 - np.radians(25.0)]))[0]
    held = refit_to_image(off, root, keypoints, 1.0, None, (focal, *centre), prior=20.0)
    free = refit_to_image(off, root, keypoints, 1.0, None, (focal, *centre), prior=1.0)
    for joint in ("r_elbow", "l_knee"):
        j = RIG_JOINTS.index(joint)
        before = quat_geodesic(off[0, j], truth[0, j])
        assert quat_geodesic(held[0, j], truth[0, j]) < 0.8 * before, joint  # towards the image ...
        assert quat_geodesic(free[0, j], truth[0, j]) < 0.4 * before, joint  # ... as far as the prior lets it
    np.testing.assert_array_equal(held[1], off[1])


def _walking_keypoints(n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints ``[n, 14, 3]`` of a 400-px-tall person whose right ankle is planted for frames
    10-49 and the left from frame 55 on, each swinging at 12 px a frame otherwise, σ 2 px noise;
    and the truth ``[n, 2]`` (right, left planted)."""
    t = np.arange(n)
    truth = np.zeros((n, 2), dtype=bool)
    truth[10:50, 0] = True
    truth[55:, 1] = True
    keypoints = np.zeros((n, 14, 3))
    keypoints[:, :, 0] = 900.0 + 3.0 * t[:, None]       # the body moves on; the planted foot does not
    keypoints[:, :, 1] = np.linspace(300.0, 700.0, 14)  # a 400-px box
    keypoints[:, :, 2] = 0.9
    for k, (side, start, stop) in enumerate((("r_ankle", 10, 49), ("l_ankle", 55, n - 1))):
        keypoints[:, KP[side], 0] = 960.0 + 40 * k + 12.0 * (t - np.clip(t, start, stop))  # swinging: 12 px a frame
    keypoints[..., :2] += rng.normal(scale=2.0, size=(n, 14, 2))
    return keypoints, truth


def test_contacts_survive_single_frame_swaps_and_missed_keypoints():
    """A detector's one-frame left/right swaps and missed ankles neither split a contact nor end it:
    each planted stretch is found as one contact, and the swinging foot is never planted."""
    rng = np.random.default_rng(4)
    keypoints, truth = _walking_keypoints(80, rng)
    r, l_ = KP["r_ankle"], KP["l_ankle"]
    for f in (15, 22, 31, 40, 60, 70):                    # swaps
        keypoints[f, [r, l_]] = keypoints[f, [l_, r]]
    keypoints[[18, 27, 36, 44, 63], r, 2] = 0.0           # missed right ankle
    keypoints[[58, 66, 74], l_, 2] = 0.0                  # missed left ankle
    ankles = np.zeros((80, 2, 3))                         # level feet: the height test passes
    planted = planted_ankles(keypoints, ankles, np.array([0.0, 1.0, 0.0]), FPS, TakeParams())
    for k in range(2):
        runs = np.flatnonzero(np.diff(np.concatenate([[0], planted[:, k].astype(int), [0]])))
        assert len(runs) == 2, f"ankle {k}: contacts {runs.reshape(-1, 2).tolist()}"   # one contact
    assert np.mean(planted[truth]) > 0.85  # each stance but its ends (the 0.25 s speed window)
    assert np.mean(truth[planted]) > 0.95                 # and hardly anything else


def test_floor_is_the_lowest_level_and_a_non_planar_set_keeps_the_cameras_up():
    """Contacts on the ground and on a platform 0.5 m up (a person climbing): the floor is the
    ground, and the two levels together are no plane, so the camera's up is kept."""
    rng = np.random.default_rng(5)
    ground = np.column_stack([rng.uniform(-1, 1, 60), np.full(60, -1.42), rng.uniform(-6, -4, 60)])
    platform = np.column_stack([rng.uniform(-1, 1, 40), np.full(40, -0.92), rng.uniform(-7, -6, 40)])
    points = np.concatenate([ground, platform])
    ankles = np.stack([points, points + [0.0, 0.3, 0.0]], axis=1)
    planted = np.zeros((len(points), 2), dtype=bool)
    planted[:, 0] = True
    up = np.array([0.0, 1.0, 0.0])
    normal, offset = floor_plane(ankles, planted, up, 0.08)
    np.testing.assert_allclose(normal, up)
    assert offset == pytest.approx(-1.50, abs=0.005)
    # the ground alone, a floor pitched 6° from the estimate: fitted
    tilt = np.radians(6.0)
    tilted = ground.copy()
    tilted[:, 1] = -1.42 - np.tan(tilt) * (tilted[:, 2] + 5.0)
    normal, _ = floor_plane(np.stack([tilted, tilted], axis=1), planted[:60], up, 0.08)
    assert np.degrees(np.arccos(normal @ [0.0, np.cos(tilt), np.sin(tilt)])) < 0.2


def test_reconstruct_writes_the_whole_take_unless_per_frame(small_db_path, tmp_path):
    """The bundled real take: the whole-take BVH moves more smoothly than the per-frame one, on a
    body of the same proportions (its size is the take's world's); ``--per-frame`` writes the
    stream's motion."""
    from mocapdb.cli.main import main
    from mocapdb.core.formats.bvh import forward_kinematics, read_bvh

    from .conftest import SAMPLE_KEYPOINTS

    common = [str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920",
              "--focal", "1681"]
    assert main(["reconstruct", *common, "--out", str(tmp_path / "take")]) == 0
    assert main(["reconstruct", *common, "--out", str(tmp_path / "frame"), "--per-frame"]) == 0
    motion = {}
    for name in ("take", "frame"):
        bvh = read_bvh(tmp_path / name / "track_1.bvh")
        joints, _ = forward_kinematics(bvh)
        motion[name] = (bvh, np.linalg.norm(np.diff(joints, 2, axis=0), axis=-1).mean())
    assert motion["take"][1] < 0.5 * motion["frame"][1]              # mean joint acceleration
    take_offsets, frame_offsets = motion["take"][0].offsets, motion["frame"][0].offsets
    size = np.linalg.norm(take_offsets) / np.linalg.norm(frame_offsets)
    np.testing.assert_allclose(take_offsets, size * frame_offsets, atol=1e-6)  # one body, scaled
    assert motion["take"][0].n_frames == motion["frame"][0].n_frames


def test_two_people_share_one_floor_and_their_sizes_follow(small_db):
    """Two people of 1.55 m and 1.85 m walking in front of one camera (1.5 m high, pitched 10°): each
    track alone assumes 1.75 m, so their floors disagree; on the shared floor both stand on one
    plane and their sizes come out in the true ratio."""
    from mocapdb.core.formats.keypoints import KeypointFrame, Person
    from mocapdb.core.geometry import axis_rotation_matrices, yaw_matrix
    from mocapdb.core.skeleton import PELVIS
    from mocapdb.runtime.engine import Engine
    from mocapdb.runtime.engine_config import EngineConfig
    from mocapdb.runtime.take import fit_take
    from mocapdb.runtime.world.fuse import estimate_world, place_in_world, track_evidence

    focal, size, pitch = 1000.0, (1920, 1080), np.radians(10.0)
    first, n = small_db.clip_first_frame[0], small_db.clip_n_frames[0]
    people = []
    for height, x, yaw in ((1.55, -1.2, 30.0), (1.85, 1.0, 200.0)):
        world = small_db.positions[first:first + n].astype(np.float64) * (height / 1.75)
        world = (world - world[:, PELVIS].mean(axis=0) * [1, 0, 1]) @ yaw_matrix(yaw).T + [x, 0.0, 0.0]
        view = (world - [0.0, 1.5, 5.0]) @ axis_rotation_matrices("X", pitch).T
        people.append(np.stack([size[0] / 2 + focal * view[..., 0] / -view[..., 2],
                                size[1] / 2 - focal * view[..., 1] / -view[..., 2]], axis=-1)[:, :14])
    frames = [KeypointFrame(i, i / 24.0, [Person(p[i], np.full(14, 0.9)) for p in people]) for i in range(n)]
    engine = Engine(small_db, EngineConfig(fps=24.0, focal_px=focal, image_size=size, keep_take=True))
    for frame in frames:
        engine.step(frame)
    recordings = [r for r in engine.finish() if len(r.quaternions) > n // 2]
    assert len(recordings) == 2
    fits = [fit_take(rec, 24.0) for rec in recordings]
    own = [result.floor_offset_m for _, result in fits]
    assert abs(own[0] - own[1]) > 0.1                    # alone, each stands on a floor of its own
    world = estimate_world([track_evidence(rec, result, 24.0) for rec, result in fits])
    shared = [place_in_world(rec, world, 24.0) for rec, _ in fits]
    assert shared[0].floor_offset_m == shared[1].floor_offset_m
    np.testing.assert_allclose(shared[0].up_view, shared[1].up_view)
    heights = {}
    for rec, (_, result) in zip(shared, fits):
        k = rec.scales[-1] / fits[[r.track for r, _ in fits].index(rec.track)][0].scales[-1]
        feet = k * result.planted_ankles_m @ rec.up_view - rec.floor_offset_m
        assert abs(np.median(feet) - 0.08 * rec.scales[-1]) < 0.03     # both on the one floor
        x = np.median(np.array(rec.root_view_m)[:, 0])
        heights["left" if x < 0 else "right"] = 1.75 * rec.scales[-1]
    assert heights["right"] / heights["left"] == pytest.approx(1.85 / 1.55, rel=0.06)
    # the camera's height above the shared floor is the true 1.5 m within 12 %: the two people's
    # geometric mean stature (1.69 m) is taken for the assumed 1.75 m, +3.5 % before the pitch's share
    assert -shared[0].floor_offset_m == pytest.approx(1.5, rel=0.12)


def test_a_straight_walk_fixes_the_floors_tilt_about_its_line():
    """Contacts along one line in depth (a walk towards the camera) on a floor pitched 8°: the
    camera's level guess keeps only its tilt about that line, so the pitch comes out right; a walk
    across the view fixes the roll and leaves the pitch to the guess."""
    from mocapdb.core.geometry import axis_rotation_matrices

    tilt = axis_rotation_matrices("X", np.radians(8.0))
    depth = np.linspace(-8.0, -3.0, 60)
    line = np.column_stack([np.zeros(60), np.full(60, -1.4), depth]) @ tilt.T   # on the pitched floor
    ankles, planted = line[:, None], np.ones((60, 1), dtype=bool)
    normal, _ = floor_plane(ankles, planted, np.array([0.0, 1.0, 0.0]), 0.08)
    np.testing.assert_allclose(normal, tilt @ [0.0, 1.0, 0.0], atol=1e-9)
    across = np.column_stack([np.linspace(-2, 2, 60), np.full(60, -1.4), np.full(60, -5.0)]) @ tilt.T
    normal, _ = floor_plane(across[:, None], planted, np.array([0.0, 1.0, 0.0]), 0.08)
    assert abs(normal[0]) < 1e-9 and abs(normal[2]) < 1e-9        # the level guess kept: pitch not fixed


@pytest.mark.parametrize("hz", [float("nan"), -1.0, float("inf")])
def test_smoothing_outside_its_domain_is_refused_naming_the_option(hz):
    with pytest.raises(ValueError, match="smoothing_hz"):
        TakeParams(smoothing_hz=hz)


def test_a_cut_off_far_above_the_frame_rate_leaves_the_rotations_as_they_are():
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (20, N_RIG_JOINTS, 1))
    quats[:, 3] = _turns(np.linspace(0.0, 1.0, 20) ** 2)
    out = smooth_rotations(quats, FPS, TakeParams(smoothing_hz=1000.0, pop_frames=1))
    np.testing.assert_allclose(out, quats, atol=1e-12)


def test_keypoints_for_the_refit_lose_pops_and_jitter_but_not_their_motion_nor_what_was_unseen():
    """A keypoint moving at constant speed with a one-frame swap, ±2 px jitter and one unseen frame
    comes out on its line (RMS under 0.5 px away from the ends), the unseen frame stays unseen, a
    keypoint seen once stays where it was, and confidences are kept."""
    n = 61
    frames = np.arange(n, dtype=np.float64)
    keypoints = np.zeros((n, 3, 3))
    keypoints[:, 0, 0], keypoints[:, 0, 1], keypoints[:, 0, 2] = 100.0 + 3.0 * frames, 500.0, 0.9
    keypoints[:, 0, 0] += np.where(np.arange(n) % 2 == 0, 2.0, -2.0)   # jitter at the Nyquist rate
    keypoints[30, 0, :2] = [700.0, 200.0]                              # swapped with another for a frame
    keypoints[20, 0] = [0.0, 0.0, 0.0]                                 # not seen
    keypoints[:, 1, 2] = 0.0
    keypoints[10, 1] = [50.0, 60.0, 0.8]                               # seen once
    keypoints[:, 2] = [400.0, 300.0, 0.7]
    out = smoothed_keypoints(keypoints, FPS, TakeParams(smoothing_hz=4.0))
    seen = np.arange(5, n - 5) != 20
    off_px = out[5:n - 5][seen, 0, :2] - np.column_stack([100.0 + 3.0 * frames[5:n - 5][seen],
                                                          np.full(seen.sum(), 500.0)])
    assert np.abs(off_px).max() < 2.0 and np.sqrt(np.mean(off_px ** 2)) < 0.5   # the pop was 600 px
    np.testing.assert_array_equal(out[20, 0], [0.0, 0.0, 0.0])
    np.testing.assert_array_equal(out[:, 1], keypoints[:, 1])
    np.testing.assert_allclose(out[:, 2], keypoints[:, 2])
    np.testing.assert_array_equal(out[..., 2], keypoints[..., 2])
