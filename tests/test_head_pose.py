"""The head's rotation from face points: the fit recovers a known rotation from projected model points
(scipy's Rotation as the reference), works with the points COCO-17 has, leaves frames without a face to
the prior, each layout's face rows, and the humanoid BVH's Head carrying the rotation relative to the chest."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, parse_bvh
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES, LAYOUTS
from mocapdb.core.formats.keypoints import to_extremities
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import N_RIG_JOINTS
from mocapdb.runtime.head_pose import FACE_MODEL_M, FACE_ROWS, _project, fit_head, head_local

CAMERA = (1500.0, 960.0, 540.0)


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


def test_the_humanoid_head_turns_by_its_rotation_relative_to_the_chest():
    n = 4
    rng = np.random.default_rng(3)
    quats = Rotation.random(n * N_RIG_JOINTS, random_state=4).as_quat()[:, [3, 0, 1, 2]].reshape(n, N_RIG_JOINTS, 4)
    relative = Rotation.from_euler("YXZ", [[30, 10, -5], [-45, 0, 0], [0, 20, 0], [10, -10, 15]], degrees=True)
    ends = np.tile([1.0, 0.0, 0.0, 0.0], (n, 5, 1))
    ends[:, 4] = head_local(quats, relative.as_quat()[:, [3, 0, 1, 2]])
    bvh = parse_bvh(format_bvh(motion_bvh(Motion(quats, rng.normal(size=(n, 3)), 30.0, end_rotations=ends),
                                          rig="humanoid")))
    _, rotations = forward_kinematics(bvh, [bvh.index("Spine1"), bvh.index("Head")])
    got = Rotation.from_matrix(np.swapaxes(rotations[:, 0], -1, -2) @ rotations[:, 1])
    assert np.degrees((got * relative.inv()).magnitude()).max() < 1e-3
