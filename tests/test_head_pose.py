"""The head's rotation from face points: the fit recovers a known rotation from projected model points
(scipy's Rotation as the reference; to 1e-9 where the cost's minimum is the true head), with the face's
left and right swapped too, works with the points COCO-17 has, leaves frames without a face to the prior,
each layout's face rows (and their world landmarks), the world landmarks' head against the chest and the
person's own face model (closed form), and the humanoid BVH's Head carrying the kept components of the
rotation relative to the chest."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, parse_bvh
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES, LAYOUTS
from mocapdb.core.formats.keypoints import to_extremities, to_extremities_world
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import N_RIG_JOINTS
from mocapdb.runtime import head_pose
from mocapdb.runtime.head_pose import (
    FACE_MODEL_M,
    FACE_ROWS,
    face_model,
    fit_head,
    head_local,
    world_relative,
)

CAMERA = (1500.0, 960.0, 540.0)


def _project(points_view: np.ndarray, camera_px: tuple[float, float, float]) -> np.ndarray:
    """The pinhole's pixels ``[..., 2]`` (y down) of view-frame points ``[..., 3]`` (y up, z to the camera)."""
    focal, cx, cy = camera_px
    depth = -points_view[..., 2]
    return np.stack([cx + focal * points_view[..., 0] / depth, cy - focal * points_view[..., 1] / depth], axis=-1)


def _scene(n: int, seed: int = 0, noise_px: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random head rotations (turn ±60°, nod ±30°, tilt ±20° about the view's axes, facing the camera's
    +z), their face points projected (``[n, 7, 3]``, confidence 0.9) and the true nose (view frame)."""
    rng = np.random.default_rng(seed)
    angles = np.column_stack([rng.uniform(-60, 60, n), rng.uniform(-30, 30, n), rng.uniform(-20, 20, n)])
    truth = Rotation.from_euler("YXZ", angles, degrees=True).as_matrix()
    centre = np.column_stack([rng.uniform(-0.5, 0.5, n), rng.uniform(0.0, 0.5, n), -rng.uniform(2.0, 5.0, n)])
    points = centre[:, None] + np.einsum("fij,pj->fpi", truth, FACE_MODEL_M)
    pixels = _project(points, CAMERA) + rng.normal(0.0, noise_px, (n, 7, 2)) if noise_px else _project(points, CAMERA)
    return truth, np.concatenate([pixels, np.full((n, 7, 1), 0.9)], axis=-1), points[:, 0]


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(Rotation.from_matrix(np.swapaxes(a, -1, -2) @ b).magnitude())


def test_exact_face_points_give_the_rotation_back():
    truth, face, nose = _scene(50)
    rotation, fixed = fit_head(face, nose, np.broadcast_to(np.eye(3), (50, 3, 3)).copy(), 1.0, CAMERA)
    assert fixed.all()
    assert np.median(_angle_deg(truth, rotation)) < 1.0


def test_a_face_with_its_left_and_right_swapped_is_fitted_as_the_same_head():
    truth, face, nose = _scene(50, seed=5)
    swapped = face[:, [0, 2, 1, 4, 3, 6, 5]]             # the detector's labels exchanged
    prior = Rotation.from_matrix(truth).as_matrix()
    rotation, fixed = fit_head(swapped, nose, prior, 1.0, CAMERA)
    assert fixed.all()
    assert np.median(_angle_deg(truth, rotation)) < 1.0


@pytest.mark.parametrize("seen", [7, 5])
def test_the_fit_lands_on_the_true_head_to_1e9_from_a_prior_30_degrees_off(seen):
    """Noise-free points, the centre started where it is and a prior too weak to pull (SD 10⁶°): the
    cost's minimum is the true rotation (every residual 0), which the Gauss-Newton must reach exactly."""
    truth, face, nose = _scene(40, seed=7)
    face[:, seen:, 2] = 0.0                               # 5: no mouth corners (COCO-17's face)
    rng = np.random.default_rng(8)
    prior = Rotation.from_rotvec(rng.normal(size=(40, 3)) * np.radians(30) / np.sqrt(3)).as_matrix() @ truth
    centre = nose - truth @ FACE_MODEL_M[0]
    rotation, fixed = fit_head(face, centre + prior @ FACE_MODEL_M[0], prior, 1.0, CAMERA, 1e6)
    assert fixed.all()
    np.testing.assert_allclose(rotation, truth, atol=1e-9)


def test_noisy_points_and_a_wrong_depth_stay_within_eight_degrees():
    truth, face, nose = _scene(200, seed=1, noise_px=1.0)
    nose = nose * 1.1                                     # the body's nose 10 % too far
    rotation, _ = fit_head(face, nose, np.broadcast_to(np.eye(3), (200, 3, 3)).copy(), 1.0, CAMERA)
    assert np.median(_angle_deg(truth, rotation)) < 8.0


def test_coco17_points_suffice_and_too_few_points_keep_the_prior():
    truth, face, nose = _scene(30, seed=2)
    face[:, 5:, 2] = 0.0                                  # no mouth corners (COCO-17: nose, eyes, ears)
    face[:10, 1:, 2] = 0.0                                # the first 10 frames: the nose alone
    prior = np.broadcast_to(Rotation.from_euler("y", 10, degrees=True).as_matrix(), (30, 3, 3)).copy()
    rotation, fixed = fit_head(face, nose, prior, 1.0, CAMERA)
    assert not fixed[:10].any() and fixed[10:].all()
    np.testing.assert_array_equal(rotation[:10], prior[:10])
    assert np.median(_angle_deg(truth[10:], rotation[10:])) < 2.0


@pytest.mark.parametrize("layout, names", [
    ("mediapipe33", ("right_eye", "left_eye", "right_ear", "left_ear", "mouth_right", "mouth_left")),
    ("coco17", ("right_eye", "left_eye", "right_ear", "left_ear", None, None)),
    ("body25", ("REye", "LEye", "REar", "LEar", None, None)),
    ("wholebody133", ("right_eye", "left_eye", "right_ear", "left_ear", "face_48", "face_54")),
])
def test_each_layout_gives_its_face_points(layout, names):
    order = LAYOUTS[layout]
    raw = np.column_stack([np.arange(len(order)) + 100.0, np.arange(len(order)) + 200.0, np.full(len(order), 0.7)])
    got = to_extremities(raw[None], layout)[0][list(FACE_ROWS)]
    for row, name in zip(got, names):
        at = None if name is None else order.index(name)
        expected = [np.nan, np.nan, 0.0] if at is None else [100.0 + at, 200.0 + at, 0.7]
        np.testing.assert_array_equal(row, expected)
    assert len(EXTREMITIES) == 14
    world = np.arange(3 * len(order), dtype=float).reshape(1, len(order), 3)
    got_world = to_extremities_world(world, layout)[0][list(FACE_ROWS)]
    for row, name in zip(got_world, names):
        expected_world = np.full(3, np.nan) if name is None else world[0, order.index(name)]
        np.testing.assert_array_equal(row, expected_world)


def _world_points(head: np.ndarray, chest: np.ndarray) -> np.ndarray:
    """:func:`~mocapdb.runtime.head_pose.face_world` points ``[F, 11, 3]`` (x right, y down, z away) of
    a head ``[F, 3, 3]`` turned by ``head`` and a chest by ``chest`` (view frames: x left of the subject
    facing the camera, y up, z to the camera), the ears 10 cm apart (the nose on the head frame's z axis),
    shoulders 36 cm, hips 24 cm."""
    face = np.array([[0, 0, 0.07], [-0.03, 0.01, 0.04], [0.03, 0.01, 0.04], [-0.05, 0, 0], [0.05, 0, 0],
                     [-0.02, -0.05, 0.05], [0.02, -0.05, 0.05]])
    body = np.array([[-0.18, 0.0, 0.0], [0.18, 0.0, 0.0], [-0.12, -0.5, 0.0], [0.12, -0.5, 0.0]])
    view = np.concatenate([np.einsum("fij,pj->fpi", head, face) + [0.0, 0.1, 0.0],
                           np.einsum("fij,pj->fpi", chest, body)], axis=1)
    return view * [1.0, -1.0, -1.0]


def test_world_landmarks_give_the_head_against_the_chest_whatever_the_labels():
    head = Rotation.from_euler("YXZ", [[30, 10, -5], [-45, 0, 0], [0, 20, 0], [10, -10, 15]], degrees=True)
    chest = Rotation.from_euler("YXZ", [[170, 5, 0], [20, 0, 10], [-60, 0, 0], [0, 0, 0]], degrees=True)
    points = _world_points((chest * head).as_matrix(), chest.as_matrix())
    truth = head.as_matrix()
    np.testing.assert_allclose(world_relative(points), truth, atol=1e-9)
    body_swapped = points[:, [0, 1, 2, 3, 4, 5, 6, 8, 7, 10, 9]]
    face_swapped = points[:, [0, 2, 1, 4, 3, 6, 5, 7, 8, 9, 10]]
    np.testing.assert_allclose(world_relative(body_swapped), truth, atol=1e-9)
    np.testing.assert_allclose(world_relative(face_swapped), truth, atol=1e-9)
    points[1, 3] = np.nan
    assert np.isnan(world_relative(points)[1]).all()


def test_the_own_face_model_is_the_world_pattern_in_the_head_frame():
    turns = Rotation.from_euler("YXZ", np.random.default_rng(6).uniform(-40, 40, (8, 3)), degrees=True)
    points = _world_points(turns.as_matrix(), np.broadcast_to(np.eye(3), (8, 3, 3)))
    model = face_model(points)
    expected = np.array([[0, 0, 0.07], [-0.03, 0.01, 0.04], [0.03, 0.01, 0.04], [-0.05, 0, 0], [0.05, 0, 0],
                         [-0.02, -0.05, 0.05], [0.02, -0.05, 0.05]])
    np.testing.assert_allclose(model, expected, atol=1e-9)
    assert face_model(points[:4]) is None                  # fewer than MIN_MODEL_FRAMES


def _humanoid_head(relative: Rotation) -> tuple[Rotation, Rotation]:
    """The humanoid BVH's Head and Neck against its Spine1 with ``relative`` as the head's rotation relative
    to the chest (random rig rotations)."""
    n = len(relative)
    rng = np.random.default_rng(3)
    quats = Rotation.random(n * N_RIG_JOINTS, random_state=4).as_quat()[:, [3, 0, 1, 2]].reshape(n, N_RIG_JOINTS, 4)
    ends = np.tile([1.0, 0.0, 0.0, 0.0], (n, 5, 1))
    ends[:, 4] = head_local(quats, relative.as_quat()[:, [3, 0, 1, 2]])
    bvh = parse_bvh(format_bvh(motion_bvh(Motion(quats, rng.normal(size=(n, 3)), 30.0, end_rotations=ends),
                                          rig="humanoid")))
    _, rotations = forward_kinematics(bvh, [bvh.index("Spine1"), bvh.index("Neck"), bvh.index("Head")])
    chest_inverse = np.swapaxes(rotations[:, 0], -1, -2)
    return Rotation.from_matrix(chest_inverse @ rotations[:, 2]), Rotation.from_matrix(chest_inverse @ rotations[:, 1])


RELATIVE = Rotation.from_euler("YXZ", [[30, 10, -5], [-45, 0, 0], [0, 20, 0], [10, -10, 15]], degrees=True)


def test_the_humanoid_head_turns_by_its_rotation_relative_to_the_chest(monkeypatch):
    monkeypatch.setattr(head_pose, "HEAD_GAINS", np.ones(3))
    got, _ = _humanoid_head(RELATIVE)
    assert np.degrees((got * RELATIVE.inv()).magnitude()).max() < 1e-3


def test_the_humanoid_head_keeps_the_fitted_tilt_and_the_neck_s_turn_and_nod():
    got, neck = _humanoid_head(RELATIVE)
    expected = np.column_stack([neck.as_euler("YXZ", degrees=True)[:, :2],
                                RELATIVE.as_euler("YXZ", degrees=True)[:, 2]])
    np.testing.assert_allclose(got.as_euler("YXZ", degrees=True), expected, atol=1e-4)
