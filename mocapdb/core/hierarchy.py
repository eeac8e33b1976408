"""Joint hierarchies as parents arrays (``parents[j] < j``, -1 for a root): which joints lie below
which, ancestors, depths and children, each in time linear in the joints at any depth and without
recursion (a walk up the parents per question would cost the depth every time)."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def subtree_bounds(parents: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each joint's rank ``[J]`` in a depth-first pre-order walk and the rank ``[J]`` just after its
    last descendant: joint ``b`` lies below ``a`` when ``rank[a] < rank[b] < end[a]``.

    ``parents[j] < j`` (-1 for a root). Two passes over the joints without recursion: time linear
    in the joint count at any depth (a parent-chain walk per query would be linear in the depth).
    """
    parent_of = parents.tolist()
    size = [1] * len(parent_of)  # joints in each subtree, the joint included
    for j in range(len(parent_of) - 1, -1, -1):
        if parent_of[j] >= 0:
            size[parent_of[j]] += size[j]
    rank = [0] * len(parent_of)
    next_rank = [0] * len(parent_of)  # the rank a joint's next child takes
    next_root = 0
    for j, p in enumerate(parent_of):
        if p < 0:
            rank[j], next_root = next_root, next_root + size[j]
        else:
            rank[j], next_rank[p] = next_rank[p], next_rank[p] + size[j]
        next_rank[j] = rank[j] + 1
    ranks = np.array(rank, dtype=np.int64)
    return ranks, ranks + np.array(size, dtype=np.int64)


def with_ancestors(parents: np.ndarray, joints: Sequence[int]) -> np.ndarray:
    """``joints`` and all their ancestors, each once, in increasing order (parents before children);
    each joint is visited once, so time is linear in the joint count at any depth."""
    kept = np.zeros(len(parents), dtype=bool)
    for joint in joints:
        while joint >= 0 and not kept[joint]:
            kept[joint] = True
            joint = int(parents[joint])
    return np.flatnonzero(kept)


def children_and_depths(parents: np.ndarray) -> tuple[list[list[int]], list[int]]:
    """Each joint's children (in index order) and its depth (0 for a root), in one pass."""
    children: list[list[int]] = [[] for _ in range(len(parents))]
    depth = [0] * len(parents)
    for j, p in enumerate(parents.tolist()):
        if p >= 0:
            children[p].append(j)
            depth[j] = depth[p] + 1
    return children, depth
