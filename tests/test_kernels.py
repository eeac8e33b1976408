"""The shared numba primitives of mocapdb.core.kernels against independent closed forms (scipy, numpy)."""
import numpy as np
from scipy.spatial.distance import cdist
from scipy.spatial.transform import Rotation

from mocapdb.core.kernels import (
    NORMALISED_HEIGHT,
    pose_distances_into,
    pose_normalisation_into,
    quat_abs_dot,
    quat_mul_into,
    quat_relative_log_into,
    quat_to_matrix_into,
    renormalised_pose_distances_into,
)
from mocapdb.core.skeleton import KP

RNG = np.random.default_rng(11)
R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]


def _wxyz(r: Rotation) -> np.ndarray:
    x, y, z, w = r.as_quat().T
    return np.stack([w, x, y, z], axis=-1)


def test_quat_mul_into_is_scipy_composition():
    a, b = Rotation.random(50, random_state=1), Rotation.random(50, random_state=2)
    qa, qb, out = _wxyz(a), _wxyz(b), np.empty(4)
    expected = (a * b).as_matrix()  # b applied first
    for i in range(50):
        quat_mul_into(qa[i], qb[i], out)
        np.testing.assert_allclose(np.linalg.norm(out), 1.0, atol=1e-12)
        m = np.empty((3, 3))
        quat_to_matrix_into(out, m)
        np.testing.assert_allclose(m, expected[i], atol=1e-12)


def test_quat_mul_into_mixed_precision_root_turn():
    # The temporal cost turns float32 database roots by float64 yaws.
    yaw, root = Rotation.from_euler("y", 33.0, degrees=True), Rotation.random(random_state=3)
    out = np.empty(4)
    quat_mul_into(_wxyz(yaw), _wxyz(root).astype(np.float32), out)
    np.testing.assert_allclose(np.abs(out @ _wxyz(yaw * root)), 1.0, atol=1e-6)


def test_quat_abs_dot_gives_half_angle():
    a, b = Rotation.random(30, random_state=4), Rotation.random(30, random_state=5)
    qa, qb = _wxyz(a), _wxyz(b)
    for i in range(30):
        half = (a[i].inv() * b[i]).magnitude() / 2
        np.testing.assert_allclose(np.arccos(min(quat_abs_dot(qa[i], -qb[i]), 1.0)), half, atol=1e-7)


def test_quat_relative_log_into_is_scipy_rotvec():
    a, b = Rotation.random(30, random_state=6), Rotation.random(30, random_state=7)
    qa, qb, out = _wxyz(a), _wxyz(b), np.empty(3)
    for i in range(30):
        quat_relative_log_into(qa[i], qb[i], out)
        np.testing.assert_allclose(out, (a[i].inv() * b[i]).as_rotvec(), atol=1e-10)


def test_pose_distances_into_is_sum_of_joint_distances():
    poses = RNG.normal(size=(40, 14, 2))
    query = RNG.normal(size=(14, 2))
    xs, ys = np.ascontiguousarray(poses[..., 0].T), np.ascontiguousarray(poses[..., 1].T)
    joints = np.array([0, 2, 3, 8, 11, 13])
    out = np.zeros(30)
    pose_distances_into(xs, ys, 5, 35, query, joints, out)
    expected = np.array([sum(cdist(p[[k]], query[[k]])[0, 0] for k in joints) for p in poses[5:35]])
    np.testing.assert_allclose(out, expected, atol=1e-12)
    # float32 poses and query, accumulated in float32 (the runtime search) or float64 (the builder).
    out32, out64 = np.zeros(30, dtype=np.float32), np.zeros(30)
    args = (xs.astype(np.float32), ys.astype(np.float32), 5, 35, query.astype(np.float32), joints)
    pose_distances_into(*args, out32)
    pose_distances_into(*args, out64)
    np.testing.assert_allclose(out32, expected, rtol=1e-5)
    np.testing.assert_allclose(out64, expected, rtol=1e-5)


def _reference_normalisation(pose: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, float]:
    """Origin (mid-hip, or the visible hip) and scale of one pose ``[14, 2]`` over ``joints``."""
    hips = [k for k in (R_HIP, L_HIP) if k in joints] or [R_HIP, L_HIP]
    origin = pose[hips].mean(axis=0) if len(hips) == 2 else pose[hips[0]]
    return origin, NORMALISED_HEIGHT / np.ptp(pose[joints, 1])


def test_pose_normalisation_into_matches_reference():
    poses = RNG.normal(scale=80.0, size=(25, 14, 2)) + 400.0
    xs, ys = np.ascontiguousarray(poses[..., 0].T), np.ascontiguousarray(poses[..., 1].T)
    for joints in (np.arange(14), np.array([0, 1, 4, 8, 9]), np.array([2, 5, 11, 12])):
        n = 20
        top, bottom, ox, oy, scale = (np.empty(n) for _ in range(5))
        pose_normalisation_into(xs, ys, 3, 23, joints, R_HIP, L_HIP, top, bottom, ox, oy, scale)
        for i in range(n):
            origin, s = _reference_normalisation(poses[3 + i], joints)
            np.testing.assert_allclose([ox[i], oy[i]], origin, atol=1e-12)
            np.testing.assert_allclose(scale[i], s, rtol=1e-12)


def test_pose_normalisation_into_zero_height_gets_zero_scale():
    xs, ys = np.ones((14, 2)), np.ones((14, 2))
    ys[:, 1] = np.nan  # a non-finite height
    out = [np.full(2, 7.0) for _ in range(5)]
    pose_normalisation_into(xs, ys, 0, 2, np.arange(14), R_HIP, L_HIP, *out)
    np.testing.assert_array_equal(out[4], [0.0, 0.0])


def test_renormalised_distances_are_distances_of_normalised_poses():
    poses = RNG.normal(scale=80.0, size=(12, 14, 2)) + 400.0
    query = RNG.normal(scale=0.3, size=(14, 2))
    xs, ys = np.ascontiguousarray(poses[..., 0].T), np.ascontiguousarray(poses[..., 1].T)
    joints = np.array([1, 2, 3, 8, 10, 13])
    top, bottom, ox, oy, scale = (np.empty(12) for _ in range(5))
    pose_normalisation_into(xs, ys, 0, 12, joints, R_HIP, L_HIP, top, bottom, ox, oy, scale)
    out = np.zeros(12)
    renormalised_pose_distances_into(xs, ys, 0, 12, query, joints, ox, oy, scale, out)
    for i in range(12):
        origin, s = _reference_normalisation(poses[i], joints)
        norm = (poses[i, joints] - origin) * s
        np.testing.assert_allclose(out[i], np.linalg.norm(norm - query[joints], axis=1).sum(), atol=1e-12)
