"""The search index's build, out of core (the ``index`` stage; ``core/formats/search_index.py`` has the
files): the projections sorted by cluster, and each cluster cut into sub-clusters.

Pass 1 streams the cluster labels once: each projection's column = its cluster's start plus the
members of that cluster met before it (:func:`columns_of`, a stable counting sort). Pass 2 fills
the columns in groups of whole clusters as large as the memory limit allows: each group streams
the 2D poses and copies those whose column falls in it (:func:`gather_group`); then each cluster
of the group is cut into sub-clusters of about :data:`~mocapdb.core.search_rules.PROJECTIONS_PER_CLUSTER`
members (:func:`subclusters_of`: the method's own recipe one level down: k-means of the members'
MDS coordinates, each sub-cluster's member nearest its centroid as its representative, every
member then moved to its nearest representative under Eq. 1), its columns ordered by sub-cluster,
and the group's stretch of every joint's row written. Cost O(P) for pass 1, O(P · groups) reads
for pass 2 (groups of at most 1 GB: ~6.7 M columns, so 5 groups at 28 M projections), and
O(Σ n_c² / 1,260) for the sub-clusters (n_c: the members of cluster c).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapdb.builder.kmeans import kmeans, representatives
from mocapdb.builder.pose_distance import nearest_poses
from mocapdb.core.search_rules import subclusters_for

BYTES_PER_COLUMN = 2 * 14 * 4 + 8  # a group's buffers per column: x and y of 14 joints, the row


@njit(cache=True)
def columns_of(labels: np.ndarray, next_free: np.ndarray, out: np.ndarray) -> None:
    """``out[i]`` = the index column of projection ``i`` of this chunk (``labels [n]`` its clusters):
    ``next_free[c]``, the next free column of cluster ``c``, which then moves on (stable order)."""
    for i in range(labels.shape[0]):
        c = labels[i]
        out[i] = next_free[c]
        next_free[c] += 1


@njit(cache=True)
def gather_group(poses: np.ndarray, columns: np.ndarray, first_row: int, lo: int, hi: int,
                 x: np.ndarray, y: np.ndarray, rows: np.ndarray) -> None:
    """Copy the chunk's poses ``[n, 14, 2]`` (projection rows ``first_row…``) whose column lies in
    ``[lo, hi)`` into the group's ``x, y [14, hi - lo]`` and ``rows [hi - lo]``."""
    for i in range(poses.shape[0]):
        col = columns[i]
        if lo <= col < hi:
            for j in range(poses.shape[1]):
                x[j, col - lo] = poses[i, j, 0]
                y[j, col - lo] = poses[i, j, 1]
            rows[col - lo] = first_row + i


def subclusters_of(poses: np.ndarray, embedding: np.ndarray, representative: int, seed: int
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One cluster's sub-clusters: its members' 2D poses ``[n, 14, 2]`` and MDS coordinates ``[n, d]``
    (in projection-row order), ``representative`` the cluster's (an index among them). Returns the
    members' new ``order [n]`` (grouped by sub-cluster, rows in order within one), the sub-clusters'
    ``sizes [s]`` and their representatives' ``positions [s]`` in that order. A cluster of one
    sub-cluster keeps its order and its representative; no sub-cluster is empty."""
    n = len(poses)
    k = subclusters_for(n)
    if k == 1:
        return np.arange(n), np.array([n]), np.array([representative])
    centroids, labels = kmeans(embedding, k, seed)
    reps = representatives(embedding, labels, centroids)
    reps = reps[reps >= 0]
    labels = nearest_poses(poses, poses[reps])  # Eq. 1, as the search measures
    labels[reps] = np.arange(len(reps))  # a representative stays in its own sub-cluster (ties)
    order = np.argsort(labels, kind="stable")
    position = np.empty(n, dtype=np.int64)
    position[order] = np.arange(n)
    return order, np.bincount(labels, minlength=len(reps)), position[reps]
