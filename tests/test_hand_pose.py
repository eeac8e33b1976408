"""Fingers and the palm in the whole take: finger rotations of a hand built in closed form against scipy's
rotations, the palm's full rotation, MediaPipe's gestures through the humanoid BVH's forward kinematics,
an absent hand eased to rest without a jump, and the humanoid file with moving fingers read back as the
build reads it."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.fingers import FINGERS, curl_deg, finger_chain, flexion_deg
from mocapdb.core.formats.bvh import parse_bvh, write_bvh
from mocapdb.core.hand_rig import ANGLE_LIMITS_DEG, FINGER_JOINTS, FINGER_NAMES, RELAXED_DEG, SIDE_NAMES
from mocapdb.core.joint_map import detect_mapping
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import (
    HAND_LENGTH_M,
    KP,
    N_RIG_JOINTS,
    PELVIS,
    pose_from_rotations,
    rest_positions_m,
    retarget,
)
from mocapdb.evaluation.gestures import CURLED_DEG, STRAIGHT_DEG, classify
from mocapdb.evaluation.hand_bvh import bvh_hand_points, side_of
from mocapdb.runtime.end_joints import KNUCKLE_SLANT, KNUCKLES_APART_M, knuckle_thumb_sides
from mocapdb.runtime.foot_contacts import INDEX_KNUCKLES, PINKY_KNUCKLES
from mocapdb.runtime.hand_pose import (
    EASE_S,
    finger_angles_deg,
    finger_quaternions,
    finger_rotations,
    hand_points_view,
    palm_frames,
    steadiness,
)
from mocapdb.runtime.take import end_rotations
from mocapdb.runtime.take_params import TakeParams

from .test_fingers import SAMPLE_HANDS, _hand_model, _pose_models

FPS = 30.0
# The four fingers' knuckles on a left hand at rest (rig axes: +x along the hand, +z the thumb's side)
KNUCKLES_M = np.array([[0.084, 0.0, 0.026], [0.084, 0.0, 0.008], [0.076, 0.0, -0.009], [0.067, 0.0, -0.026]])
BONES_M = np.array([0.045, 0.027, 0.02])


def _rotation_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle (degrees) between quaternions ``a`` and ``b`` ``[..., 4]`` (w, x, y, z)."""
    return np.degrees(2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0)))


def _scipy(rotation: Rotation) -> np.ndarray:
    return np.roll(rotation.as_quat(), 1, axis=-1)      # scipy's (x, y, z, w) → (w, x, y, z)


def _closed_form_hand(side: str, hand: Rotation, angles_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A hand's 21 points (view frame) turned by ``hand`` with the four fingers' ``angles_deg [4, 5]`` (spread
    towards the thumb, flexions towards the palm), and each finger joint's local rotation (scipy): on the left
    hand flexion turns +x towards −y (about −z) and spread towards +z (about −y); the right hand's mirror image
    (x negated) turns about +z and +y."""
    mirror = np.array([-1.0, 1.0, 1.0]) if side == "Right" else np.ones(3)
    sign = 1.0 if side == "Right" else -1.0
    points = np.full((21, 3), np.nan)
    points[0] = 0.0
    points[1:5] = hand.apply(mirror * np.array([[0.02, -0.01, 0.02], [0.05, -0.02, 0.04], [0.07, -0.03, 0.05],
                                                [0.09, -0.03, 0.06]]))            # the thumb: only placed
    expected = np.zeros((4, 3, 4))
    for f, (spread, flex1, _, *flexes) in enumerate(angles_deg):
        chain = finger_chain(FINGERS[f + 1])
        left_turn = Rotation.from_euler("y", -spread, degrees=True)     # the geometry: a left hand, mirrored
        position = mirror * KNUCKLES_M[f]
        points[chain[1]] = hand.apply(position)
        bent = 0.0
        for k, flex in enumerate([flex1, *flexes]):
            bent += flex
            position = position + mirror * (left_turn * Rotation.from_euler("z", -bent, degrees=True)).apply(
                [BONES_M[k], 0.0, 0.0])
            points[chain[k + 2]] = hand.apply(position)
            joint = Rotation.from_euler("z", sign * flex, degrees=True)
            expected[f, k] = _scipy(Rotation.from_euler("y", sign * spread, degrees=True) * joint if k == 0 else joint)
    return points, expected


def _measured(points: np.ndarray) -> np.ndarray:
    """``[F, 30, 4]`` finger rotations of hands ``[F, 2, 21, 3]`` already in the view frame."""
    return finger_quaternions(finger_angles_deg(points, palm_frames(points)))


def test_finger_rotations_of_a_hand_built_in_closed_form():
    rng = np.random.default_rng(4)
    for side in SIDE_NAMES:
        hand = Rotation.random(random_state=7)
        angles = np.column_stack([rng.uniform(-20, 20, 4), rng.uniform(-20, 55, 4), np.zeros(4), rng.uniform(0, 100, 4),
                                  rng.uniform(0, 80, 4)])
        points, expected = _closed_form_hand(side, hand, angles)
        both = np.full((1, 2, 21, 3), np.nan)
        both[0, SIDE_NAMES.index(side)] = points
        rows = [FINGER_JOINTS.index(f"{side}Hand{name}{k}") for name in FINGER_NAMES[1:] for k in (1, 2, 3)]
        assert _rotation_deg(_measured(both)[0, rows], expected.reshape(12, 4)).max() < 1e-4, side   # arccos noise
        basis = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]) * (np.array([-1.0, 1, 1]) if side == "Right" else 1)
        np.testing.assert_allclose(palm_frames(both)[0, SIDE_NAMES.index(side)], (hand.as_matrix() @ basis.T).T,
                                   atol=1e-9)                      # u, t, n: the rest basis turned by the hand


def test_the_hand_turns_fully_with_its_palm():
    """A left hand's palm turned by a known rotation (its twist about the hand within the forearm's range):
    the whole take's hand rotation is that rotation (the arm at rest: its local rotation is the global); a
    palm twisted 150° (beyond the forearm's reach: misread) is not used, the hand keeps its shortest turn."""
    n = 12
    for hand, expected in ((Rotation.from_euler("zyx", [25.0, -30.0, 60.0], degrees=True), None),
                           (Rotation.from_euler("x", 150.0, degrees=True), Rotation.identity())):
        points = np.full((n, 2, 21, 3), np.nan)
        points[:, 1] = _closed_form_hand("Left", hand, np.zeros((4, 5)))[0]
        quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, N_RIG_JOINTS, 1))
        local = end_rotations(quats, np.tile([0.0, 0.0, -3.0], (n, 1)), 1.0, None, np.zeros((n, 14, 3)),
                              np.zeros((n, 8, 3)), (1000.0, 960.0, 540.0), np.zeros((n, 2), bool),
                              np.array([0.0, 1.0, 0.0]), FPS, TakeParams(), palm_frames(points))
        assert _rotation_deg(local[:, 3], _scipy(hand if expected is None else expected)).max() < 1e-4
        np.testing.assert_allclose(local[:, 2], np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), atol=1e-12)   # never seen


def test_the_hand_twists_to_the_pose_knuckles():
    """Without the hand model: a hand turned by a known rotation (within the forearm's range) seen as BlazePose
    sees it, its wrist and its index and little-finger knuckles (their line slanted as the rig's) in exact
    pixels: the whole take's hand rotation is that rotation, its twist about the hand included (the arm at
    rest: the local rotation is the global); the other hand, never seen, keeps its rest."""
    n, camera = 12, (1000.0, 960.0, 540.0)
    hand = Rotation.from_euler("zyx", [30.0, 20.0, 45.0], degrees=True)
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (n, N_RIG_JOINTS, 1))
    root = np.tile([0.0, 0.0, -3.0], (n, 1))
    wrist = pose_from_rotations(quats[:1], root[:1], 1.0, None)[0, KP["l_wrist"]]
    along, thumb_side = hand.apply([1.0, 0.0, 0.0]), hand.apply([0.0, 0.0, 1.0])   # the left hand's u, t at rest
    middle = wrist + HAND_LENGTH_M * along
    half = 0.5 * KNUCKLES_APART_M * (KNUCKLE_SLANT * along + thumb_side)

    def pixel(point: np.ndarray) -> np.ndarray:
        return [camera[1] + camera[0] * point[0] / -point[2], camera[2] - camera[0] * point[1] / -point[2], 1.0]

    keypoints, extremities = np.zeros((n, 14, 3)), np.zeros((n, 8, 3))
    keypoints[:, KP["l_wrist"]] = pixel(wrist)
    extremities[:, INDEX_KNUCKLES[1]], extremities[:, PINKY_KNUCKLES[1]] = pixel(middle + half), pixel(middle - half)
    local = end_rotations(quats, root, 1.0, None, keypoints, extremities, camera, np.zeros((n, 2), bool),
                          np.array([0.0, 1.0, 0.0]), FPS, TakeParams())
    swing = Rotation.align_vectors([along], [[1.0, 0.0, 0.0]])[0]   # the shortest turn: 40° from the truth
    assert _rotation_deg(_scipy(swing), _scipy(hand)) > 30.0
    # within 1°: the engine lifts the knuckles' mid-point in the image, not the image of their mid-point (0.6° here)
    assert _rotation_deg(local[:, 3], _scipy(hand)).max() < 1.0
    np.testing.assert_allclose(local[:, 2], np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), atol=1e-12)


def test_the_knuckles_thumb_side_is_exact_in_perspective():
    """200 hands at random turns 2–4 m away, their knuckles' line slanted as the rig's, projected by a pinhole:
    the thumb side the pose's knuckles give is the true one (to 1e-5°), of its two, wherever the palm is not
    seen from its edge (the knuckles closer than 0.4 of their width in the image: NaN, and not most hands)."""
    rng, camera = np.random.default_rng(7), (1000.0, 640.0, 360.0)
    errors, edge_on = [], 0
    for rotation in Rotation.random(200, random_state=rng):
        wrist = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), -rng.uniform(2.0, 4.0)])
        along, thumb_side = rotation.apply([1.0, 0.0, 0.0]), rotation.apply([0.0, 1.0, 0.0])
        half = 0.5 * KNUCKLES_APART_M * (KNUCKLE_SLANT * along + thumb_side)
        extremities = np.zeros((1, 8, 3))
        for index, pinky in zip(INDEX_KNUCKLES, PINKY_KNUCKLES):
            middle = wrist + HAND_LENGTH_M * along
            for row, point in ((index, middle + half), (pinky, middle - half)):
                extremities[0, row] = [camera[1] + camera[0] * point[0] / -point[2],
                                       camera[2] - camera[0] * point[1] / -point[2], 1.0]
        untwisted = np.array([[rotation.apply([0.0, 1.0, 0.0])] * 2])   # the true twist: none from here
        sides = knuckle_thumb_sides(np.array([[along, along]]), extremities, camera, np.array([[-wrist[2]] * 2]), 1.0,
                                    untwisted)
        if np.isnan(sides).all():
            edge_on += 1
            continue
        errors.append(np.degrees(np.arccos(np.clip(sides[0] @ thumb_side, -1.0, 1.0))))
    assert 0 < edge_on < 40 and np.max(errors) < 1e-5


def test_a_scattered_knuckle_twist_is_not_used():
    """The knuckles' twist is kept whole when it scatters up to 8° a frame, none from 16°, linearly between
    (the scatter: 1.4826 × the median absolute second difference / √6; an alternating ±a has second
    differences ±4a, so a scatter of 1.4826 × 4a / √6), and not at all on fewer than 8 frames measured (the
    frames unmeasured, NaN, left out)."""
    t = np.arange(40)
    for scatter, kept in ((0.0, 1.0), (8.0, 1.0), (12.0, 0.5), (16.0, 0.0), (30.0, 0.0)):
        a = scatter * np.sqrt(6.0) / (4.0 * 1.4826)
        assert steadiness(20.0 + a * (-1.0) ** t) == pytest.approx(kept, abs=1e-9)
    assert steadiness(np.full(40, np.nan)) == 0.0
    few = np.full(40, np.nan)
    few[::5] = 10.0
    assert steadiness(few) == 1.0 and steadiness(few[:35]) == 0.0


def _gesture_hands() -> list[tuple[str, str, np.ndarray]]:
    """(gesture, side, points [21, 3] image convention) of MediaPipe's fist landmarks and one photo of each
    other gesture (data/sample_hands); the photos need the models."""
    from mocapdb.evaluation.gestures import photo_hands

    fist = np.array(json.loads((SAMPLE_HANDS / "mediapipe_world_landmarks.json").read_text())["hands"]["fist"])
    found = [("fist", side_of(fist), fist)]
    for photo in ("pointing_1.jpg", "open_palm_1.jpg", "thumb_down_1.jpg", "thumb_up_1.jpg"):
        gesture = photo.rsplit("_", 1)[0]
        for label, points, _ in photo_hands(cv2.imread(str(SAMPLE_HANDS / photo)), _pose_models(), _hand_model()):
            if classify(points) == gesture:
                side = "Right" if label.endswith("right") else "Left" if label.endswith("left") else side_of(points)
                found.append((gesture, side, points))
                break
    return found


def test_gestures_through_the_bvh_forward_kinematics():
    """MediaPipe's gestures: the humanoid BVH's fingers, forward kinematics from the measured rotations, show
    the same gesture, each finger curled or straight as measured; the second and third joints' flexion (the
    thumb's MCP and IP, the fingers' PIP and DIP) within a median 5° of the points' (within the limits: blurred
    photos' curled fingers bend PIPs to 150-176°), within 10° on MediaPipe's own fist."""
    hands = _gesture_hands()
    assert [g for g, _, _ in hands] == ["fist", "pointing", "open_palm", "thumb_down", "thumb_up"]
    errors = []
    for gesture, side, points in hands:
        rebuilt = bvh_hand_points(side, points)
        assert classify(rebuilt) == gesture, (gesture, side)
        measured, fk = curl_deg(flexion_deg(points))[1:], curl_deg(flexion_deg(rebuilt))[1:]
        for a, b in zip(measured, fk):
            assert (a < STRAIGHT_DEG) == (b < STRAIGHT_DEG) and (a > CURLED_DEG) == (b > CURLED_DEG), gesture
        joints = [3, 4]                                             # ANGLES: the second and third bones' flexion
        within = np.clip(flexion_deg(points)[:, 1:], ANGLE_LIMITS_DEG[:, joints, 0], ANGLE_LIMITS_DEG[:, joints, 1])
        errors.append(np.abs(within - flexion_deg(rebuilt)[:, 1:]))
    assert errors[0].max() < 10.0 and np.median(errors) < 5.0


def test_an_absent_hand_eases_to_rest_without_a_jump():
    """A left fist seen for 1 s, gone 2 s, seen 0.2 s, gone 0.3 s (bridged), seen 1 s; the right hand never:
    the right hand relaxed throughout, the left relaxed in the long gap's middle, the short gap interpolated,
    no joint turning more a frame than the ease allows (1.5 × its change over the ease's frames)."""
    n = int(4.5 * FPS)
    seen = np.zeros(n, bool)
    for start_s, stop_s in ((0.0, 1.0), (3.0, 3.2), (3.5, 4.5)):
        seen[int(start_s * FPS):int(stop_s * FPS)] = True
    fist = np.tile([0.0, 60.0, 0.0, 90.0, 50.0], (4, 1))
    left = _closed_form_hand("Left", Rotation.from_euler("x", 20.0, degrees=True), fist)[0]
    points = np.full((n, 2, 21, 3), np.nan)
    points[seen, 1] = left
    quats = finger_rotations(points, palm_frames(points), FPS, TakeParams())
    relaxed = finger_quaternions(np.broadcast_to(RELAXED_DEG, (1, 2, 5, 5)))[0]
    assert _rotation_deg(quats[:, :15], relaxed[:15]).max() < 1e-4                 # never seen: relaxed
    assert _rotation_deg(quats[int(2.0 * FPS), 15:], relaxed[15:]).max() < 1e-3     # the long gap: at rest
    measured = _measured(points[:1])[0, 15:]
    assert _rotation_deg(quats[int(3.35 * FPS), 15:], measured).max() < 1.0         # the short gap: bridged
    step = _rotation_deg(quats[1:], quats[:-1]).max()
    largest_change = _rotation_deg(measured, relaxed[15:]).max()
    assert 0 < step <= 1.5 * largest_change / (EASE_S * FPS)


def test_the_humanoid_file_with_moving_fingers_reads_back_as_without(tmp_path):
    """`mocapdb build` reads a humanoid BVH as a Mixamo rig: its finger joints moving changes nothing it reads."""
    rng = np.random.default_rng(2)
    quats, pos = retarget(rest_positions_m() + rng.normal(scale=0.04, size=(30, 15, 3)) + [0.0, 1.0, 0.0])
    fingers = finger_quaternions(rng.uniform(0.0, 60.0, size=(30, 2, 5, 5)))
    clips = {}
    for name, turned in (("still", None), ("fingers", fingers)):
        path = tmp_path / f"{name}.bvh"
        write_bvh(path, motion_bvh(Motion(quats, pos[:, PELVIS], FPS, finger_rotations=turned), "cm", "humanoid"))
        assert detect_mapping(parse_bvh(path.read_text())).convention == "motionbuilder_mixamo"
        clips[name] = process_clip(path, tmp_path, ClipOptions(fps=FPS)).positions
    np.testing.assert_array_equal(clips["still"], clips["fingers"])


def test_the_hands_travel_from_the_frames_to_the_take(small_db):
    """Person.hands through the engine (keep_take) into the track's recording (hands_px, NaN where absent) and
    the whole take: the left fist's fingers turn in the BVH as measured, the right hand never seen stays
    relaxed; hands_seen flags the measured frames."""
    from mocapdb.core.formats.keypoints import KeypointFrame, Person
    from mocapdb.runtime.engine import Engine
    from mocapdb.runtime.engine_config import EngineConfig
    from mocapdb.runtime.take import fit_take

    first, n = small_db.clip_first_frame[0], small_db.clip_n_frames[0]
    world = small_db.positions[first:first + n].astype(np.float64) - [0.0, 1.0, 4.0]
    body = np.stack([960 + 1000 * world[..., 0] / -world[..., 2], 540 - 1000 * world[..., 1] / -world[..., 2]],
                    axis=-1)[:, :14]
    fist = np.tile([0.0, 60.0, 0.0, 90.0, 50.0], (4, 1))
    left = _closed_form_hand("Left", Rotation.from_euler("x", 20.0, degrees=True), fist)[0]
    hands = np.zeros((2, 21, 4))
    hands[1, :, :3] = left * 1000.0 * [1.0, -1.0, -1.0] + [1200.0, 500.0, 0.0]      # image px, z px
    hands[1, :, 3] = 0.9
    seen = np.arange(n) % 40 < 30                                                   # 10 frames in 40 lost
    frames = [KeypointFrame(i, i / 24.0, [Person(body[i], np.full(14, 0.9), hands=hands if seen[i] else
                                                 hands * [1.0, 1.0, 1.0, 0.0])]) for i in range(n)]
    engine = Engine(small_db, EngineConfig(fps=24.0, focal_px=1000.0, image_size=(1920, 1080), keep_take=True))
    for frame in frames:
        engine.step(frame)
    rec = max(engine.finish(), key=len)
    recorded = rec.column("hands_px")
    assert recorded.dtype == np.float32 and recorded.shape == (len(rec), 2, 21, 3)
    assert np.isnan(recorded[:, 0]).all() and (np.isfinite(recorded[:, 1]).all(axis=(-2, -1)) == seen[:len(rec)]).all()
    fitted, _ = fit_take(rec, 24.0)
    np.testing.assert_array_equal(fitted.hands_seen, np.isfinite(recorded).all(axis=(-2, -1)))
    relaxed = finger_quaternions(np.broadcast_to(RELAXED_DEG, (1, 2, 5, 5)))[0]
    measured = _measured(hand_points_view(recorded[:1].astype(np.float64)))[0]
    assert _rotation_deg(fitted.finger_quaternions[:, :15], relaxed[:15]).max() < 1e-4
    assert _rotation_deg(fitted.finger_quaternions[5, 15:], measured[15:]).max() < 1e-3
