"""The head, hands and feet against synthetic truth (mocapdb/evaluation/end_truth.py, ends.py): the score, the
frames it is taken in, the truth read off the clips' own rig and the points rendered from it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.bvh import forward_kinematics
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import CAMERA_FROM_VIEW, motion_bvh
from mocapdb.core.skeleton import END_JOINTS, KP, N_RIG_JOINTS
from mocapdb.evaluation.bodies import reshape_body
from mocapdb.evaluation.end_truth import FACE_M, FOOT_M, HAND_M, end_points
from mocapdb.evaluation.ends import end_globals, ends_truths, geodesic_deg, view_frames, view_rotation
from mocapdb.evaluation.gate import GATE_BODIES
from mocapdb.evaluation.heldout import EvalConfig, Scenario, camera_distance, camera_view, project, render

CLIP = Path(__file__).resolve().parents[1] / "data" / "gate" / "cmu_bvh" / "007_12.bvh"


def _random_motion(rng: np.random.Generator, n: int = 6) -> Motion:
    quats = Rotation.random(n * N_RIG_JOINTS, random_state=1).as_quat(scalar_first=True).reshape(n, N_RIG_JOINTS, 4)
    ends = Rotation.random(n * len(END_JOINTS), random_state=2).as_quat(scalar_first=True).reshape(n, -1, 4)
    return Motion(quats, rng.normal(size=(n, 3)), 24.0, "view", end_rotations=ends)


def test_geodesic_error_is_scipys_angle():
    a = Rotation.random(50, random_state=3)
    b = Rotation.random(50, random_state=4)
    assert np.allclose(geodesic_deg(a.as_matrix(), b.as_matrix()), np.degrees((a.inv() * b).magnitude()), atol=1e-6)


def test_a_known_rotation_scores_0_and_an_offset_of_30_deg_scores_30():
    """The humanoid BVH's end bones as the truth score 0; turned 30 deg about any axis in their own frame or
    the world's, 30 (scipy's angle of the same offset)."""
    globals_ = end_globals(_random_motion(np.random.default_rng(0)))
    assert np.allclose(geodesic_deg(globals_, globals_), 0.0, atol=1e-6)
    offset = Rotation.from_rotvec(np.radians(30.0) * np.array([0.36, -0.48, 0.8])).as_matrix()
    for truth in (globals_ @ offset, offset @ globals_):
        scipy_angle = np.degrees((Rotation.from_matrix(globals_.reshape(-1, 3, 3)).inv()
                                  * Rotation.from_matrix(truth.reshape(-1, 3, 3))).magnitude())
        assert np.allclose(geodesic_deg(globals_, truth).ravel(), scipy_angle, atol=1e-6)
        assert np.allclose(scipy_angle, 30.0, atol=1e-6)


def test_an_unseen_output_is_nan_not_zero():
    eye = np.broadcast_to(np.eye(3), (2, 3, 3)).copy()
    eye[1, 0, 0] = np.nan
    assert np.isnan(geodesic_deg(eye, np.eye(3))[1]) and geodesic_deg(eye, np.eye(3))[0] == 0.0


def test_the_humanoid_rest_is_the_truths_convention():
    """At rest every end bone's global rotation is the identity, and the rig puts the bones where the
    truth's frames have them: the right hand along -x, the left along +x, toes forwards (+z), the nose
    ahead of the head (+z)."""
    rest = Motion(np.tile([1.0, 0.0, 0.0, 0.0], (1, N_RIG_JOINTS, 1)), np.zeros((1, 3)), 24.0, "view",
                  end_rotations=np.tile([1.0, 0.0, 0.0, 0.0], (1, len(END_JOINTS), 1)))
    assert np.allclose(end_globals(rest), np.eye(3), atol=1e-9)
    bvh = motion_bvh(rest, rig="humanoid")
    names = ["RightHand", "RightHandMiddle1", "LeftHand", "LeftHandMiddle1", "RightFoot", "RightToeBase", "Head",
             "Head_End"]
    p = forward_kinematics(bvh, [bvh.names.index(n) for n in names])[0][0]
    hand_r, hand_l, foot, head = (p[k + 1] - p[k] for k in range(0, 8, 2))
    assert hand_r[0] < -abs(hand_r[1:]).max() and hand_l[0] > abs(hand_l[1:]).max()
    assert foot[2] > abs(foot[0]) and head[2] > abs(head[0])


def test_view_rotation_turns_as_the_camera_view():
    points = np.random.default_rng(5).normal(size=(1, 20, 3))
    for yaw, pitch, roll in ((3.0, 0.0, 0.0), (123.0, 15.0, 30.0)):
        cam = camera_view(points, yaw, 1.5, 5.0, pitch, roll)[0] * CAMERA_FROM_VIEW
        view = view_rotation(yaw, pitch, roll)
        assert np.isclose(np.linalg.det(view), 1.0)
        assert np.allclose(cam[1:] - cam[0], (points[0, 1:] - points[0, 0]) @ view.T, atol=1e-12)


@pytest.fixture(scope="module")
def clip():
    return ends_truths([CLIP], 48, (63.0,), 24.0)[0]


def test_the_truth_lines_up_with_the_body_and_is_anatomical(clip):
    """Rotations for the same frames as the body, proper; the hands' x along the wrist's bone away from the
    elbow side, the feet level where flat (median pitch of the foot's z near 0), the head's y up."""
    truth, ends = clip
    r = ends.rotations
    assert r.shape == (len(truth.source_m), 5, 3, 3)
    assert np.allclose(np.einsum("fkji,fkjl->fkil", r, r), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(r), 1.0)
    p = truth.source_m
    for k, side, sign in ((2, "r", -1.0), (3, "l", 1.0)):
        forearm = p[:, KP[f"{side}_wrist"]] - p[:, KP[f"{side}_elbow"]]
        assert np.median(np.einsum("fi,fi->f", sign * r[:, k, :, 0], forearm)) > 0
    assert abs(np.degrees(np.median(np.arcsin(r[:, :2, 1, 2])))) < 8.0
    assert np.median(r[:, 4, 1, 1]) > 0.8


def test_the_points_sit_on_the_ends_frames(clip):
    """Each rendered point is its anchor plus the end's rotation times its layout (scaled to the stature)."""
    truth, ends = clip
    posed = reshape_body(truth.source_joints(), GATE_BODIES[1].lengths_m())
    points = end_points(posed, ends.rotations, 1.54)
    s = 1.54 / 1.75
    f = 7
    nose = np.array(FACE_M["nose"])
    expected_ear = posed[f, KP["head"]] + ends.rotations[f, 4] @ ((np.array(FACE_M["l_ear"]) - nose) * s)
    assert np.allclose(points[f, EXTREMITIES.index("l_ear")], expected_ear)
    index = np.array(HAND_M["index"]) * [-1.0, 1.0, 1.0] * s
    assert np.allclose(points[f, EXTREMITIES.index("l_index")], posed[f, KP["l_wrist"]] + ends.rotations[f, 3] @ index)
    toe = np.array(FOOT_M["big_toe"]) * s
    assert np.allclose(points[f, EXTREMITIES.index("r_big_toe")], posed[f, KP["r_ankle"]] + ends.rotations[f, 0] @ toe)


def test_rendered_points_project_the_truth_in_the_view_frame(clip):
    """Exact input: the pixels of the face points are the projection of the nose plus the truth's view-frame
    rotation times the layout (the frame the scores compare in)."""
    truth, ends = clip
    posed = reshape_body(truth.source_joints(), GATE_BODIES[0].lengths_m())
    config = EvalConfig()
    frames, true_view = view_frames(posed, ends, 1.75, 63.0, Scenario("exact"), config)
    f = 11
    cam = camera_view(posed, 63.0, 1.5, camera_distance(posed, 63.0, config))
    nose_view = cam[f, KP["head"]] * CAMERA_FROM_VIEW
    eye = nose_view + true_view[f, 4] @ (np.array(FACE_M["r_eye"]) - np.array(FACE_M["nose"]))
    expected = project((eye * CAMERA_FROM_VIEW)[None], config.focal_px, config.image_size)[0]
    assert np.allclose(frames[f].people[0].extremities[EXTREMITIES.index("r_eye"), :2], expected, atol=1e-9)


def test_rendering_the_ends_leaves_the_body_frames_as_they_were(clip):
    """The body's pixels and confidences are drawn first: the same with or without the end points; the end
    points swap with the body (the face's right and left in a swapped frame)."""
    truth, ends = clip
    cam = camera_view(np.concatenate([truth.source_m, end_points(truth.source_m, ends.rotations, 1.75)], axis=1),
                      3.0, 1.5, 6.0)
    noisy = Scenario("noisy", noise_px=5.0, dropout=0.1, swap=0.3)
    plain = render(cam[:, :15], noisy, 1000.0, (1920, 1080), np.random.default_rng(9))
    with_ends = render(cam[:, :15], noisy, 1000.0, (1920, 1080), np.random.default_rng(9), cam[:, 15:])
    for a, b in zip(plain, with_ends):
        assert np.array_equal(a.people[0].points_px, b.people[0].points_px, equal_nan=True)
        assert np.array_equal(a.people[0].confidence, b.people[0].confidence)
    exact = render(cam[:, :15], Scenario("swaps", swap=0.3), 1000.0, (1920, 1080), np.random.default_rng(9),
                   cam[:, 15:])
    clean = project(cam[:, 15:], 1000.0, (1920, 1080))
    right, left = EXTREMITIES.index("r_eye"), EXTREMITIES.index("l_eye")
    swapped = [np.allclose(f.people[0].extremities[right, :2], clean[i, left]) for i, f in enumerate(exact)]
    body_swapped = [np.allclose(f.people[0].points_px[KP["r_wrist"]],
                                project(cam[i, KP["l_wrist"]], 1000.0, (1920, 1080))) for i, f in enumerate(exact)]
    assert any(swapped) and swapped == body_swapped


def test_the_gates_ends_part_has_its_thresholds():
    """Every figure the gate's part ``ends`` makes has a threshold set with the part's own margin."""
    import json

    from mocapdb.evaluation.ends import GATE_ENDS_VARIANTS, GATE_MARGIN, GROUPS
    from mocapdb.evaluation.gate import thresholds_from

    data = json.loads((CLIP.parents[3] / "data_specs" / "accuracy_gate.json").read_text())
    assert data["margin"]["ends"] == {"relative": GATE_MARGIN[0], "absolute": GATE_MARGIN[1]}
    names = [f"ends/{variant}/{group}_deg" for variant in GATE_ENDS_VARIANTS for group in GROUPS]
    for name in names:
        entry = data["figures"][name]
        assert entry == thresholds_from({name: entry["measured"]}, *GATE_MARGIN)[name]
