"""The database floor of `mocapdb eval`: how close the database itself comes to a truth pose.

For a truth frame ``a`` (15 pelvis-relative keypoints, world frame, y up, metres) the floor is

    min over database frames f and yaw θ (continuous, about y) of MPJPE(a, R_y(θ) · b_f)

with ``b_f`` database frame f made pelvis-relative. No retrieval engine that outputs database
poses turned about the vertical can do better on that frame (smoothing, which blends frames, and a
2D refinement that leaves the database can). Both sides live in the world frame, so the floor does
not depend on the camera (height, pitch, yaw); it does depend on the database, and must be
computed against the database that is evaluated.

Computation (:func:`database_floor`):

1. For the *sum of squared* distances the best turn has a closed form (2D Procrustes in the
   x-z plane): with ``Y = Σ a_y b_y``, ``C = Σ (a_x b_x + a_z b_z)`` and
   ``S = Σ (a_z b_x − a_x b_z)`` (sums over the 15 keypoints),
   ``min_θ Σ‖a − R(θ) b‖² = ‖a‖² + ‖b‖² − 2 (Y + √(C² + S²))`` at ``θ* = atan2(−S, C)``
   (``R`` as :func:`mocapdb.core.geometry.yaw_matrix`). ``‖b‖²`` is precomputed per database frame,
   so a (truth, database) pair costs the three 15-term sums. A numba kernel (parallel over blocks
   of truth frames, float32 sums, SIMD over database frames) keeps the :data:`TOP_K` database
   frames with the smallest squared error for every truth frame: ~2 s for 2,000 truth frames
   against 550,000 database frames on 2 cores.
2. For those candidates the true MPJPE (mean of per-joint Euclidean distances) is computed in
   float64 at ``θ*``, then improved by up to :data:`TURN_ITERATIONS` Weiszfeld-type steps (the
   squared-optimal turn with joint weights 1/distance, which minimises a majoriser of the summed
   distances, so the MPJPE never increases); the floor is the smallest over the candidates.

Approximation: the MPJPE-best frame might rank below the :data:`TOP_K` squared-error best, and
the reweighting may stop short of the MPJPE-optimal turn. Both only make the result larger: the
floor returned is an upper bound on the exact floor. Measured on 432 CMU subject-2 frames against
the 15,872-frame database without subject 2 (exact: dense 0.25° grid over the 1,000 best frames;
floor 8.3 cm on average): the plain version (32 frames, ``θ*`` only) is 1.06 mm (1.3 %)
above on average, up to 10.5 mm; with 32 frames and the reweighting 0.08 mm, up to 7.2 mm; with
128 frames and the reweighting (the defaults) 0.006 mm, up to 1.2 mm. ``tests/test_evaluate.py``
checks it against a dense θ grid over every frame.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from mocapdb.core.skeleton import N_POINTS, PELVIS

TOP_K = 128          # database frames kept per truth frame by squared error
CHUNK = 1024         # database frames scored together (kept in cache while a block of truth frames runs)
TURN_ITERATIONS = 10  # reweighting steps from the squared-optimal turn towards the MPJPE-optimal one
TRUTH_BLOCK = 16     # truth frames per parallel task
N_JOINTS = N_POINTS  # the 14 keypoints and the pelvis
_PAD = np.float32(1e30)   # squared norm of the padding frames after the last chunk: never among the best
_WORST = np.float32(3e38)


@dataclass
class FloorIndex:
    """Database frames prepared for :func:`database_floor` (pelvis-relative, world frame).

    The squared-error pass reads them chunk-major (``[chunk, joint, frame in chunk]``) so that
    its innermost loop runs over consecutive database frames (SIMD)."""

    by: np.ndarray      # [C, 15, CHUNK] float32: y of every keypoint
    bxz: np.ndarray     # [C, 30, CHUNK] float32: x of the 15 keypoints, then z
    norm2: np.ndarray   # [C, CHUNK] float32: Σ‖b‖² (padding: 1e30)
    rel: np.ndarray     # [F, 15, 3] float64: pelvis-relative keypoints (for the exact MPJPE)

    @classmethod
    def from_positions(cls, positions: np.ndarray) -> FloorIndex:
        """``positions [F, 15, 3]`` (metres, y up), e.g. ``MotionDatabase.positions``."""
        rel = np.asarray(positions, dtype=np.float64)
        rel = rel - rel[:, PELVIS:PELVIS + 1]
        n = len(rel)
        chunks = max(1, -(-n // CHUNK))
        rows = np.zeros((chunks * CHUNK, 3 * N_JOINTS), dtype=np.float32)  # one database frame a row
        rows[:n] = np.concatenate([rel[..., 1], rel[..., 0], rel[..., 2]], axis=1)
        cols = rows.reshape(chunks, CHUNK, 3 * N_JOINTS).transpose(0, 2, 1)
        norm2 = np.full(chunks * CHUNK, _PAD, dtype=np.float32)
        norm2[:n] = np.sum(rel ** 2, axis=(1, 2))
        return cls(by=np.ascontiguousarray(cols[:, :N_JOINTS]), bxz=np.ascontiguousarray(cols[:, N_JOINTS:]),
                   norm2=norm2.reshape(chunks, CHUNK), rel=np.ascontiguousarray(rel))

    @property
    def n_frames(self) -> int:
        return len(self.rel)


@dataclass
class Floor:
    """Per truth frame: the floor (metres), the database frame and the turn (degrees) reaching it."""

    mpjpe_m: np.ndarray  # [T]
    frame: np.ndarray    # [T] database frame index
    yaw_deg: np.ndarray  # [T]


def database_floor(index: FloorIndex, truth: np.ndarray, top_k: int = TOP_K,
                   turn_iterations: int = TURN_ITERATIONS) -> Floor:
    """The floor of every truth frame ``truth [T, 15, 3]`` (metres, world frame, y up) against the
    database ``index`` (see the module docstring for the method and its approximation)."""
    rel = np.asarray(truth, dtype=np.float64)
    rel = rel - rel[:, PELVIS:PELVIS + 1]
    k = max(1, min(top_k, index.n_frames))
    if len(rel) == 0 or index.n_frames == 0:
        return Floor(np.full(len(rel), np.nan), np.full(len(rel), -1, dtype=np.int64), np.zeros(len(rel)))
    ay = np.ascontiguousarray(rel[..., 1], dtype=np.float32)                                      # [T, 15]
    axz = np.ascontiguousarray(np.concatenate([rel[..., 0], rel[..., 2]], axis=1), dtype=np.float32)    # [T, 30]
    aperp = np.ascontiguousarray(np.concatenate([rel[..., 2], -rel[..., 0]], axis=1), dtype=np.float32)  # [T, 30]
    norm_a = np.sum(rel ** 2, axis=(1, 2)).astype(np.float32)
    candidates = _top_k_kernel(ay, axz, aperp, norm_a, index.by, index.bxz, index.norm2, k)
    mpjpe, frame, yaw = _exact_kernel(np.ascontiguousarray(rel), index.rel, candidates, turn_iterations)
    return Floor(mpjpe, frame, np.degrees(yaw))


@njit(cache=True, fastmath=True)
def _score_chunk(cy, cxz, cperp, na, by, bxz, nb, e, sy, sc, ss):
    """``e[f]`` = squared error of one truth frame against the chunk's frames under their best turn."""
    m = e.shape[0]
    for f in range(m):
        sy[f] = 0.0
        sc[f] = 0.0
        ss[f] = 0.0
    for j in range(N_JOINTS):
        a = cy[j]
        for f in range(m):
            sy[f] += a * by[j, f]
    for j in range(2 * N_JOINTS):
        a1, a2 = cxz[j], cperp[j]
        for f in range(m):
            b = bxz[j, f]
            sc[f] += a1 * b
            ss[f] += a2 * b
    for f in range(m):
        e[f] = na + nb[f] - 2.0 * (sy[f] + np.sqrt(sc[f] * sc[f] + ss[f] * ss[f]))


@njit(cache=True, parallel=True)
def _top_k_kernel(ay, axz, aperp, norm_a, by, bxz, norm_b, k):
    """Database frame indices ``[T, k]`` with the smallest squared error under the best turn for
    every truth frame (unordered). Parallel over blocks of truth frames; each block runs every
    database chunk against its truth frames while the chunk is in cache."""
    n, n_chunks = ay.shape[0], by.shape[0]
    out = np.empty((n, k), dtype=np.int64)
    n_blocks = (n + TRUTH_BLOCK - 1) // TRUTH_BLOCK
    for blk in prange(n_blocks):
        t0 = blk * TRUTH_BLOCK
        nt = min(n, t0 + TRUTH_BLOCK) - t0
        best_e = np.full((nt, k), _WORST, dtype=np.float32)
        best_f = np.zeros((nt, k), dtype=np.int64)
        worst = np.zeros(nt, dtype=np.int64)           # slot holding the largest kept error
        thr = np.full(nt, _WORST, dtype=np.float32)     # that error
        e = np.empty(CHUNK, dtype=np.float32)
        sy = np.empty(CHUNK, dtype=np.float32)
        sc = np.empty(CHUNK, dtype=np.float32)
        ss = np.empty(CHUNK, dtype=np.float32)
        for c in range(n_chunks):
            for ti in range(nt):
                t = t0 + ti
                _score_chunk(ay[t], axz[t], aperp[t], norm_a[t], by[c], bxz[c], norm_b[c], e, sy, sc, ss)
                if e.min() >= thr[ti]:
                    continue
                for f in range(CHUNK):
                    if e[f] < thr[ti]:
                        w = worst[ti]
                        best_e[ti, w] = e[f]
                        best_f[ti, w] = c * CHUNK + f
                        m, mi = best_e[ti, 0], 0
                        for i in range(1, k):
                            if best_e[ti, i] > m:
                                m, mi = best_e[ti, i], i
                        worst[ti], thr[ti] = mi, m
        out[t0:t0 + nt] = best_f
    return out


@njit(cache=True)
def _mpjpe_turned(a, b, theta, weights):
    """MPJPE between ``a`` and ``b`` turned by ``theta`` (radians, as ``yaw_matrix``); fills
    ``weights`` with the per-joint distances."""
    ct, st = np.cos(theta), np.sin(theta)
    total = 0.0
    for j in range(N_JOINTS):
        dx = a[j, 0] - (ct * b[j, 0] + st * b[j, 2])
        dy = a[j, 1] - b[j, 1]
        dz = a[j, 2] - (-st * b[j, 0] + ct * b[j, 2])
        weights[j] = np.sqrt(dx * dx + dy * dy + dz * dz)
        total += weights[j]
    return total / N_JOINTS


@njit(cache=True, parallel=True)
def _exact_kernel(truth, db_rel, candidates, turn_iterations):
    """For every truth frame: the smallest MPJPE over its candidate frames, each at its
    squared-optimal turn improved by ``turn_iterations`` reweighting steps; returns
    (mpjpe [T], frame [T], turn in radians [T])."""
    n, k = candidates.shape
    mpjpe = np.empty(n)
    frame = np.empty(n, dtype=np.int64)
    yaw = np.empty(n)
    for t in prange(n):
        a = truth[t]
        dist = np.empty(N_JOINTS)
        best, best_f, best_yaw = np.inf, -1, 0.0
        for i in range(k):
            f = candidates[t, i]
            b = db_rel[f]
            c, s = 0.0, 0.0
            for j in range(N_JOINTS):
                c += a[j, 0] * b[j, 0] + a[j, 2] * b[j, 2]
                s += a[j, 2] * b[j, 0] - a[j, 0] * b[j, 2]
            theta = np.arctan2(-s, c)
            err = _mpjpe_turned(a, b, theta, dist)
            for _ in range(turn_iterations):
                # Weiszfeld-type step: the squared-optimal turn with joint weights 1 / distance
                # minimises a majoriser of the summed distances, so the MPJPE never increases.
                c, s = 0.0, 0.0
                for j in range(N_JOINTS):
                    w = 1.0 / max(dist[j], 1e-9)
                    c += w * (a[j, 0] * b[j, 0] + a[j, 2] * b[j, 2])
                    s += w * (a[j, 2] * b[j, 0] - a[j, 0] * b[j, 2])
                candidate = np.arctan2(-s, c)
                new = _mpjpe_turned(a, b, candidate, dist)
                if new >= err:
                    break
                theta, err = candidate, new
            if err < best:
                best, best_f, best_yaw = err, f, theta
        mpjpe[t] = best
        frame[t] = best_f
        yaw[t] = best_yaw
    return mpjpe, frame, yaw
