"""The method's two-level search over the database's normalised 2D projections (numba).

Clustered search: Eq. 1 distance from the query to every cluster representative (K), keep the
``n_clusters`` nearest clusters, then the ``per_cluster`` nearest members of each: cost
O(K + n_clusters · mean cluster size) pose distances. Exact search: every projection, O(P).

Sub-clusters (databases with a search index, ``data_specs/database.md``): each cluster is cut into
sub-clusters of ~1,260 projections, and the members searched are those of the ``n_clusters × subclusters``
sub-clusters of the nearest clusters whose representatives are nearest the query, so the poses read per
query stay bounded as the database grows (:func:`mocapdb.core.search_rules.subclusters_searched_for`). A
database whose clusters are one sub-cluster each is searched exactly as the method does.

Grid descent (``descents`` > 0): the best candidates of the clustered search then move, while it lowers Eq. 1,
to a neighbouring projection on the database's grid (the same frame at the next or previous yaw, or the next or
previous frame of the same clip at the same yaw), a few distances each. The exact nearest projection the
clusters miss is often one of these neighbours, split from it by a cluster boundary: on 5.5 M projections
(K 4,401, 10 clusters searched) 3 descents raise recall@1 from 0.997 to 1.000 clean and from 0.926 to 0.963
with noise and missing joints, at the paper's size (K 500, 5 clusters) from 0.954 to 0.973 with missing
joints, for 6–11 µs (``tools/bench_search.py``; how K and i grow with the database:
:mod:`mocapdb.core.search_rules`).

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
    frame_clip: np.ndarray      # [F] int64: clip of each database frame (rows are frame-major: frame × yaws + yaw)
    n_yaws: int
    cluster_subs: np.ndarray    # [K + 1] int64: cluster c's sub-clusters are cluster_subs[c]:cluster_subs[c+1]
    sub_start: np.ndarray       # [S + 1] int64: sub-cluster s is columns sub_start[s]:sub_start[s+1]
    sub_x: np.ndarray           # [14, S] float32: the sub-clusters' representatives
    sub_y: np.ndarray           # [14, S] float32

    @classmethod
    def from_database(cls, db: MotionDatabase) -> SearchIndex:
        """The database's search index, memory-mapped (databases built with one), else sorted here with
        one sub-cluster per cluster (the method's search exactly)."""
        nonempty = np.flatnonzero(db.representative >= 0)
        frame_clip, n_yaws = np.asarray(db.frame_clip, dtype=np.int64), len(db.meta["yaws_deg"])
        if db.search_index is not None:
            built = db.search_index
            x, y, columns = np.asarray(built.x), np.asarray(built.y), np.asarray(built.columns)
            rows, start = np.asarray(built.rows), np.asarray(built.cluster_start)
            subs, sub_start, sub_rep = (np.asarray(built.cluster_subs), np.asarray(built.sub_start),
                                        np.asarray(built.sub_rep))
        else:
            order = np.argsort(db.cluster, kind="stable")
            counts = np.bincount(db.cluster, minlength=db.n_clusters)
            start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
            poses = db.keypoints_2d[order]
            x, y = np.ascontiguousarray(poses[..., 0].T), np.ascontiguousarray(poses[..., 1].T)
            rows, columns = order.astype(np.int64), np.argsort(order)
            subs, sub_start = np.arange(db.n_clusters + 1, dtype=np.int64), start
            sub_rep = np.where(db.representative >= 0, columns[np.maximum(db.representative, 0)], 0)
        rep_columns = columns[db.representative[nonempty]]
        return cls(x, y, rows, start, np.ascontiguousarray(x[:, rep_columns]), np.ascontiguousarray(y[:, rep_columns]),
                   nonempty.astype(np.int64), columns, frame_clip, n_yaws, subs, sub_start,
                   np.ascontiguousarray(x[:, sub_rep]), np.ascontiguousarray(y[:, sub_rep]))

    def pose(self, row: int) -> np.ndarray:
        """The normalised 2D pose ``[14, 2]`` of projection ``row``."""
        column = self.column_of_row[row]
        return np.stack([self.x[:, column], self.y[:, column]], axis=1)


@njit(cache=True)
def range_distances(x, y, lo, hi, query, vis_idx, renormalise):
    """Eq. 1 distances ``[hi - lo]`` (float32) from ``query [14, 2]`` (the poses' dtype) to poses lo:hi, over
    joints ``vis_idx``. With ``renormalise`` each pose is first renormalised over those joints."""
    out = np.empty(hi - lo, dtype=np.float32)
    _distances_into(x, y, lo, hi, query, vis_idx, renormalise, np.empty((5, hi - lo), dtype=np.float32), out)
    return out


@njit(cache=True)
def _distances_into(x, y, lo, hi, query, vis_idx, renormalise, work, out):
    """:func:`range_distances` into ``out [hi - lo]``, with ``work [5, hi - lo]`` for the renormalisation."""
    out[:] = 0.0
    if renormalise:
        pose_normalisation_into(x, y, lo, hi, vis_idx, R_HIP, L_HIP, work[0], work[1], work[2], work[3], work[4])
        renormalised_pose_distances_into(x, y, lo, hi, query, vis_idx, work[2], work[3], work[4], out)
    else:
        pose_distances_into(x, y, lo, hi, query, vis_idx, out)


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
def _clustered(x, y, rep_x, rep_y, rep_cluster, cluster_subs, sub_start, sub_x, sub_y, rows, query, visible,
               n_clusters, n_subs, per_cluster):
    vis_idx, renorm = _visible_joints(visible)
    n_rep = rep_x.shape[1]
    top_c, _ = _smallest(range_distances(rep_x, rep_y, 0, n_rep, query, vis_idx, renorm),
                         min(n_clusters, n_rep), 0)
    chosen = _nearest_subclusters(sub_x, sub_y, cluster_subs, rep_cluster[top_c], query, vis_idx, renorm,
                                  n_subs * top_c.shape[0])
    out_d = np.full(top_c.shape[0] * per_cluster, np.inf)
    out_i = np.full(out_d.shape[0], -1, dtype=np.int64)
    for n in range(top_c.shape[0]):
        c = rep_cluster[top_c[n]]
        best_d = np.full(per_cluster, np.inf)
        best_i = np.full(per_cluster, -1, dtype=np.int64)
        first = _offset(cluster_subs, rep_cluster[top_c], n) - cluster_subs[c]  # flags of c in ``chosen``
        s, end = cluster_subs[c], cluster_subs[c + 1]
        while s < end:
            if not chosen[first + s]:
                s += 1
                continue
            run_end = s + 1  # chosen sub-clusters next to each other are one column range: searched at once
            while run_end < end and chosen[first + run_end]:
                run_end += 1
            lo, hi = sub_start[s], sub_start[run_end]
            found_i, found_d = _smallest(range_distances(x, y, lo, hi, query, vis_idx, renorm), per_cluster, lo)
            merged_i, merged_d = _smallest(np.concatenate((best_d, found_d)), per_cluster, 0)
            pool_i = np.concatenate((best_i, found_i))
            best_i, best_d = np.where(merged_i >= 0, pool_i[np.maximum(merged_i, 0)], -1), merged_d
            s = run_end
        out_i[n * per_cluster:(n + 1) * per_cluster] = best_i
        out_d[n * per_cluster:(n + 1) * per_cluster] = best_d
    keep = out_i >= 0
    return rows[out_i[keep]], out_d[keep]


@njit(cache=True)
def _offset(cluster_subs, clusters, n):
    """Where cluster ``clusters[n]``'s sub-clusters start in the concatenation of the ``clusters``' ones."""
    total = 0
    for m in range(n):
        total += cluster_subs[clusters[m] + 1] - cluster_subs[clusters[m]]
    return total


@njit(cache=True)
def _nearest_subclusters(sub_x, sub_y, cluster_subs, clusters, query, vis_idx, renorm, count):
    """Flags over the ``clusters``' sub-clusters (concatenated in that order): the ``count`` whose
    representatives are nearest the query, all of them when they are no more."""
    total = _offset(cluster_subs, clusters, clusters.shape[0])
    chosen = np.ones(total, dtype=np.bool_)
    if total <= count:
        return chosen
    dist = np.empty(total, dtype=np.float32)
    at = 0
    for c in clusters:
        s0, s1 = cluster_subs[c], cluster_subs[c + 1]
        dist[at:at + s1 - s0] = range_distances(sub_x, sub_y, s0, s1, query, vis_idx, renorm)
        at += s1 - s0
    picked, _ = _smallest(dist, count, 0)
    chosen[:] = False
    for i in picked:
        chosen[i] = True
    return chosen


GRID_STEPS = np.array([[0, 1], [0, -1], [1, 0], [-1, 0]], dtype=np.int64)  # (frame, yaw) moves of a descent


@njit(cache=True)
def _grid_descent(x, y, column_of_row, frame_clip, n_yaws, rows, dist, query, visible, descents):
    """Rows and Eq. 1 distances of the ``descents`` best candidates ``rows, dist`` after steepest descent over
    their grid neighbours (:data:`GRID_STEPS`, within the clip), only those that moved."""
    vis_idx, renorm = _visible_joints(visible)
    start = np.argsort(dist)[:descents]
    out_r = np.empty(start.shape[0], dtype=np.int64)
    out_d = np.empty(start.shape[0], dtype=dist.dtype)
    work, one = np.empty((5, 1), dtype=np.float32), np.empty(1, dtype=np.float32)  # for one pose's distance
    n_out = 0
    for s in start:
        r, d = rows[s], dist[s]
        moved = True
        while moved:
            moved = False
            f, v = r // n_yaws, r % n_yaws
            best_r, best_d = r, d
            for k in range(GRID_STEPS.shape[0]):
                f2 = f + GRID_STEPS[k, 0]
                if f2 < 0 or f2 >= frame_clip.shape[0] or frame_clip[f2] != frame_clip[f]:
                    continue
                r2 = f2 * n_yaws + (v + GRID_STEPS[k, 1]) % n_yaws
                c = column_of_row[r2]
                _distances_into(x, y, c, c + 1, query, vis_idx, renorm, work, one)
                d2 = one[0]
                if d2 < best_d:
                    best_r, best_d = r2, d2
            if best_r != r:
                r, d, moved = best_r, best_d, True
        if r != rows[s]:
            out_r[n_out], out_d[n_out] = r, d
            n_out += 1
    return out_r[:n_out], out_d[:n_out]


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


def visible_distances(x: np.ndarray, y: np.ndarray, query: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Eq. 1 distances ``[P]`` from ``query [14, 2]`` to every pose of joint-major ``x, y [14, P]``, over the
    ``visible [14]`` joints (each pose renormalised over them when some are missing)."""
    vis_idx, renorm = _visible_joints(visible)
    return range_distances(x, y, 0, x.shape[1], np.ascontiguousarray(query, dtype=x.dtype), vis_idx, renorm)


def search_clustered(index: SearchIndex, query: np.ndarray, visible: np.ndarray, n_clusters: int = 5,
                     per_cluster: int = 10, descents: int = 0, subclusters: int = 5
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Candidates of the clustered search: the ``per_cluster`` nearest members of each of the ``n_clusters``
    clusters with the nearest representatives, searched in the ``n_clusters × subclusters`` sub-clusters of
    theirs with the nearest representatives (all of them where they have no more); database projection rows
    and their Eq. 1 distances, followed by the ends of the ``descents`` best candidates' grid descents that
    moved (see the module docstring).

    ``query [14, 2]`` is normalised over ``visible [14]`` (see ``normalize_pose_2d``).
    """
    query = _query_like(query, index)
    rows, dist = _clustered(index.x, index.y, index.rep_x, index.rep_y, index.rep_cluster, index.cluster_subs,
                            index.sub_start, index.sub_x, index.sub_y, index.rows, query, visible, n_clusters,
                            subclusters, per_cluster)
    if descents == 0:
        return rows, dist
    more_rows, more_dist = _grid_descent(index.x, index.y, index.column_of_row, index.frame_clip, index.n_yaws,
                                         rows, dist, query, visible, descents)
    return np.concatenate((rows, more_rows)), np.concatenate((dist, more_dist))


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
