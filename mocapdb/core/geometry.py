"""Rotations, quaternions, projection and 2D pose normalisation, shared by builder, runtime and stereo.

Conventions (see ``data_specs/skeleton.md``):

* quaternions are ``(w, x, y, z)`` arrays, unit length, acting on column vectors;
* rotation matrices act on column vectors: ``p_world = R @ p_local``;
* the mocap world is right-handed, metres, y up;
* image coordinates are pixels, x to the right, y down (as OpenPose writes them).

Every function is vectorised over leading axes.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from mocapdb.core.kernels import NORMALISED_HEIGHT as NORMALISED_HEIGHT
from mocapdb.core.kernels import pose_normalisation_into, quat_to_matrix_into
from mocapdb.core.keypoint_order import KP

if TYPE_CHECKING:  # cameras imports cv2 (slow); geometry only needs the camera's fields
    from mocapdb.core.cameras import DatabaseCamera


AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}


def axis_rotation_matrices(axis: str, angles_rad: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` about the X, Y or Z axis by ``angles_rad``."""
    c, s = np.cos(angles_rad), np.sin(angles_rad)
    out = np.zeros(np.shape(angles_rad) + (3, 3))
    i = AXIS_INDEX[axis]
    j, k = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., j, j] = c
    out[..., k, k] = c
    out[..., j, k] = -s
    out[..., k, j] = s
    return out


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Compose intrinsic rotations as BVH does: ``order="ZYX"`` gives ``Rz @ Ry @ Rx``.

    ``angles_deg[..., i]`` is the angle in degrees about axis ``order[i]``.
    """
    angles = np.radians(np.asarray(angles_deg, dtype=np.float64))
    out = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for i, axis in enumerate(order):
        out = out @ axis_rotation_matrices(axis, angles[..., i])
    return out


def matrix_to_euler(matrices: np.ndarray, order: str) -> np.ndarray:
    """Inverse of :func:`euler_to_matrix` for a Tait-Bryan ``order`` (three distinct axes), degrees.

    Near gimbal lock the first angle absorbs the rotation and the last is set to zero.
    """
    i, j, k = (AXIS_INDEX[a] for a in order)
    sign = 1.0 if (j - i) % 3 == 1 else -1.0  # cyclic orders (XYZ, YZX, ZXY) have sign +1
    m = np.asarray(matrices, dtype=np.float64)
    sin_b = np.clip(sign * m[..., i, k], -1.0, 1.0)
    b = np.arcsin(sin_b)
    cos_b = np.sqrt(np.maximum(1.0 - sin_b**2, 0.0))
    locked = cos_b < 1e-9
    a = np.where(locked,
                 np.arctan2(sign * m[..., k, j], m[..., j, j]),
                 np.arctan2(-sign * m[..., j, k], m[..., k, k]))
    c = np.where(locked, 0.0, np.arctan2(-sign * m[..., i, j], m[..., i, i]))
    return np.degrees(np.stack([a, b, c], axis=-1))


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``[..., 3, 3]`` of unit quaternions ``[..., 4]`` (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64)
    out = np.empty(q.shape[:-1] + (3, 3))
    _quats_to_matrices(np.ascontiguousarray(q.reshape(-1, 4)), out.reshape(-1, 3, 3))
    return out


@njit(cache=True)
def _quats_to_matrices(quats: np.ndarray, out: np.ndarray) -> None:
    """``out [N, 3, 3]``: the rotation matrix of each unit quaternion of ``quats [N, 4]``."""
    for i in range(quats.shape[0]):
        quat_to_matrix_into(quats[i], out[i])


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[..., 4]`` with ``w >= 0`` of rotation matrices ``[..., 3, 3]`` (NaN where a
    matrix's diagonal is)."""
    m = np.asarray(m, dtype=np.float64)
    out = np.empty(m.shape[:-2] + (4,))
    _matrices_to_quats(np.ascontiguousarray(m.reshape(-1, 3, 3)), out.reshape(-1, 4))
    return out


@njit(cache=True)
def _matrices_to_quats(matrices: np.ndarray, out: np.ndarray) -> None:
    """``out [N, 4]``: the unit quaternion (``w >= 0``) of each rotation matrix of ``matrices [N, 3, 3]``,
    from its largest component's magnitude (numerically stable; the first of equals, the first NaN)."""
    cand = np.empty(4)
    for i in range(matrices.shape[0]):
        m = matrices[i]
        trace = m[0, 0] + m[1, 1] + m[2, 2]
        cand[0] = 1 + trace
        cand[1] = 1 + m[0, 0] - m[1, 1] - m[2, 2]
        cand[2] = 1 - m[0, 0] + m[1, 1] - m[2, 2]
        cand[3] = 1 - m[0, 0] - m[1, 1] + m[2, 2]
        best = 0
        for k in range(4):
            if cand[k] != cand[k] or cand[k] > cand[best]:
                best = k
                if cand[k] != cand[k]:
                    break
        largest = cand[best]
        r = np.sqrt(largest if not largest <= 1e-300 else 1e-300)   # NaN stays NaN
        s = 0.5 / r
        d21, d02, d10 = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]
        s21, s02, s10 = m[2, 1] + m[1, 2], m[0, 2] + m[2, 0], m[1, 0] + m[0, 1]
        q = out[i]
        if best == 0:
            q[0], q[1], q[2], q[3] = 0.5 * r, d21 * s, d02 * s, d10 * s
        elif best == 1:
            q[0], q[1], q[2], q[3] = d21 * s, 0.5 * r, s10 * s, s02 * s
        elif best == 2:
            q[0], q[1], q[2], q[3] = d02 * s, s10 * s, 0.5 * r, s21 * s
        else:
            q[0], q[1], q[2], q[3] = d10 * s, s02 * s, s21 * s, 0.5 * r
        norm = np.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
        sign = -1.0 if q[0] / norm < 0 else 1.0
        for k in range(4):
            q[k] = sign * (q[k] / norm)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a * b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate (the inverse of a unit quaternion)."""
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def quat_geodesic(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``‖log(a⁻¹ b)‖``: half the rotation angle between ``a`` and ``b`` in radians, in ``[0, π/2]``.

    This is the per-joint term of Lee et al.'s skeleton distance (the method's Eq. 2); it is
    the same for ``b`` and ``-b`` (the quaternion double cover).
    """
    dot = np.abs(np.sum(np.asarray(a) * np.asarray(b), axis=-1))
    return np.arccos(np.clip(dot, 0.0, 1.0))


def slerp(a: np.ndarray, b: np.ndarray, share: np.ndarray | float) -> np.ndarray:
    """``share [...]`` of the way from unit vectors ``a [..., n]`` to ``b [..., n]`` along the great circle
    (directions, or quaternions in ``a``'s hemisphere: the caller aligns their signs); broadcast."""
    a, b, share, shape = _rows(a, b, share)
    out = np.empty(share.shape + (shape[-1],))
    _slerp_rows(a, b, share, out)
    return out.reshape(shape)


def quat_turned_towards(a: np.ndarray, b: np.ndarray, max_angle_rad: np.ndarray | float) -> np.ndarray:
    """Unit quaternions ``b [..., 4]``, or where ``b`` is more than ``max_angle_rad [...]`` from ``a [..., 4]``,
    the rotation that far from ``a`` towards it (a speed limit over one step); ``b``'s sign aligned to ``a``."""
    a, b, limit, shape = _rows(a, b, max_angle_rad)
    out = np.empty(limit.shape + (shape[-1],))
    _turned_towards_rows(a, b, limit, out)
    return out.reshape(shape)


def _rows(a: np.ndarray, b: np.ndarray, per_row: np.ndarray | float
          ) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    """``a, b [..., n]`` and ``per_row [...]`` broadcast together and flattened to rows ``[R, n]``,
    ``[R, n]``, ``[R]`` (contiguous float64), and the broadcast shape ``(..., n)``."""
    a, b, per_row = (np.asarray(v, dtype=np.float64) for v in (a, b, per_row))
    rows = (-1, a.shape[-1])
    if a.shape == b.shape and per_row.shape in ((), a.shape[:-1]):   # the usual case, without broadcasting's cost
        return (np.ascontiguousarray(a.reshape(rows)), np.ascontiguousarray(b.reshape(rows)),
                np.ascontiguousarray(np.broadcast_to(per_row, a.shape[:-1]).reshape(-1)), a.shape)
    shape = np.broadcast_shapes(a.shape, b.shape, per_row.shape + (1,))
    rows = (-1, shape[-1])
    return (np.ascontiguousarray(np.broadcast_to(a, shape).reshape(rows)),
            np.ascontiguousarray(np.broadcast_to(b, shape).reshape(rows)),
            np.ascontiguousarray(np.broadcast_to(per_row[..., None], shape)[..., 0].reshape(-1)), shape)


@njit(cache=True, error_model="numpy")   # x / 0: inf or NaN, as NumPy
def _slerp_row(a: np.ndarray, b: np.ndarray, share: float, out: np.ndarray) -> None:
    """``out [n]``: :func:`slerp` of one row (NaN in, NaN out)."""
    dot = 0.0
    for k in range(a.shape[0]):
        dot += a[k] * b[k]
    dot = 1.0 if dot > 1.0 else (-1.0 if dot < -1.0 else dot)
    theta = np.arccos(dot)
    if theta < 1e-6:
        wa, wb = 1.0 - share, share
    else:
        sin = np.sin(theta)
        wa, wb = np.sin((1.0 - share) * theta) / sin, np.sin(share * theta) / sin
    norm = 0.0
    for k in range(a.shape[0]):
        out[k] = wa * a[k] + wb * b[k]
        norm += out[k] * out[k]
    norm = np.sqrt(norm)
    for k in range(a.shape[0]):
        out[k] /= norm


@njit(cache=True, error_model="numpy")   # x / 0: inf or NaN, as NumPy
def _slerp_rows(a: np.ndarray, b: np.ndarray, share: np.ndarray, out: np.ndarray) -> None:
    """``out [R, n]``: :func:`slerp` row by row."""
    for r in range(a.shape[0]):
        _slerp_row(a[r], b[r], share[r], out[r])


@njit(cache=True, error_model="numpy")   # x / 0: inf or NaN, as NumPy
def _turned_towards_rows(a: np.ndarray, b: np.ndarray, limit: np.ndarray, out: np.ndarray) -> None:
    """``out [R, 4]``: :func:`quat_turned_towards` row by row (NaN in, NaN out)."""
    aligned = np.empty(a.shape[1])
    for r in range(a.shape[0]):
        dot = 0.0
        for k in range(a.shape[1]):
            dot += a[r, k] * b[r, k]
        sign = -1.0 if dot < 0 else 1.0
        for k in range(a.shape[1]):
            aligned[k] = sign * b[r, k]
        cos = abs(dot)
        angle = 2.0 * np.arccos(1.0 if cos > 1.0 else cos)
        share = limit[r] / (1e-12 if angle < 1e-12 else angle)
        _slerp_row(a[r], aligned, 1.0 if share > 1.0 else share, out[r])


def yaw_matrix(yaw_deg: float | np.ndarray) -> np.ndarray:
    """Rotations ``[..., 3, 3]`` about the vertical (y) axis by ``yaw_deg`` degrees (right-handed)."""
    return axis_rotation_matrices("Y", np.radians(np.asarray(yaw_deg, dtype=np.float64)))


def frame_from_axes(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frames ``[..., 3, 3]`` whose columns are ``(p, s', p × s')``.

    ``p`` is ``primary`` normalised and ``s'`` is ``secondary`` made orthogonal to ``p`` (Gram–Schmidt).
    """
    p = primary / np.linalg.norm(primary, axis=-1, keepdims=True)
    s = secondary - np.sum(secondary * p, axis=-1, keepdims=True) * p
    s /= np.linalg.norm(s, axis=-1, keepdims=True)
    return np.stack([p, s, np.cross(p, s)], axis=-1)


def kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation ``R [..., 3, 3]`` best taking directions ``a [..., N, 3]`` to ``b`` (Kabsch: least
    squares, no reflection)."""
    u, _, vt = np.linalg.svd(np.einsum("...ni,...nj->...ij", b, a))
    fix = np.ones(u.shape[:-2] + (3,))
    fix[..., 2] = np.sign(np.linalg.det(u @ vt))
    return (u * fix[..., None, :]) @ vt


def camera_axes_world() -> np.ndarray:
    """World→camera rotation of ``cameras.DatabaseCamera`` in OpenCV axes (x right, y down, z forward)."""
    return np.diag([1.0, -1.0, -1.0])


def project_pinhole(points_cam: np.ndarray, focal_px: float, center_px: tuple[float, float]) -> np.ndarray:
    """Project points in OpenCV camera axes ``[..., 3]`` (metres) to pixels ``[..., 2]``."""
    z = points_cam[..., 2:3]
    return points_cam[..., :2] * (focal_px / z) + np.asarray(center_px)


def project_views(positions_m: np.ndarray, pelvis_m: np.ndarray, yaws_deg: np.ndarray,
                  floor_y_m: float, camera: DatabaseCamera) -> np.ndarray:
    """Turn each frame's skeleton about the vertical axis through its pelvis and project it.

    ``positions_m [F, J, 3]`` in the mocap world, ``pelvis_m [F, 3]``; returns pixels
    ``[F, V, J, 2]`` for the ``V`` yaws. The camera follows the pelvis horizontally (so the subject
    stays centred) and stays ``camera.height_m`` above ``floor_y_m``.
    """
    rel = positions_m - pelvis_m[:, None, :]                       # [F, J, 3]
    turned = np.einsum("vab,fjb->fvja", yaw_matrix(yaws_deg), rel)  # [F, V, J, 3]
    cam = np.empty_like(turned)
    cam[..., 0] = turned[..., 0]
    cam[..., 1] = (floor_y_m + camera.height_m) - (turned[..., 1] + pelvis_m[:, None, None, 1])
    cam[..., 2] = camera.distance_m - turned[..., 2]
    return project_pinhole(cam, camera.focal_px, camera.center_px)


HIPS = (KP["r_hip"], KP["l_hip"])   # the right and left hip among the 14 keypoints (their mid-point: a pose's origin)


def normalize_pose_2d(points_px: np.ndarray, visible: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The method's scaling step, shared by builder and runtime (``kernels.pose_normalisation_into``).

    Moves the mid-hip point (``r_hip`` and ``l_hip``; the visible one if only one is) to the
    origin and scales so the bounding box of the visible joints is :data:`NORMALISED_HEIGHT` high.
    ``points_px [..., 14, 2]``; ``visible [..., 14]`` (default all). Returns
    ``(normalised, origin_px [..., 2], scale [...])`` with ``normalised = (p - origin) * scale``.
    Invisible joints are set to 0; a pose with no height or no visible hip gets scale 0.
    """
    pts = np.asarray(points_px, dtype=np.float64)
    if visible is None:
        visible = np.ones(pts.shape[:-1], dtype=np.bool_)
    r_hip, l_hip = HIPS
    if pts.ndim == 2:  # one pose: the runtime's per-frame call, kept lean
        out, origin, scale = _normalize_kernel(pts[None], np.asarray(visible, dtype=np.bool_)[None], r_hip, l_hip)
        return out[0], origin[0], scale[0]
    lead = pts.shape[:-2]
    vis = np.broadcast_to(np.asarray(visible, dtype=np.bool_), pts.shape[:-1])
    flat_pts = np.ascontiguousarray(pts.reshape(-1, pts.shape[-2], 2))
    flat_vis = np.ascontiguousarray(vis.reshape(-1, pts.shape[-2]))
    out, origin, scale = _normalize_kernel(flat_pts, flat_vis, r_hip, l_hip)
    return out.reshape(pts.shape), origin.reshape(lead + (2,)), scale.reshape(lead)


@njit(cache=True)
def _normalize_kernel(pts: np.ndarray, vis: np.ndarray, r_hip: int, l_hip: int):
    """Normalise poses ``pts [n, J, 2]`` over their own visible joints ``vis [n, J]``."""
    n, n_joints = pts.shape[0], pts.shape[1]
    xs, ys = pts[:, :, 0].T, pts[:, :, 1].T  # joint-major views [J, n]
    out = np.zeros_like(pts)
    origin = np.zeros((n, 2))
    scale = np.zeros(n)
    joints = np.empty(n_joints, dtype=np.int64)
    top, bottom, ox, oy = np.empty(1), np.empty(1), np.empty(1), np.empty(1)
    for i in range(n):
        m = 0
        for k in range(n_joints):
            if vis[i, k]:
                joints[m] = k
                m += 1
        pose_normalisation_into(xs, ys, i, i + 1, joints[:m], r_hip, l_hip, top, bottom, ox, oy, scale[i:i + 1])
        origin[i, 0], origin[i, 1] = ox[0], oy[0]
        if scale[i] == 0.0 or not (vis[i, r_hip] or vis[i, l_hip]):
            scale[i] = 0.0
            continue
        for k in range(n_joints):
            if vis[i, k]:
                out[i, k, 0] = (pts[i, k, 0] - origin[i, 0]) * scale[i]
                out[i, k, 1] = (pts[i, k, 1] - origin[i, 1]) * scale[i]
    return out, origin, scale
