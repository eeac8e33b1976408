"""2D refinement after retrieval: the retrieved pose is the prior, a robust fit to the image the output.

Unknowns (36): the root position ``t`` (metres, view frame) and, for each of the 11 rig joints
(the root included: a tilted camera shows the body tilted on all three axes), a rotation
increment ``δ_j`` in the joint's own frame, ``q_j ← q_j ⊗ exp(δ_j)``. Bones are the track's own
body (its estimated proportions, :class:`~mocapdb.runtime.world.body_size.BoneLengths`) times its scale,
fixed during the fit.

Cost, with re-projection residuals in units of the person's box height ``h`` (pixels) and
rotations in radians::

    Σ_k c_k ρ(‖π(p_k) − x_k‖² / h²)               confident keypoints x_k (confidence c_k)
  + Σ_j λ_j ‖log(r_j⁻¹ q_j)‖²                       near the retrieved pose r: it carries the depth
                                                     order the image cannot (λ_root for the root)
  + λ_prev Σ_j ‖log(p_j⁻¹ q_j)‖²                    near the track's previous refined pose p
  + λ_limit Σ_{j≠root} Σ_a d(log(q_j)_a, [lo, hi])²  inside the joint limits (:class:`JointLimits`)
  + Σ_b w_b ρ_w(‖u_b − e_b‖²)                       bones u_b along the detector's own 3D e_b (optional)

``π`` is the pinhole camera at the view frame's origin looking along −z. ``ρ(s) = s c²/(s + c²)``
(Geman–McClure, ``c`` = :attr:`RefineParams.robust_scale`): a keypoint far off (a left/right swap,
a hand found on the background) costs at most ``c²`` and stops pulling its limb.

The last term is given per call (:class:`WorldBones`; none by default): unit directions ``e_b`` of
bones between two of the 14 keypoints in the view frame (the detector's world landmarks,
:mod:`mocapdb.runtime.world.detector_prior`) with weights ``w_b``; ``u_b`` is the fitted bone's direction;
``ρ_w`` is Geman–McClure at :attr:`RefineParams.world_scale`, so a bone the detector got the wrong
way round (a left/right or front/back swap) stops pulling once it is far off.

Levenberg–Marquardt with analytic Jacobians and IRLS weights for a fixed number of iterations,
in one numba kernel that allocates nothing (:class:`Refiner` owns the work arrays). A keypoint
``p`` below joint ``j`` moves by ``dp = −[p − o_j]× G_j δ_j`` (``o_j``, ``G_j``: the joint's
global position and rotation); the prior residuals use the inverse right Jacobian of SO(3).
Cost per call O(iterations · (14 keypoints · 5² blocks + 36³ / 6)): ~10 µs per iteration.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocapdb.core.kernels import (
    cholesky_solve_into,
    quat_exp_into,
    quat_log_into,
    quat_mul_into,
    quat_relative_log_into,
    right_jacobian_inverse_into,
)
from mocapdb.core.skeleton import (
    JOINT_NODE,
    N_KEYPOINTS_2D,
    N_RIG_JOINTS,
    NODE_JOINT,
    NODE_OF_POINT,
    NODE_OFFSETS_M,
    NODE_PARENTS,
    rig_globals_into,
)

N_PARAMS = 3 + 3 * N_RIG_JOINTS
MAX_CHAIN = 4  # rotation joints above a keypoint at most (wrist: pelvis, spine, shoulder, elbow)


@dataclass(frozen=True)
class RefineParams:
    """Weights of the refinement cost (see the module docstring); residuals in box heights."""

    iterations: int = 6
    robust_scale: float = 0.08     # c: re-projection error (box heights) where ρ is half its cap
    prior_root: float = 0.0005     # λ_root: near the retrieved root orientation (per rad²)
    prior_joint: float = 0.001     # λ_j: near the retrieved joint rotations
    previous: float = 0.002        # λ_prev: near the track's previous refined pose
    limits: float = 1.0            # λ_limit: outside the joint limits
    damping: float = 1e-3          # initial Levenberg–Marquardt damping (relative to the diagonal)
    world: float = 0.01            # λ_w: the detector's world bones (× each bone's weight; 0: not used)
    world_scale: float = 1.0       # c_w: a world bone's direction error (chord: 1 = 60°) where ρ_w is half its cap

    def __post_init__(self) -> None:
        if self.iterations < 0 or self.robust_scale <= 0 or self.world_scale <= 0:
            raise ValueError(f"iterations must be >= 0, robust_scale and world_scale positive: {self}")
        if min(self.prior_root, self.prior_joint, self.previous, self.limits, self.damping, self.world) < 0:
            raise ValueError(f"refinement weights must be non-negative: {self}")

    def as_array(self) -> np.ndarray:
        return np.array([self.robust_scale, self.prior_root, self.prior_joint, self.previous,
                         self.limits, self.damping, self.world_scale])


@dataclass(frozen=True)
class WorldBones:
    """Bones ``start → end`` (indices among the 14 keypoints, ``[B]`` each) with the directions the
    detector's 3D gives them, ``directions [B, 3]`` (unit, view frame), and their weights ``[B]`` (0:
    not used)."""

    start: np.ndarray
    end: np.ndarray
    directions: np.ndarray
    weights: np.ndarray

    def as_tuple(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        return (np.ascontiguousarray(self.start, dtype=np.int64), np.ascontiguousarray(self.end, dtype=np.int64),
                np.ascontiguousarray(self.directions, dtype=np.float64),
                np.ascontiguousarray(self.weights, dtype=np.float64))


NO_WORLD = WorldBones(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)).as_tuple()


@dataclass(frozen=True)
class JointLimits:
    """Per joint and axis, the range of ``log(q_j)`` (rotation vector in the parent's frame, radians).

    Taken from the database's own motion (every captured pose is humanly possible): the 0.1 and
    99.9 percentiles of each component over all frames, widened by ``margin_deg``. The root has
    no limit (rows 0 are ±∞).
    """

    lo: np.ndarray  # [R, 3]
    hi: np.ndarray  # [R, 3]

    @classmethod
    def from_rotations(cls, quats: np.ndarray, margin_deg: float = 10.0,
                       percentile: float = 0.1) -> "JointLimits":
        logs = rotation_vectors(quats.reshape(-1, N_RIG_JOINTS, 4))
        margin = np.radians(margin_deg)
        lo = np.percentile(logs, percentile, axis=0) - margin
        hi = np.percentile(logs, 100.0 - percentile, axis=0) + margin
        lo[0], hi[0] = -np.inf, np.inf
        return cls(np.ascontiguousarray(lo), np.ascontiguousarray(hi))


def rotation_vectors(quats: np.ndarray) -> np.ndarray:
    """Rotation vectors ``[..., 3]`` (radians, |angle| ≤ π) of unit quaternions ``[..., 4]``."""
    q = np.asarray(quats, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    sin_half = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    return q[..., 1:] * np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-12), 2.0)


def _ancestor_joints() -> np.ndarray:
    """Per 2D keypoint, the rotation joints (rows of RIG_JOINTS) above it, nearest first, −1 padded."""
    out = np.full((N_KEYPOINTS_2D, MAX_CHAIN), -1, dtype=np.int64)
    for k in range(N_KEYPOINTS_2D):
        chain, node = [], NODE_PARENTS[NODE_OF_POINT[k]]
        while node >= 0:
            if NODE_JOINT[node] >= 0:
                chain.append(NODE_JOINT[node])
            node = NODE_PARENTS[node]
        out[k, :len(chain)] = chain
    return out


_RIG = (NODE_PARENTS.astype(np.int64), np.ascontiguousarray(NODE_OFFSETS_M, dtype=np.float64),
        NODE_JOINT.astype(np.int64), NODE_OF_POINT[:N_KEYPOINTS_2D].astype(np.int64),
        _ancestor_joints(), JOINT_NODE.astype(np.int64))


class Refiner:
    """Refines poses in place; owns the kernel's work arrays (one per engine, not thread-safe)."""

    def __init__(self, params: RefineParams, limits: JointLimits):
        self.params = params
        self.limits = limits
        self._params = params.as_array()
        n_nodes = len(NODE_PARENTS)
        self._ws = (np.empty((n_nodes, 3, 3)), np.empty((n_nodes, 3)), np.empty((3, 3)),
                    np.empty((N_PARAMS, N_PARAMS)), np.empty((N_PARAMS, N_PARAMS)), np.empty(N_PARAMS),
                    np.empty(N_PARAMS), np.empty((N_RIG_JOINTS, 4)), np.empty(3), np.empty(3),
                    np.empty((3, 3)), np.empty((MAX_CHAIN + 1, 2, 3)), np.empty(MAX_CHAIN + 1, dtype=np.int64),
                    np.empty(4), np.empty((2 * MAX_CHAIN, 3, 3)), np.empty(2 * MAX_CHAIN, dtype=np.int64),
                    np.empty(3))

    def __call__(self, quats: np.ndarray, root_m: np.ndarray, scale: float, points_px: np.ndarray,
                 confidence: np.ndarray, prior: np.ndarray, previous: np.ndarray | None,
                 focal_px: float, center_px: tuple[float, float], offsets_m: np.ndarray | None = None,
                 world: WorldBones | None = None) -> float:
        """Refine ``quats [R, 4]`` and ``root_m [3]`` (view frame) in place against ``points_px
        [14, 2]`` weighted by ``confidence [14]`` (0: not seen), on the body of rest offsets
        ``offsets_m`` (``skeleton.body_offsets_m``; default the universal body) times ``scale``, and
        ``world``'s bone directions when given. Returns the final cost."""
        has_previous = previous is not None
        rig = _RIG if offsets_m is None else (_RIG[0], offsets_m) + _RIG[2:]
        return _refine(quats, root_m, float(scale), points_px, confidence, _box_height(points_px, confidence),
                       prior, previous if has_previous else prior, has_previous, float(focal_px),
                       float(center_px[0]), float(center_px[1]), self._params, self.params.iterations,
                       self.limits.lo, self.limits.hi, rig, NO_WORLD if world is None else world.as_tuple(), self._ws)


def _box_height(points_px: np.ndarray, confidence: np.ndarray) -> float:
    ys = points_px[confidence > 0, 1]
    return max(float(ys.max() - ys.min()), 1.0) if len(ys) else 1.0


@njit(cache=True, nogil=True)  # the live writer thread re-fits whole takes beside the stream
def _refine(quats, root, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy,
            params, iterations, lo, hi, rig, world, ws):
    hess, damped, grad, step, q_trial, root_trial = ws[3], ws[4], ws[5], ws[6], ws[7], ws[8]
    mu = params[5]
    cost = _cost(quats, root, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy,
                 params, lo, hi, rig, world, ws)
    stale = True
    for _ in range(iterations):
        if stale:
            _linearise(quats, root, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy,
                       params, lo, hi, rig, world, ws)
            stale = False
        damped[:] = hess
        for i in range(N_PARAMS):
            damped[i, i] += mu * hess[i, i] + 1e-9
        if not cholesky_solve_into(damped, grad, N_PARAMS, step):
            break
        step *= -1.0
        for a in range(3):
            root_trial[a] = root[a] + step[a]
        for j in range(N_RIG_JOINTS):
            quat_exp_into(step[3 + 3 * j:6 + 3 * j], ws[13])
            quat_mul_into(quats[j], ws[13], q_trial[j])
        trial = _cost(q_trial, root_trial, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy,
                      params, lo, hi, rig, world, ws)
        if trial < cost:
            quats[:] = q_trial
            root[:] = root_trial
            cost = trial
            mu = max(mu / 3.0, 1e-9)
            stale = True
        else:
            mu *= 4.0
    return cost


@njit(cache=True)
def _reprojection(g_pos, node, point, focal, cx, cy, box_h):
    """Residual (u, v) in box heights, depth and position of one keypoint; depth ≤ 0: behind."""
    x, y, z = g_pos[node, 0], g_pos[node, 1], g_pos[node, 2]
    depth = -z
    if depth < 1e-3:
        return 0.0, 0.0, depth
    ru = (cx + focal * x / depth - point[0]) / box_h
    rv = (cy - focal * y / depth - point[1]) / box_h
    return ru, rv, depth


@njit(cache=True)
def _cost(quats, root, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy, params, lo, hi, rig, world,
          ws):
    parents, offsets, node_joint, kp_node, _, _ = rig
    g_rot, g_pos, local, v = ws[0], ws[1], ws[2], ws[9]
    rig_globals_into(quats, root, scale, parents, offsets, node_joint, local, g_rot, g_pos)
    c2 = params[0] * params[0]
    total = 0.0
    for k in range(kp_node.shape[0]):
        if conf[k] <= 0.0:
            continue
        ru, rv, depth = _reprojection(g_pos, kp_node[k], points[k], focal, cx, cy, box_h)
        if depth < 1e-3:
            total += conf[k] * c2  # behind the camera: the robust cap
            continue
        s = ru * ru + rv * rv
        total += conf[k] * s * c2 / (s + c2)
    for j in range(quats.shape[0]):
        quat_relative_log_into(prior[j], quats[j], v)
        total += (params[1] if j == 0 else params[2]) * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if has_prev:
            quat_relative_log_into(prev[j], quats[j], v)
            total += params[3] * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        if j > 0:
            quat_log_into(quats[j], v)
            for a in range(3):
                d = _outside(v[a], lo[j, a], hi[j, a])
                total += params[4] * d * d
    cw2 = params[6] * params[6]
    starts, ends, directions, weights = world
    for b in range(weights.shape[0]):
        if weights[b] <= 0.0:
            continue
        s, _ = _bone_residual(g_pos, kp_node[starts[b]], kp_node[ends[b]], directions[b], ws[16])
        total += weights[b] * s * cw2 / (s + cw2)
    return total


@njit(cache=True)
def _bone_residual(g_pos, start, end, direction, r):
    """``r`` = the unit bone ``start → end`` (nodes) minus ``direction``; returns ``(‖r‖², length)``."""
    bx, by, bz = g_pos[end, 0] - g_pos[start, 0], g_pos[end, 1] - g_pos[start, 1], g_pos[end, 2] - g_pos[start, 2]
    length = max(np.sqrt(bx * bx + by * by + bz * bz), 1e-9)
    r[0], r[1], r[2] = bx / length - direction[0], by / length - direction[1], bz / length - direction[2]
    return r[0] * r[0] + r[1] * r[1] + r[2] * r[2], length


@njit(cache=True)
def _outside(value, lo, hi):
    """How far ``value`` lies outside ``[lo, hi]`` (signed; 0 inside)."""
    if value > hi:
        return value - hi
    if value < lo:
        return value - lo
    return 0.0


@njit(cache=True)
def _linearise(quats, root, scale, points, conf, box_h, prior, prev, has_prev, focal, cx, cy, params, lo, hi, rig,
               world, ws):
    """Gauss–Newton normal equations ``ws[3] (H)``, ``ws[5] (g)`` at the current pose (IRLS weights)."""
    parents, offsets, node_joint, kp_node, kp_chain, joint_node = rig
    g_rot, g_pos, local, hess, grad = ws[0], ws[1], ws[2], ws[3], ws[5]
    v, jr, blocks, cols = ws[9], ws[10], ws[11], ws[12]
    rig_globals_into(quats, root, scale, parents, offsets, node_joint, local, g_rot, g_pos)
    hess[:] = 0.0
    grad[:] = 0.0
    c2 = params[0] * params[0]
    for k in range(kp_node.shape[0]):
        if conf[k] <= 0.0:
            continue
        node = kp_node[k]
        ru, rv, depth = _reprojection(g_pos, node, points[k], focal, cx, cy, box_h)
        if depth < 1e-3:
            continue
        s = ru * ru + rv * rv
        w = conf[k] * c2 * c2 / ((s + c2) * (s + c2))
        n_blocks = _keypoint_blocks(g_rot, g_pos, node, kp_chain[k], joint_node, focal, depth, box_h, blocks, cols)
        _accumulate(hess, grad, blocks, cols, n_blocks, w, ru, rv)
    for j in range(quats.shape[0]):
        col = 3 + 3 * j
        quat_relative_log_into(prior[j], quats[j], v)
        _add_rotation_prior(hess, grad, col, v, jr, params[1] if j == 0 else params[2])
        if has_prev:
            quat_relative_log_into(prev[j], quats[j], v)
            _add_rotation_prior(hess, grad, col, v, jr, params[3])
        if j > 0:
            quat_log_into(quats[j], v)
            right_jacobian_inverse_into(v, jr)
            for a in range(3):
                d = _outside(v[a], lo[j, a], hi[j, a])
                if d == 0.0:
                    continue
                for r in range(3):
                    grad[col + r] += params[4] * jr[a, r] * d
                    for c in range(3):
                        hess[col + r, col + c] += params[4] * jr[a, r] * jr[a, c]
    _linearise_world(g_rot, g_pos, kp_node, kp_chain, joint_node, params[6], world, ws)


@njit(cache=True)
def _linearise_world(g_rot, g_pos, kp_node, kp_chain, joint_node, scale_w, world, ws):
    """The world bones' terms added to ``ws[3] (H)``, ``ws[5] (g)`` (IRLS weights of ρ_w): the unit
    bone ``u = b / |b|`` moves by ``(I − u uᵀ) db / |b|``, ``db`` = the end's motion minus the start's."""
    hess, grad, blocks, cols, r = ws[3], ws[5], ws[14], ws[15], ws[16]
    cw2 = scale_w * scale_w
    starts, ends, directions, weights = world
    for b in range(weights.shape[0]):
        if weights[b] <= 0.0:
            continue
        start, end = kp_node[starts[b]], kp_node[ends[b]]
        s, length = _bone_residual(g_pos, start, end, directions[b], r)
        ux = (g_pos[end, 0] - g_pos[start, 0]) / length
        uy = (g_pos[end, 1] - g_pos[start, 1]) / length
        uz = (g_pos[end, 2] - g_pos[start, 2]) / length
        w = weights[b] * cw2 * cw2 / ((s + cw2) * (s + cw2))
        n = 0
        for side in range(2):   # joints above the end move it (+), joints above the start move it (−)
            k, other = (ends[b], starts[b]) if side == 0 else (starts[b], ends[b])
            node = end if side == 0 else start
            sign = 1.0 if side == 0 else -1.0
            for i in range(kp_chain.shape[1]):
                j = kp_chain[k, i]
                if j < 0:
                    break
                if _in_chain(kp_chain[other], j):
                    if side == 1:
                        continue   # above both: counted once, with the whole bone as its lever
                    node_from = start
                else:
                    node_from = joint_node[j]
                ex = g_pos[node, 0] - g_pos[node_from, 0]
                ey = g_pos[node, 1] - g_pos[node_from, 1]
                ez = g_pos[node, 2] - g_pos[node_from, 2]
                jn = joint_node[j]
                for c in range(3):
                    gx, gy, gz = g_rot[jn, 0, c], g_rot[jn, 1, c], g_rot[jn, 2, c]
                    mx = sign * (gy * ez - gz * ey) / length
                    my = sign * (gz * ex - gx * ez) / length
                    mz = sign * (gx * ey - gy * ex) / length
                    dot = ux * mx + uy * my + uz * mz
                    blocks[n, 0, c], blocks[n, 1, c], blocks[n, 2, c] = mx - dot * ux, my - dot * uy, mz - dot * uz
                cols[n] = 3 + 3 * j
                n += 1
        for bi in range(n):
            ci = cols[bi]
            for rr in range(3):
                grad[ci + rr] += w * (blocks[bi, 0, rr] * r[0] + blocks[bi, 1, rr] * r[1] + blocks[bi, 2, rr] * r[2])
                for bj in range(n):
                    cj = cols[bj]
                    for c in range(3):
                        hess[ci + rr, cj + c] += w * (blocks[bi, 0, rr] * blocks[bj, 0, c] +
                                                      blocks[bi, 1, rr] * blocks[bj, 1, c] +
                                                      blocks[bi, 2, rr] * blocks[bj, 2, c])


@njit(cache=True)
def _in_chain(chain, j):
    for i in range(chain.shape[0]):
        if chain[i] == j:
            return True
    return False


@njit(cache=True)
def _keypoint_blocks(g_rot, g_pos, node, chain, joint_node, focal, depth, box_h, blocks, cols):
    """Jacobian blocks ``[n, 2, 3]`` of one keypoint's residual (translation, then each joint above)."""
    x, y = g_pos[node, 0], g_pos[node, 1]
    a = focal / (depth * box_h)
    # d(residual)/d(position): u row (a, 0, a x / depth), v row (0, −a, −a y / depth)
    pu0, pu2 = a, a * x / depth
    pv1, pv2 = -a, -a * y / depth
    blocks[0, 0, 0], blocks[0, 0, 1], blocks[0, 0, 2] = pu0, 0.0, pu2
    blocks[0, 1, 0], blocks[0, 1, 1], blocks[0, 1, 2] = 0.0, pv1, pv2
    cols[0] = 0
    n = 1
    for i in range(chain.shape[0]):
        j = chain[i]
        if j < 0:
            break
        jn = joint_node[j]
        ex, ey, ez = g_pos[node, 0] - g_pos[jn, 0], g_pos[node, 1] - g_pos[jn, 1], g_pos[node, 2] - g_pos[jn, 2]
        for c in range(3):
            gx, gy, gz = g_rot[jn, 0, c], g_rot[jn, 1, c], g_rot[jn, 2, c]
            # dp/dδ_c = G[:, c] × e
            mx, my, mz = gy * ez - gz * ey, gz * ex - gx * ez, gx * ey - gy * ex
            blocks[n, 0, c] = pu0 * mx + pu2 * mz
            blocks[n, 1, c] = pv1 * my + pv2 * mz
        cols[n] = 3 + 3 * j
        n += 1
    return n


@njit(cache=True)
def _accumulate(hess, grad, blocks, cols, n_blocks, w, ru, rv):
    """``H += w JᵀJ``, ``g += w Jᵀr`` for one keypoint's sparse Jacobian blocks."""
    for bi in range(n_blocks):
        ci = cols[bi]
        for r in range(3):
            ju, jv = blocks[bi, 0, r], blocks[bi, 1, r]
            grad[ci + r] += w * (ju * ru + jv * rv)
            for bj in range(n_blocks):
                cj = cols[bj]
                for c in range(3):
                    hess[ci + r, cj + c] += w * (ju * blocks[bj, 0, c] + jv * blocks[bj, 1, c])


@njit(cache=True)
def _add_rotation_prior(hess, grad, col, e, jr, weight):
    """``λ ‖e + J δ‖²`` with ``J = J_r⁻¹(e)`` added to the normal equations of joint block ``col``."""
    if weight <= 0.0:
        return
    right_jacobian_inverse_into(e, jr)
    for r in range(3):
        g = 0.0
        for i in range(3):
            g += jr[i, r] * e[i]
        grad[col + r] += weight * g
        for c in range(3):
            h = 0.0
            for i in range(3):
                h += jr[i, r] * jr[i, c]
            hess[col + r, col + c] += weight * h
