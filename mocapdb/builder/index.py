"""The search index's build, out of core (the ``index`` stage; ``core/formats/search_index.py`` has the
files): a stable counting sort of the projections by cluster.

Pass 1 streams the cluster labels once: each projection's column = its cluster's start plus the
members of that cluster met before it (:func:`columns_of`). Pass 2 fills the columns in groups as
large as the memory limit allows: each group streams the 2D poses and copies those whose column
falls in it (:func:`gather_group`), then writes the group's stretch of every joint's row. Cost
O(P) for pass 1 and O(P · groups) reads for pass 2, groups = P × 120 bytes / the memory budget
(one at the default limit up to ~40 M projections).
"""
from __future__ import annotations

import numpy as np
from numba import njit

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
