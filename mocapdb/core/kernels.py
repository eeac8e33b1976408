"""Numba primitives on 3-vectors, rotation matrices and quaternions, for hot loops.

Each writes into an output argument, so kernels that call them per joint and per iteration
allocate nothing. Quaternions are ``(w, x, y, z)`` and act on column vectors; a rotation vector
is axis × angle (radians, the full angle); ``[v]×`` is the cross-product matrix of ``v``.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def quat_to_matrix_into(q: np.ndarray, out: np.ndarray) -> None:
    """``out [3, 3]`` = the rotation matrix of unit quaternion ``q [4]``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    out[0, 0], out[0, 1], out[0, 2] = 1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)
    out[1, 0], out[1, 1], out[1, 2] = 2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)
    out[2, 0], out[2, 1], out[2, 2] = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)


@njit(cache=True)
def quat_mul_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a * b`` (Hamilton product: ``b`` applied first). ``out`` may not alias ``a`` or ``b``."""
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]


@njit(cache=True)
def quat_relative_log_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out [3]`` = ``log(a⁻¹ b)``: the rotation vector from ``a`` to ``b`` (shortest, |angle| ≤ π)."""
    w = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    x = a[0] * b[1] - a[1] * b[0] - a[2] * b[3] + a[3] * b[2]
    y = a[0] * b[2] + a[1] * b[3] - a[2] * b[0] - a[3] * b[1]
    z = a[0] * b[3] - a[1] * b[2] + a[2] * b[1] - a[3] * b[0]
    _log_parts_into(w, x, y, z, out)


@njit(cache=True)
def quat_log_into(q: np.ndarray, out: np.ndarray) -> None:
    """``out [3]`` = the rotation vector of unit quaternion ``q`` (shortest, |angle| ≤ π)."""
    _log_parts_into(q[0], q[1], q[2], q[3], out)


@njit(cache=True)
def _log_parts_into(w: float, x: float, y: float, z: float, out: np.ndarray) -> None:
    if w < 0.0:
        w, x, y, z = -w, -x, -y, -z
    sin_half = np.sqrt(x * x + y * y + z * z)
    # angle / sin(angle / 2); tends to 2 as the angle goes to 0.
    k = 2.0 * np.arctan2(sin_half, w) / sin_half if sin_half > 1e-12 else 2.0 / max(w, 1e-12)
    out[0], out[1], out[2] = k * x, k * y, k * z


@njit(cache=True)
def quat_exp_into(v: np.ndarray, out: np.ndarray) -> None:
    """``out [4]`` = the unit quaternion of rotation vector ``v [3]``."""
    angle = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    half = 0.5 * angle
    k = np.sin(half) / angle if angle > 1e-12 else 0.5
    out[0], out[1], out[2], out[3] = np.cos(half), k * v[0], k * v[1], k * v[2]


@njit(cache=True)
def right_jacobian_inverse_into(phi: np.ndarray, out: np.ndarray) -> None:
    """``out [3, 3]`` = ``J_r⁻¹(φ)``: ``log(exp(φ) exp(δ)) ≈ φ + J_r⁻¹(φ) δ`` for small ``δ``.

    ``J_r⁻¹(φ) = I + ½[φ]× + (1/θ² − (1 + cos θ) / (2 θ sin θ)) [φ]×²`` with ``θ = |φ|``.
    """
    theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    theta = np.sqrt(theta2)
    if theta < 1e-6:
        c = 1.0 / 12.0
    elif theta > np.pi - 1e-6:
        c = 1.0 / theta2
    else:
        c = 1.0 / theta2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))
    x, y, z = phi[0], phi[1], phi[2]
    # [φ]×² = φφᵀ − θ² I
    out[0, 0] = 1.0 + c * (x * x - theta2)
    out[1, 1] = 1.0 + c * (y * y - theta2)
    out[2, 2] = 1.0 + c * (z * z - theta2)
    out[0, 1] = -0.5 * z + c * x * y
    out[1, 0] = 0.5 * z + c * x * y
    out[0, 2] = 0.5 * y + c * x * z
    out[2, 0] = -0.5 * y + c * x * z
    out[1, 2] = -0.5 * x + c * y * z
    out[2, 1] = 0.5 * x + c * y * z


@njit(cache=True)
def mat3_mul_into(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    """``out = a @ b`` for 3 × 3 matrices; ``out`` may not alias ``a`` or ``b``."""
    for i in range(3):
        for j in range(3):
            out[i, j] = a[i, 0] * b[0, j] + a[i, 1] * b[1, j] + a[i, 2] * b[2, j]


@njit(cache=True)
def cholesky_solve_into(a: np.ndarray, b: np.ndarray, n: int, out: np.ndarray) -> bool:
    """Solve ``a x = b`` for symmetric positive-definite ``a [n, n]`` (overwritten by its
    Cholesky factor); ``out [n]`` gets ``x``. Returns False (``out`` untouched) if ``a`` is not
    positive definite."""
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= a[j, k] * a[j, k]
        if s <= 0.0 or not np.isfinite(s):
            return False
        a[j, j] = np.sqrt(s)
        for i in range(j + 1, n):
            s = a[i, j]
            for k in range(j):
                s -= a[i, k] * a[j, k]
            a[i, j] = s / a[j, j]
    for i in range(n):  # L y = b
        s = b[i]
        for k in range(i):
            s -= a[i, k] * out[k]
        out[i] = s / a[i, i]
    for i in range(n - 1, -1, -1):  # Lᵀ x = y
        s = out[i]
        for k in range(i + 1, n):
            s -= a[k, i] * out[k]
        out[i] = s / a[i, i]
    return True


@njit(cache=True)
def quat_abs_dot(a: np.ndarray, b: np.ndarray) -> float:
    """``|a · b|`` of quaternions ``a, b [4]``: the cosine of half the angle between them."""
    return abs(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3])


# Poses in the joint-major layout: ``xs [J, P]`` and ``ys [J, P]`` hold the x and y of joint ``k``
# of pose ``i`` at ``[k, i]``, so loops over poses are contiguous (SIMD). 2D pose units: pixels or
# normalised box heights, whatever the caller stores.

@njit(cache=True, fastmath=True)
def pose_distances_into(xs: np.ndarray, ys: np.ndarray, lo: int, hi: int, query: np.ndarray,
                        joints: np.ndarray, out: np.ndarray) -> None:
    """The method's Eq. 1 pose distance: ``out[i] += Σ_{k ∈ joints} ‖p_{lo+i, k} − query[k]‖``.

    ``xs, ys [J, P]`` joint-major poses (columns ``lo:hi`` used), ``query [J, 2]`` of the poses'
    dtype (a float64 query against float32 poses would difference in float64), ``joints [n]``
    int indices, ``out [hi - lo]`` accumulated in its own dtype (zero it first). Euclidean
    distances per joint, not squared.
    """
    for k in joints:
        qx, qy = query[k, 0], query[k, 1]
        xk, yk = xs[k, lo:hi], ys[k, lo:hi]
        for i in range(hi - lo):
            dx = xk[i] - qx
            dy = yk[i] - qy
            out[i] += np.sqrt(dx * dx + dy * dy)


@njit(cache=True, fastmath=True)
def renormalised_pose_distances_into(xs: np.ndarray, ys: np.ndarray, lo: int, hi: int, query: np.ndarray,
                                     joints: np.ndarray, origin_x: np.ndarray, origin_y: np.ndarray,
                                     scale: np.ndarray, out: np.ndarray) -> None:
    """Eq. 1 as :func:`pose_distances_into` with pose ``i`` first mapped to
    ``(p − origin[i]) · scale[i]`` (``origin_x, origin_y, scale [hi - lo]``, see
    :func:`pose_normalisation_into`)."""
    for k in joints:
        qx, qy = query[k, 0], query[k, 1]
        for i in range(hi - lo):
            dx = (xs[k, lo + i] - origin_x[i]) * scale[i] - qx
            dy = (ys[k, lo + i] - origin_y[i]) * scale[i] - qy
            out[i] += np.sqrt(dx * dx + dy * dy)


NORMALISED_HEIGHT = 1.0  # bounding-box height of every normalised 2D pose (unitless)


@njit(cache=True)
def pose_normalisation_into(xs: np.ndarray, ys: np.ndarray, lo: int, hi: int, joints: np.ndarray,
                            r_hip: int, l_hip: int, top: np.ndarray, bottom: np.ndarray,
                            origin_x: np.ndarray, origin_y: np.ndarray, scale: np.ndarray) -> None:
    """The method's 2D scaling step for poses ``lo:hi`` of joint-major ``xs, ys [J, P]`` over the
    visible joints ``joints [n]`` (int indices, the same for every pose).

    ``origin [hi - lo]`` = the mid-point of joints ``r_hip`` and ``l_hip`` (the one in ``joints``
    if only one is; both anyway if neither is); ``scale [hi - lo]`` = :data:`NORMALISED_HEIGHT` /
    the height of the box of the visible joints, 0 when that height is ≤ 1e-9 or not finite.
    A normalised pose is ``(p − origin) · scale``. ``top, bottom [hi - lo]`` are scratch; every
    output is stored in its array's dtype (so float32 arrays give float32 results).
    """
    n = hi - lo
    top[:n] = np.inf
    bottom[:n] = -np.inf
    has_r, has_l = False, False
    for k in joints:
        has_r |= k == r_hip
        has_l |= k == l_hip
        yk = ys[k, lo:hi]
        for i in range(n):
            top[i] = min(top[i], yk[i])
            bottom[i] = max(bottom[i], yk[i])
    r = r_hip if has_r else l_hip
    l_ = l_hip if has_l else r_hip
    for i in range(n):
        height = bottom[i] - top[i]
        scale[i] = NORMALISED_HEIGHT / height if height > 1e-9 and np.isfinite(height) else 0.0
        origin_x[i] = 0.5 * (xs[r, lo + i] + xs[l_, lo + i])
        origin_y[i] = 0.5 * (ys[r, lo + i] + ys[l_, lo + i])
