"""The method's two-level search over the database's normalised 2D projections (numba).

Clustered search: Eq. 1 distance from the query to every cluster representative (K), keep the
``n_clusters`` nearest clusters, then the ``per_cluster`` nearest members of each: cost
O(K + n_clusters · mean cluster size) pose distances. Exact search: every projection, O(P).

Missing joints: the query is normalised over its visible joints only, and each database pose is
renormalised over the same joints (origin at the mid-hip, or the visible hip; unit height of the
visible joints' box) before the distance, which then sums over the visible joints only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.kernels import pose_distances_into, pose_normalisation_into, renormalised_pose_distances_into
from mocapdb.core.skeleton import KP

R_HIP, L_HIP = KP["r_hip"], KP["l_hip"]  # numba freezes them as constants


@dataclass
class SearchIndex:
    """Database projections reordered so each cluster's members are contiguous.

    Coordinates are stored joint-major (``x[k, i]``) so the distance loops run over poses with
    SIMD; the same layout holds the cluster representatives.
    """

    x: np.ndarray               # [14, P] float32, grouped by cluster
    y: np.ndarray               # [14, P] float32
    rows: np.ndarray            # [P] int64: database projection row of each column
    cluster_start: np.ndarray   # [K + 1] int64: cluster c is columns start[c]:start[c+1]
    rep_x: np.ndarray           # [14, K'] float32: representatives of the non-empty clusters
    rep_y: np.ndarray           # [14, K'] float32
    rep_cluster: np.ndarray     # [K'] int64: their cluster numbers
    column_of_row: np.ndarray   # [P] int64: inverse of ``rows``

    @classmethod
    def from_database(cls, db: MotionDatabase) -> "SearchIndex":
        order = np.argsort(db.cluster, kind="stable")
        counts = np.bincount(db.cluster, minlength=db.n_clusters)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        nonempty = np.flatnonzero(db.representative >= 0)
        poses = db.keypoints_2d[order]
        reps = db.keypoints_2d[db.representative[nonempty]]
        return cls(np.ascontiguousarray(poses[..., 0].T), np.ascontiguousarray(poses[..., 1].T),
                   order.astype(np.int64), start, np.ascontiguousarray(reps[..., 0].T),
                   np.ascontiguousarray(reps[..., 1].T), nonempty.astype(np.int64), np.argsort(order))


@njit(cache=True)
def range_distances(x, y, lo, hi, query, vis_idx, renormalise):
    """Eq. 1 distances ``[hi - lo]`` (float32) from ``query [14, 2]`` (the poses' dtype) to poses lo:hi, over
    joints ``vis_idx``. With ``renormalise`` each pose is first renormalised over those joints."""
    n = hi - lo
    out = np.zeros(n, dtype=np.float32)
    if renormalise:
        top, bottom = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
        ox, oy, s = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
        pose_normalisation_into(x, y, lo, hi, vis_idx, R_HIP, L_HIP, top, bottom, ox, oy, s)
        renormalised_pose_distances_into(x, y, lo, hi, query, vis_idx, ox, oy, s, out)
    else:
        pose_distances_into(x, y, lo, hi, query, vis_idx, out)
    return out


@njit(cache=True)
def _smallest(dist, k, offset):
    """Indices (plus ``offset``) and values of the ``k`` smallest of ``dist``, ascending."""
    best_d = np.full(k, np.inf)
    best_i = np.full(k, -1, dtype=np.int64)
    for i in range(dist.shape[0]):
        d = dist[i]
        if d >= best_d[k - 1]:
            continue
        j = k - 1
        while j > 0 and best_d[j - 1] > d:
            best_d[j] = best_d[j - 1]
            best_i[j] = best_i[j - 1]
            j -= 1
        best_d[j] = d
        best_i[j] = i + offset
    return best_i, best_d


@njit(cache=True)
def _clustered(x, y, cluster_start, rep_x, rep_y, rep_cluster, rows, query, visible, n_clusters, per_cluster):
    vis_idx, renorm = _visible_joints(visible)
    n_rep = rep_x.shape[1]
    top_c, _ = _smallest(range_distances(rep_x, rep_y, 0, n_rep, query, vis_idx, renorm),
                         min(n_clusters, n_rep), 0)
    out_d = np.full(top_c.shape[0] * per_cluster, np.inf)
    out_i = np.full(out_d.shape[0], -1, dtype=np.int64)
    for n in range(top_c.shape[0]):
        c = rep_cluster[top_c[n]]
        lo, hi = cluster_start[c], cluster_start[c + 1]
        best_i, best_d = _smallest(range_distances(x, y, lo, hi, query, vis_idx, renorm), per_cluster, lo)
        out_i[n * per_cluster:(n + 1) * per_cluster] = best_i
        out_d[n * per_cluster:(n + 1) * per_cluster] = best_d
    keep = out_i >= 0
    return rows[out_i[keep]], out_d[keep]


@njit(cache=True)
def _exact(x, y, rows, query, visible, k):
    vis_idx, renorm = _visible_joints(visible)
    best_i, best_d = _smallest(range_distances(x, y, 0, x.shape[1], query, vis_idx, renorm), k, 0)
    keep = best_i >= 0
    return rows[best_i[keep]], best_d[keep]


@njit(cache=True)
def _visible_joints(visible: np.ndarray):
    vis_idx = np.flatnonzero(visible).astype(np.int64)
    return vis_idx, vis_idx.shape[0] < visible.shape[0]


def _query_like(query: np.ndarray, index: SearchIndex) -> np.ndarray:
    """``query`` in the index's dtype (float32): the distance kernels difference in the poses' dtype."""
    return np.ascontiguousarray(query, dtype=index.x.dtype)


def search_clustered(index: SearchIndex, query: np.ndarray, visible: np.ndarray,
                     n_clusters: int = 5, per_cluster: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Candidates of the two-level search: database projection rows and their Eq. 1 distances.

    ``query [14, 2]`` is normalised over ``visible [14]`` (see ``normalize_pose_2d``).
    """
    return _clustered(index.x, index.y, index.cluster_start, index.rep_x, index.rep_y, index.rep_cluster,
                      index.rows, _query_like(query, index), visible, n_clusters, per_cluster)


def search_exact(index: SearchIndex, query: np.ndarray, visible: np.ndarray,
                 k: int = 50) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest projections over the whole database (brute force), nearest first."""
    return _exact(index.x, index.y, index.rows, _query_like(query, index), visible, k)


@njit(cache=True)
def _yaw_offset(x, y, column_of_row, frame, yaw, n_yaws, step_deg, query, visible):
    vis_idx, renorm = _visible_joints(visible)
    d = np.empty(3)
    for n in range(3):
        col = column_of_row[frame * n_yaws + (yaw + n - 1) % n_yaws]
        d[n] = range_distances(x, y, col, col + 1, query, vis_idx, renorm)[0]
    rise = max(d[0], d[2]) - d[1]
    if rise <= 1e-12:
        return 0.0
    return min(max(0.5 * step_deg * (d[0] - d[2]) / rise, -0.5 * step_deg), 0.5 * step_deg)


def yaw_offset(index: SearchIndex, frame: int, yaw: int, yaws_deg: np.ndarray, query: np.ndarray,
               visible: np.ndarray) -> float:
    """Degrees to add to yaw ``yaw`` of database ``frame`` to best match ``query``.

    Eq. 1 grows about linearly with the yaw error near the match, so the distances of the same
    frame seen from the neighbouring yaws (rows are frame-major) place the minimum of a V between
    them; the offset is kept within half a yaw step.
    """
    return _yaw_offset(index.x, index.y, index.column_of_row, frame, yaw, len(yaws_deg),
                       float(yaws_deg[1] - yaws_deg[0]), _query_like(query, index), visible)
