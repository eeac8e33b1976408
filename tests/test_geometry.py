"""Rotations against scipy, projection against OpenCV, normalisation against hand-computed cases."""
import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.cameras import CameraModel, DatabaseCamera
from mocapdb.core.geometry import (
    camera_axes_world,
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quat,
    normalize_pose_2d,
    project_views,
    quat_geodesic,
    quat_mul,
    quat_to_matrix,
    quat_turned_towards,
    slerp,
    yaw_matrix,
)
from mocapdb.core.skeleton import KP, PELVIS

RNG = np.random.default_rng(7)


def _scipy_quat(r: Rotation) -> np.ndarray:
    q = r.as_quat()[..., [3, 0, 1, 2]]
    return np.where(q[..., :1] < 0, -q, q)


@pytest.mark.parametrize("order", ["ZYX", "XYZ", "ZXY", "YXZ", "YZX", "XZY"])
def test_euler_matches_scipy_intrinsic_and_inverts(order):
    angles = RNG.uniform(-170, 170, size=(200, 3))
    angles[:, 1] = RNG.uniform(-85, 85, size=200)
    mats = euler_to_matrix(angles, order)
    np.testing.assert_allclose(mats, Rotation.from_euler(order, angles, degrees=True).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(euler_to_matrix(matrix_to_euler(mats, order), order), mats, atol=1e-9)


def test_quaternions_match_scipy():
    r = Rotation.random(500, random_state=3)
    q = _scipy_quat(r)
    np.testing.assert_allclose(matrix_to_quat(r.as_matrix()), q, atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(q), r.as_matrix(), atol=1e-12)
    s = Rotation.random(500, random_state=4)
    np.testing.assert_allclose(quat_to_matrix(quat_mul(q, _scipy_quat(s))), (r * s).as_matrix(), atol=1e-12)


def test_quaternions_keep_any_leading_shape_and_propagate_nan():
    """The numba kernels behind matrix_to_quat and quat_to_matrix: any leading axes (none, several,
    empty) as SciPy gives them, a half turn (w = 0: the largest component is not w), and NaN out
    where a matrix's diagonal holds NaN."""
    r = Rotation.random(12, random_state=8)
    q = _scipy_quat(r).reshape(3, 4, 4)
    np.testing.assert_allclose(quat_to_matrix(q), r.as_matrix().reshape(3, 4, 3, 3), atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(r.as_matrix().reshape(3, 4, 3, 3)), q, atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(r.as_matrix()[0]), q[0, 0], atol=1e-12)
    assert quat_to_matrix(np.zeros((0, 4))).shape == (0, 3, 3) and matrix_to_quat(np.zeros((0, 3, 3))).shape == (0, 4)
    half_turns = Rotation.from_rotvec(np.pi * np.eye(3))
    np.testing.assert_allclose(np.abs(matrix_to_quat(half_turns.as_matrix())), np.abs(_scipy_quat(half_turns)),
                               atol=1e-12)
    broken = r.as_matrix()[:2].copy()
    broken[0, 1, 1] = np.nan
    out = matrix_to_quat(broken)
    assert np.isnan(out[0]).all() and np.isfinite(out[1]).all()


def test_slerp_and_the_turn_limit_match_scipy():
    """slerp against SciPy's Slerp (quaternions, each pair, shares per pair or one for all, one start
    broadcast against many ends); quat_turned_towards: the end where it is within the limit, else SciPy's
    rotation that far along the shorter way (an end of the other sign is the same rotation); NaN stays NaN."""
    from scipy.spatial.transform import Slerp

    r, s = Rotation.random(30, random_state=9), Rotation.random(30, random_state=10)
    a, b = _scipy_quat(r), _scipy_quat(s)
    b = np.where(np.sum(a * b, axis=-1, keepdims=True) < 0, -b, b)   # a's hemisphere, as slerp's callers give
    share = np.linspace(0.0, 1.0, 30)
    expected = [Slerp([0.0, 1.0], Rotation.from_quat(np.stack([a[i], b[i]])[:, [1, 2, 3, 0]]))(share[i]).as_quat()
                for i in range(30)]
    expected = np.array(expected)[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(np.abs(np.sum(slerp(a, b, share) * expected, axis=-1)), 1.0, atol=1e-12)
    assert slerp(a, b, 0.3).shape == (30, 4) and slerp(a[0], b, share).shape == (30, 4)
    angle = 2.0 * np.arccos(np.clip(np.abs(np.sum(a * b, axis=-1)), 0.0, 1.0))
    limit = 0.5 * angle
    limit[:10] = angle[:10] + 0.1    # within the limit: the end itself
    turned = quat_turned_towards(a, -b, limit)
    np.testing.assert_allclose(turned[:10], b[:10], atol=1e-12)
    along = (r[10:].inv() * Rotation.from_quat(turned[10:, [1, 2, 3, 0]])).magnitude()
    np.testing.assert_allclose(along, limit[10:], atol=1e-9)
    assert np.isnan(slerp(np.full(4, np.nan), b[0], 0.5)).all()


def test_geodesic_is_half_angle_and_sign_blind():
    r = Rotation.random(100, random_state=5)
    s = Rotation.random(100, random_state=6)
    expected = (r.inv() * s).magnitude() / 2
    a, b = _scipy_quat(r), _scipy_quat(s)
    np.testing.assert_allclose(quat_geodesic(a, b), expected, atol=1e-7)
    np.testing.assert_allclose(quat_geodesic(a, -b), expected, atol=1e-7)


def test_projection_matches_opencv():
    cam = DatabaseCamera(height_m=1.5, distance_m=4.0, focal_px=1000.0)
    pts = RNG.normal(scale=0.5, size=(3, 15, 3)) + np.array([0.2, 1.0, -0.3])
    pelvis = pts[:, PELVIS]
    yaws = np.array([0.0, 12.0, 200.0])
    ours = project_views(pts, pelvis, yaws, floor_y_m=0.1, camera=cam)
    k = np.array([[1000.0, 0, 960], [0, 1000.0, 540], [0, 0, 1]])
    r_cam = camera_axes_world()
    for f in range(3):
        for v, yaw in enumerate(yaws):
            turned = (pts[f] - pelvis[f]) @ yaw_matrix(yaw).T + pelvis[f]
            center = np.array([pelvis[f, 0], 0.1 + 1.5, pelvis[f, 2] + 4.0])
            rvec, _ = cv2.Rodrigues(r_cam)
            ref, _ = cv2.projectPoints(turned, rvec, -r_cam @ center, k, None)
            np.testing.assert_allclose(ours[f, v], ref[:, 0, :], atol=1e-6)


def test_front_view_mirrors_left_to_image_right():
    # Subject facing +z (toward the camera at yaw 0): its left (+x) shows on the image's right.
    pts = np.zeros((1, 15, 3))
    left, right = KP["l_shoulder"], KP["r_shoulder"]
    pts[0, left] = [0.2, 1.7, 0]
    pts[0, right] = [-0.2, 1.7, 0]
    uv = project_views(pts, pts[:, PELVIS], np.array([0.0]), 0.0, DatabaseCamera())
    assert uv[0, 0, left, 0] > 960 > uv[0, 0, right, 0]
    assert uv[0, 0, left, 1] < 540  # above the camera → upper half of the image


def test_database_camera_model_is_its_pinhole():
    cam = DatabaseCamera(height_m=1.2, distance_m=3.0, focal_px=800.0, width_px=1280, height_px=720)
    model = cam.model()
    assert isinstance(model, CameraModel)
    np.testing.assert_array_equal(model.K, [[800.0, 0.0, 640.0], [0.0, 800.0, 360.0], [0.0, 0.0, 1.0]])
    np.testing.assert_array_equal(model.dist, np.zeros(4))
    np.testing.assert_array_equal(model.R, np.eye(3))
    np.testing.assert_array_equal(model.t, np.zeros(3))
    assert model.size == (1280, 720)
    # project_views is that model looking from the camera's place (OpenCV axes, pose removed).
    pts = RNG.normal(scale=0.4, size=(2, 15, 3)) + np.array([0.1, 1.0, 0.2])
    pelvis = pts[:, PELVIS]
    ours = project_views(pts, pelvis, np.array([0.0]), floor_y_m=0.05, camera=cam)
    for f in range(2):
        center = np.array([pelvis[f, 0], 0.05 + 1.2, pelvis[f, 2] + 3.0])
        in_camera = (pts[f] - center) @ camera_axes_world().T
        np.testing.assert_allclose(ours[f, 0], model.project(in_camera), atol=1e-6)


def test_normalisation_hand_computed():
    pts = np.zeros((14, 2))
    pts[:, 1] = np.linspace(100, 300, 14)  # 200 px high
    pts[:, 0] = 50
    pts[KP["r_hip"]] = [40, 250]
    pts[KP["l_hip"]] = [60, 250]
    norm, origin, scale = normalize_pose_2d(pts)
    np.testing.assert_allclose(origin, [50, 250])
    assert scale == pytest.approx(1 / 200)
    np.testing.assert_allclose(norm[KP["head"]], [0, -0.75])
    vis = np.ones(14, bool)
    vis[KP["head"]] = False  # the top joint hidden: the box shrinks, the joint reads as 0
    norm2, _, scale2 = normalize_pose_2d(pts, vis)
    assert scale2 == pytest.approx(1 / (300 - pts[KP["neck"], 1]))
    np.testing.assert_allclose(norm2[KP["head"]], 0)


def test_normalisation_one_hip_or_none():
    pts = RNG.normal(scale=50.0, size=(14, 2)) + 300.0
    vis = np.ones(14, bool)
    vis[KP["l_hip"]] = False  # the visible hip is the origin
    _, origin, scale = normalize_pose_2d(pts, vis)
    np.testing.assert_allclose(origin, pts[KP["r_hip"]])
    assert scale == pytest.approx(1 / np.ptp(pts[vis, 1]))
    vis[KP["r_hip"]] = False  # no hip: no origin to scale about
    norm, _, scale = normalize_pose_2d(pts, vis)
    assert scale == 0 and not norm.any()


def test_normalisation_is_scale_and_shift_invariant():
    pts = RNG.normal(size=(10, 14, 2))
    a, _, _ = normalize_pose_2d(pts)
    b, _, _ = normalize_pose_2d(pts * 3.7 + np.array([100.0, -20.0]))
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_degenerate_pose_gets_zero_scale():
    _, _, scale = normalize_pose_2d(np.ones((14, 2)))
    assert scale == 0
