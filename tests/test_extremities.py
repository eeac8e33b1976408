"""Heels, big toes and knuckles: which layout point each is, foot phases on a synthetic walk, the
foot's and hand's direction from hand-made image points, a foot's roll levelled, the humanoid BVH's feet and
hands turning, and layouts without them giving exactly what they gave before."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, parse_bvh, read_bvh
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES, LAYOUTS, N_FEET_HANDS
from mocapdb.core.formats.keypoints import to_extremities
from mocapdb.core.formats.openpose import parse_openpose_json
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import (
    HAND_LENGTH_M,
    HEEL_TO_TOE_M,
    HEEL_TO_TOE_SLOPE_DEG,
    KP,
    N_RIG_JOINTS,
    RIG_JOINTS,
    global_rotations,
    pose_from_rotations,
)
from mocapdb.runtime.end_branches import BranchPath, continuous_directions
from mocapdb.runtime.end_joints import (
    END_PARENTS,
    END_REST_DIRECTIONS,
    levelled_feet,
    lift_candidates,
    measured_candidates,
    nearest_candidate,
    sign_references,
)
from mocapdb.runtime.foot_contacts import FLAT, HEEL_STRIKE, SWING, TOE_OFF, UNSEEN, foot_phases, planted_ankles
from mocapdb.runtime.take import end_rotations
from mocapdb.runtime.take_params import TakeParams

FPS = 30.0
MISSING = [np.nan, np.nan, 0.0]


@pytest.mark.parametrize("layout, expected", [
    ("body25", ("RHeel", "RBigToe", "LHeel", "LBigToe", None, None, None, None)),
    ("body25b", ("right_heel", "right_big_toe", "left_heel", "left_big_toe", None, None, None, None)),
    ("halpe26", ("right_heel", "right_big_toe", "left_heel", "left_big_toe", None, None, None, None)),
    ("wholebody133", ("right_heel", "right_big_toe", "left_heel", "left_big_toe",
                      "right_hand_5", "right_hand_17", "left_hand_5", "left_hand_17")),
    ("mediapipe33", ("right_heel", "right_foot_index", "left_heel", "left_foot_index",
                     "right_index", "right_pinky", "left_index", "left_pinky")),
])
def test_each_layout_gives_its_own_heels_toes_and_knuckles(layout, expected):
    names = LAYOUTS[layout]
    raw = np.column_stack([100.0 + np.arange(len(names)), 200.0 + np.arange(len(names)), np.full(len(names), 0.8)])
    raw[names.index(expected[0]), 2] = 0.0            # a point the detector missed
    got = to_extremities(raw[None], layout)[0]
    assert got.shape == (len(EXTREMITIES), 3)
    for row, name in zip(got, expected):
        if name is None or name == expected[0]:
            np.testing.assert_array_equal(row, MISSING)
        else:
            np.testing.assert_array_equal(row, [100.0 + names.index(name), 200.0 + names.index(name), 0.8])


@pytest.mark.parametrize("layout", ["coco17", "coco18"])
def test_layouts_without_feet_or_hands_give_only_face_points(layout):
    raw = np.ones((1, len(LAYOUTS[layout]), 3))
    got = to_extremities(raw, layout)[0]
    assert (got[:N_FEET_HANDS, 2] == 0).all() and (got[N_FEET_HANDS:N_FEET_HANDS + 4, 2] == 1).all()
    text = json.dumps({"people": [{"pose_keypoints_2d": (raw[0] * 500.0).ravel().tolist()}]})
    assert (parse_openpose_json(text, 0).people[0].extremities[:N_FEET_HANDS, 2] == 0).all()


def test_an_openpose_body25_person_carries_its_heels_and_toes():
    raw = np.zeros((25, 3))
    raw[:, :2] = np.arange(50.0).reshape(25, 2) + 300.0
    raw[:, 2] = 0.9
    person = parse_openpose_json(json.dumps({"people": [{"pose_keypoints_2d": raw.ravel().tolist()}]}), 0,
                                 layout="body25").people[0]
    np.testing.assert_array_equal(person.extremities[0], [*raw[24, :2], 0.9])   # RHeel
    np.testing.assert_array_equal(person.extremities[3], [*raw[19, :2], 0.9])   # LBigToe


def _walk() -> np.ndarray:
    """A right foot's heel and toe ``[110, 8, 3]`` (box 400 px, 30 fps): flat 0-19, heel rising
    20-39, in the air 40-59, heel down and toe coming down 60-79, flat from 80, the heel unseen
    from frame 100; the left foot flat throughout; no hand points."""
    n = 110
    heel_step = np.zeros((n, 2))
    toe_step = np.zeros((n, 2))
    heel_step[20:40] = [4.0, -6.0]      # toe-off: the heel lifts and moves on, 240 px/s
    heel_step[40:60] = [10.0, 0.0]      # swing
    toe_step[40:60] = [10.0, 0.0]
    toe_step[60:80] = [0.0, 6.0]        # heel strike: the toe comes down
    extremities = np.tile(np.array(MISSING), (n, 8, 1))
    extremities[:, 0] = np.column_stack([500.0 + np.cumsum(heel_step, axis=0), np.full(n, 0.9)])
    extremities[:, 0, 1] += 300.0
    extremities[:, 1] = np.column_stack([550.0 + np.cumsum(toe_step, axis=0), np.full(n, 0.9)])
    extremities[:, 1, 1] += 260.0
    extremities[:, 2] = [700.0, 800.0, 0.9]
    extremities[:, 3] = [750.0, 810.0, 0.9]
    extremities[100:, 0] = MISSING
    return extremities


def test_foot_phases_follow_a_synthetic_step():
    phases = foot_phases(_walk(), 400.0, FPS, TakeParams())
    for (start, stop), phase in zip([(0, 20), (20, 40), (40, 60), (60, 80), (80, 100)],
                                    [FLAT, TOE_OFF, SWING, HEEL_STRIKE, FLAT]):
        assert (phases[start + 6:stop - 6, 0] == phase).all(), (start, phases[start:stop, 0].tolist())
    assert (phases[103:, 0] == UNSEEN).all()    # no heel in the 5-frame median: not seen
    assert (phases[:, 1] == FLAT).all()


def test_a_flat_foot_carries_the_body_while_the_other_is_off_the_floor():
    """Heights decide between two flat feet, not when the other foot is in the air: the flat foot
    is planted even where the estimated pose puts it higher (a wrong leg pose)."""
    n = 40
    keypoints = np.zeros((n, 14, 3))
    keypoints[:, :, 1] = np.linspace(300.0, 700.0, 14)
    keypoints[:, :, 0] = 900.0
    keypoints[:, :, 2] = 0.9
    ankles = np.zeros((n, 2, 3))
    ankles[:, 0, 1] = 0.10                       # the right ankle 10 cm above the left
    up = np.array([0.0, 1.0, 0.0])
    params = TakeParams()
    swinging_left = np.tile([FLAT, SWING], (n, 1))
    planted = planted_ankles(keypoints, ankles, up, FPS, params, swinging_left)
    assert planted[:, 0].all() and not planted[:, 1].any()
    both_flat = np.full((n, 2), FLAT)
    planted = planted_ankles(keypoints, ankles, up, FPS, params, both_flat)
    assert not planted[:, 0].any() and planted[:, 1].all()
    unseen = np.full((n, 2), UNSEEN)             # no heel or toe: the ankles' own test
    np.testing.assert_array_equal(planted_ankles(keypoints, ankles, up, FPS, params, unseen),
                                  planted_ankles(keypoints, ankles, up, FPS, params))


@pytest.mark.parametrize("drift_box_per_s, other, planted_expected", [
    (0.35, SWING, True),          # under the body's weight, drifting: it carries the body
    (0.60, SWING, False),         # faster than carrying_box_per_s (0.5): it moves
    (0.35, TOE_OFF, False),       # the other foot partly on the floor: no carrier is needed
])
def test_the_lower_slower_foot_carries_the_body_while_the_other_swings(drift_box_per_s, other, planted_expected):
    """The right foot is the lower one; its ankle drifts right at ``drift_box_per_s`` box heights a
    second (box 400 px) and its heel and toe are seen moving (phase SWING: not flat); the left
    ankle sweeps at 2 box heights a second, 10 cm higher, its foot in phase ``other``."""
    n = 40
    t = np.arange(n) / FPS
    keypoints = np.zeros((n, 14, 3))
    keypoints[:, :, 1] = np.linspace(300.0, 700.0, 14)   # a box 400 px tall
    keypoints[:, :, 0] = 900.0
    keypoints[:, :, 2] = 0.9
    keypoints[:, KP["r_ankle"], 0] += 400.0 * drift_box_per_s * t
    keypoints[:, KP["l_ankle"], 0] += 400.0 * 2.0 * t
    ankles = np.zeros((n, 2, 3))
    ankles[:, 1, 1] = 0.10
    phases = np.tile([SWING, other], (n, 1))
    inner = slice(8, -8)   # the speeds' line fits reach past the ends (edges held: slower there)
    planted = planted_ankles(keypoints, ankles, np.array([0.0, 1.0, 0.0]), FPS, TakeParams(), phases)[inner]
    assert planted[:, 0].all() == planted_expected and planted[:, 0].any() == planted_expected
    assert not planted[:, 1].any()
    # without heels and toes, the ankles' own test alone: 0.35 box heights a second is not still
    assert not planted_ankles(keypoints, ankles, np.array([0.0, 1.0, 0.0]), FPS, TakeParams())[inner, 0].any()


CAMERA = (1000.0, 960.0, 540.0)   # focal, cx, cy (pixels)


def _pixel(view_m: np.ndarray) -> np.ndarray:
    """The pixel ``[..., 2]`` of view-frame points ``[..., 3]`` (x right, y up, z towards the camera) under CAMERA."""
    focal, cx, cy = CAMERA
    return np.stack([cx + focal * view_m[..., 0] / -view_m[..., 2], cy - focal * view_m[..., 1] / -view_m[..., 2]],
                    axis=-1)


def test_lifting_inverts_the_perspective():
    """A 0.25 m segment from a point 4 m in front of the camera, 0.6 across and 0.8 along the view (towards
    or away from the camera, on and off the optical axis): the image gives it and its mirror about the ray
    through its end, farther first; the reference picks it."""
    length = np.array(0.25)
    for start in (np.array([0.0, 0.0, -4.0]), np.array([0.7, -1.2, -4.0])):
        depth = np.array(-start[2])
        for direction in ([0.6, 0.0, 0.8], [0.6, 0.0, -0.8], [0.0, -0.6, 0.8]):
            direction = np.array(direction)
            candidates = lift_candidates(_pixel(start), _pixel(start + length * direction), depth, length, CAMERA)
            towards = np.sign(direction[2]) * np.array([0.1, 0.0, 1.0])
            np.testing.assert_allclose(nearest_candidate(candidates, towards), direction, atol=1e-12)
            np.testing.assert_allclose(candidates[0 if direction[2] < 0 else 1], direction, atol=1e-12)
            np.testing.assert_allclose(np.linalg.norm(candidates, axis=-1), 1.0)
    # an image longer than the length: the ray's point nearest the start, across the view, both ways
    got = lift_candidates(_pixel(np.array([0.0, 0.0, -4.0])), _pixel(np.array([0.0, -0.5, -4.0])), np.array(4.0),
                          np.array(0.25), CAMERA)
    np.testing.assert_allclose(got[0], got[1])
    assert np.degrees(np.arccos(-got[0, 1])) < 7.2   # the ray 7.1 deg off the start's: its nearest point


def test_the_depth_follows_the_path_not_each_frame_alone():
    """A foot turning slowly 55 -> 65 deg from the camera's axis, its mirror image about the view ray the other
    depth; the prior (the pelvis's forward) faces the camera but every fifth frame is misread as 150 deg: one
    frame at a time those frames take the mirror image, the path never does (whole take and online); a path
    started on misread frames leaves the mirror image for good once the prior is right."""
    fps, n = 24.0, 40
    heading = np.radians(np.linspace(55.0, 65.0, n))
    truth = np.stack([np.sin(heading), np.full(n, -0.2), np.cos(heading)], axis=-1)
    truth /= np.linalg.norm(truth, axis=-1, keepdims=True)
    mirror = truth * [1.0, 1.0, -1.0]                                  # about the ray along the optical axis
    candidates = np.stack([mirror, truth], axis=1)[:, None]            # [F, 1, 2, 3]: farther, nearer
    misread = np.arange(n) % 5 == 2
    facing = np.radians(np.where(misread, 150.0, 0.0))
    prior = np.stack([np.sin(facing), np.zeros(n), np.cos(facing)], axis=-1)[:, None]
    single = nearest_candidate(candidates, prior)[:, 0]
    np.testing.assert_allclose(single[misread], mirror[misread], atol=1e-12)
    np.testing.assert_allclose(continuous_directions(candidates, prior, fps)[:, 0], truth, atol=1e-12)
    online = BranchPath(1)
    steps = np.array([online.step(f / fps, candidates[f], prior[f])[0][0] for f in range(n)])
    np.testing.assert_allclose(steps, truth, atol=1e-12)
    late = BranchPath(1)
    start = np.where(np.arange(n) < 3, np.pi * 150.0 / 180.0, 0.0)
    prior = np.stack([np.sin(start), np.zeros(n), np.cos(start)], axis=-1)[:, None]
    picks = [np.allclose(late.step(f / fps, candidates[f], prior[f])[0][0], truth[f]) for f in range(n)]
    assert not picks[0] and picks[-1] and all(picks[picks.index(True):])


def test_a_foot_is_lifted_on_the_side_the_pelvis_faces_not_the_knee():
    """The right thigh turned in by 120 deg (its knee, and the foot's rest direction with it, faces away from the
    camera) under a pelvis facing the camera: a foot seen pointing 30 deg to the side is lifted towards the
    camera, where the hips face, exactly (the perspective inverted)."""
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (1, N_RIG_JOINTS, 1))
    turn = np.radians(120.0) / 2
    quats[0, RIG_JOINTS.index("r_hip")] = [np.cos(turn), 0.0, np.sin(turn), 0.0]
    root = np.array([[0.2, 0.1, -4.0]])
    ankle = pose_from_rotations(quats, root)[0, KP["r_ankle"]]
    foot = np.array([np.sin(np.radians(30.0)), -0.2, np.cos(np.radians(30.0))])
    foot /= np.linalg.norm(foot)
    keypoints = np.zeros((1, 14, 3))
    extremities = np.tile(np.array(MISSING), (1, 8, 1))
    extremities[0, 0] = [*_pixel(ankle), 0.9]
    extremities[0, 1] = [*_pixel(ankle + HEEL_TO_TOE_M * foot), 0.9]
    got = nearest_candidate(measured_candidates(quats, root, 1.0, None, keypoints, extremities, CAMERA),
                            sign_references(quats))[0]
    np.testing.assert_allclose(got[0], foot, atol=1e-9)
    assert np.isnan(got[1:]).all()


def _directions(quats: np.ndarray, end_quats: np.ndarray) -> np.ndarray:
    """The feet's and hands' directions ``[F, 4, 3]`` (view frame) of a pose with end rotations."""
    parents = global_rotations(quats)[:, [RIG_JOINTS.index(j) for j in END_PARENTS]]
    return np.einsum("fkij,kj->fki", parents @ quat_to_matrix(end_quats), END_REST_DIRECTIONS)


def test_end_rotations_turn_feet_and_hands_to_the_image_points():
    """A T-pose 4 m in front of the camera facing it: the right foot's heel → toe image is that of
    a foot turned 30° to the subject's left and pitched 20° up, the right hand's knuckles those of a
    hand bent 30° down; the left foot and hand are not seen and do not turn. Planted, the right foot
    keeps its yaw and stands flat (sloping as a standing foot's keypoints do)."""
    n, focal = 3, 1000.0
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, N_RIG_JOINTS, 1))
    root = np.tile([0.0, 0.0, -4.0], (n, 1))
    yaw, pitch = np.radians(30.0), np.radians(20.0)
    foot = np.array([np.cos(pitch) * np.sin(yaw), np.sin(pitch), np.cos(pitch) * np.cos(yaw)])
    hand = np.array([-np.cos(np.radians(30.0)), -np.sin(np.radians(30.0)), 0.0])
    # the segments from points on the heel's and wrist's pixels at the joints' depth (4 m, the T-pose's),
    # projected exactly
    heel, wrist = (np.array([(x - CAMERA[1]) * 4.0 / focal, (CAMERA[2] - y) * 4.0 / focal, -4.0])
                   for x, y in ((420.0, 900.0), (300.0, 500.0)))
    keypoints = np.zeros((n, 14, 3))
    keypoints[:, KP["r_wrist"]] = [300.0, 500.0, 0.9]
    extremities = np.tile(np.array(MISSING), (n, 8, 1))
    extremities[:, 0] = [420.0, 900.0, 0.9]                                 # right heel
    extremities[:, 1, :2] = _pixel(heel + HEEL_TO_TOE_M * foot)             # right big toe
    knuckles = _pixel(wrist + HAND_LENGTH_M * hand)
    extremities[:, 4, :2] = knuckles + [0.0, 5.0]                           # right index knuckle
    extremities[:, 5, :2] = knuckles - [0.0, 5.0]                           # right pinky knuckle
    extremities[:, [1, 4, 5], 2] = 0.9
    params, up = TakeParams(smoothing_hz=0.0), np.array([0.0, 1.0, 0.0])
    not_planted = np.zeros((n, 2), dtype=bool)
    end_quats = end_rotations(quats, root, 1.0, None, keypoints, extremities, CAMERA, not_planted, up, FPS, params)
    got = _directions(quats, end_quats)
    np.testing.assert_allclose(got[:, 0], np.broadcast_to(foot, (n, 3)), atol=1e-9)
    np.testing.assert_allclose(got[:, 2], np.broadcast_to(hand, (n, 3)), atol=1e-9)
    np.testing.assert_allclose(end_quats[:, [1, 3]], np.broadcast_to([1.0, 0, 0, 0], (n, 2, 4)), atol=1e-12)
    planted = not_planted.copy()
    planted[:, 0] = True
    flat = _directions(quats, end_rotations(quats, root, 1.0, None, keypoints, extremities, CAMERA, planted, up,
                                            FPS, params))[:, 0]
    slope = np.radians(HEEL_TO_TOE_SLOPE_DEG)
    standing = [np.cos(slope) * np.sin(yaw), -np.sin(slope), np.cos(slope) * np.cos(yaw)]
    np.testing.assert_allclose(flat, np.broadcast_to(standing, (n, 3)), atol=1e-9)


def test_the_humanoid_bvh_turns_its_feet_and_hands_and_nothing_else():
    n = 4
    rng = np.random.default_rng(3)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, N_RIG_JOINTS, 1))
    root = rng.normal(size=(n, 3))
    angle = np.radians(30.0)
    end_quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, 5, 1))
    end_quats[:, 0] = [np.cos(angle / 2), 0.0, np.sin(angle / 2), 0.0]     # right foot: 30° about up
    end_quats[:, 3] = [np.cos(angle / 2), 0.0, 0.0, -np.sin(angle / 2)]    # left hand: 30° down
    still = parse_bvh(format_bvh(motion_bvh(Motion(quats, root, FPS), rig="humanoid")))
    turned = parse_bvh(format_bvh(motion_bvh(Motion(quats, root, FPS, end_rotations=end_quats), rig="humanoid")))
    p_still, p_turned = forward_kinematics(still)[0], forward_kinematics(turned)[0]
    moved = np.flatnonzero(np.abs(p_turned - p_still).max(axis=(0, 2)) > 1e-6)
    left_fingers = [n for n in turned.names if n.startswith("LeftHand") and n != "LeftHand"]
    assert sorted(turned.names[j] for j in moved) == sorted(left_fingers + ["RightToeBase", "RightToeBase_End"])

    def bone(positions: np.ndarray, child: str, parent: str) -> np.ndarray:
        return positions[:, turned.index(child)] - positions[:, turned.index(parent)]

    c, s = np.cos(angle), np.sin(angle)
    yaw = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    np.testing.assert_allclose(bone(p_turned, "RightToeBase", "RightFoot"),
                               bone(p_still, "RightToeBase", "RightFoot") @ yaw.T, atol=1e-5)
    hand = bone(p_turned, "LeftHandMiddle1", "LeftHand")[0]
    hand -= bone(p_still, "LeftHandMiddle1", "LeftHand")[0][2] * np.array([0.0, 0.0, 1.0])   # along the hand
    assert np.degrees(np.arctan2(-hand[1], hand[0])) == pytest.approx(30.0, abs=1e-3)


def _write_folder(folder, frames: list[list[np.ndarray]]) -> None:
    folder.mkdir()
    for i, people in enumerate(frames):
        body = {"people": [{"pose_keypoints_2d": p.ravel().tolist()} for p in people]}
        (folder / f"f{i:04d}.json").write_text(json.dumps(body))


def test_without_heels_and_toes_a_reconstruction_is_what_it_was(small_db_path, tmp_path):
    """The bundled BODY_25B take cut to its first 17 points (COCO-17: the same 14 keypoints, no feet)
    and with its feet points removed give the same files to the byte; with its feet, the per-frame
    stream is the same and the humanoid rig's feet turn."""
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    frames = [[np.asarray(p["pose_keypoints_2d"], dtype=np.float64).reshape(-1, 3)
               for p in json.loads(path.read_text())["people"] if p["pose_keypoints_2d"]]
              for path in sorted(SAMPLE_KEYPOINTS.glob("cam01.*.json"))]
    no_feet = [[np.where(np.arange(25)[:, None] >= 19, 0.0, p) for p in people] for people in frames]
    _write_folder(tmp_path / "coco17", [[p[:17] for p in people] for people in frames])
    _write_folder(tmp_path / "no_feet", no_feet)
    _write_folder(tmp_path / "feet", frames)
    common = ["--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920", "--focal", "1681",
              "--rig", "humanoid", "--format", "bvh,csv", "--per-frame-stream"]  # the online take reads the feet
    for name, layout in (("coco17", "coco17"), ("no_feet", "body25b"), ("feet", "body25b")):
        assert main(["reconstruct", str(tmp_path / name), "--keypoints", layout, "--out", str(tmp_path / f"out_{name}"),
                     *common]) == 0
    out = {name: tmp_path / f"out_{name}" for name in ("coco17", "no_feet", "feet")}
    files = sorted(p.name for p in out["coco17"].iterdir())
    assert files == sorted(p.name for p in out["no_feet"].iterdir())
    for name in files:
        assert (out["coco17"] / name).read_bytes() == (out["no_feet"] / name).read_bytes(), name
    assert (out["coco17"] / "result.jsonl").read_bytes() == (out["feet"] / "result.jsonl").read_bytes()
    track = next(name for name in files if name.endswith(".bvh"))
    for name, turning in (("coco17", False), ("feet", True)):
        bvh = read_bvh(out[name] / track)
        rotations = forward_kinematics(bvh)[1]
        foot, leg = bvh.index("RightFoot"), bvh.index("RightLeg")
        local = np.swapaxes(rotations[:, leg], -1, -2) @ rotations[:, foot]
        angle = np.degrees(np.arccos(np.clip((np.trace(local, axis1=-2, axis2=-1) - 1) / 2, -1, 1)))
        assert (angle.max() > 10.0) if turning else (angle.max() < 1e-3), (name, angle.max())  # text precision


def test_a_foot_is_rolled_about_its_direction_until_its_lateral_axis_is_level():
    """Random shanks and feet (SciPy's rotations), up tilted: each foot keeps its heel → toe, its lateral axis
    (the humanoid foot's x) ends perpendicular to up on the nearer side (the smaller roll); a foot rolled 20 deg
    about its own heel → toe on an unturned shank comes back to rest; one along up is not rolled; hands as given."""
    n = 200
    up = np.array([0.1, 0.95, -0.2]) / np.linalg.norm([0.1, 0.95, -0.2])
    parents = Rotation.random(n * 4, random_state=5).as_matrix().reshape(n, 4, 3, 3)
    locals_ = Rotation.random(n * 4, random_state=6).as_quat()[:, [3, 0, 1, 2]].reshape(n, 4, 4)
    got = levelled_feet(parents, locals_, up)
    before = parents @ quat_to_matrix(locals_)
    after = parents @ quat_to_matrix(got)
    d0 = END_REST_DIRECTIONS[0]
    np.testing.assert_allclose(after[:, :2] @ d0, before[:, :2] @ d0, atol=1e-12)
    off_vertical = np.linalg.norm(np.cross(up, after[:, :2] @ d0), axis=-1) >= 0.5
    assert np.abs(after[:, :2, :, 0] @ up)[off_vertical].max() < 1e-12
    assert (np.sum(after[:, :2, :, 0] * before[:, :2, :, 0], axis=-1) >= 0).all()
    np.testing.assert_array_equal(got[:, 2:], locals_[:, 2:])
    rolled = Rotation.from_rotvec(np.radians(20.0) * d0).as_quat()[[3, 0, 1, 2]]
    rest = levelled_feet(np.tile(np.eye(3), (1, 4, 1, 1)), np.tile(rolled, (1, 4, 1)), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(np.abs(rest[0, :2, 0]), 1.0, atol=1e-12)
    upright = Rotation.align_vectors([up], [d0])[0].as_quat()[[3, 0, 1, 2]]
    along = np.tile(upright, (1, 4, 1))
    np.testing.assert_allclose(levelled_feet(np.tile(np.eye(3), (1, 4, 1, 1)), along, up), along, atol=1e-12)
