"""Clustering of the embedded poses: k-means (k-means++ seeding, Lloyd's iterations with bounds
that skip most distance computations), each cluster's representative, the mean member distance.
One iteration costs at most ``O(N·K·d)``; the hot loops are numba kernels. The k-means also runs
streamed over arrays on disk, chunk by chunk, with the same result for any chunk size
(:func:`kmeans_seed`, :func:`kmeans_iterate`, :func:`kmeans_finish`; ``data_specs/build.md``), and its
chunks run as tasks wherever the build's tasks run (:mod:`mocapdb.builder.tasks`).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np
from numba import njit, prange
from scipy.spatial.distance import cdist

from mocapdb.builder.tasks import Tasks

KMEANS_INIT_PER_CLUSTER = 20   # k-means++ runs on a random subsample of this many × k points
KMEANS_BLOCK_ROWS = 4096       # k-means sums points in fixed blocks of this many, then the blocks in order

# fastmath without the no-inf/no-NaN assumptions: the k-means bounds start at infinity.
_FASTMATH_WITH_INF = {"nsz", "contract", "reassoc"}


@njit(fastmath=_FASTMATH_WITH_INF, cache=True)
def _sq_dist(x: np.ndarray, y: np.ndarray) -> float:
    """Squared Euclidean distance of two vectors."""
    sq = 0.0
    for j in range(x.shape[0]):
        t = x[j] - y[j]
        sq += t * t
    return sq


@njit(cache=True, fastmath=_FASTMATH_WITH_INF)
def _member_distances(points: np.ndarray, labels: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """Euclidean distance ``[N]`` of every point to its cluster's centroid (serial: O(N·d) is cheap)."""
    out = np.empty(points.shape[0])
    for i in range(points.shape[0]):
        out[i] = np.sqrt(_sq_dist(points[i], centroids[labels[i]]))
    return out


@njit(fastmath=_FASTMATH_WITH_INF, cache=True)
def _two_nearest(x: np.ndarray, cent_t: np.ndarray, acc: np.ndarray) -> tuple[int, float, float]:
    """Nearest centroid of ``x`` among ``cent_t [d, k]`` and the squared distances to the
    nearest and second nearest (``acc [k]`` is scratch)."""
    acc[:] = 0.0
    for j in range(cent_t.shape[0]):
        xj, row = x[j], cent_t[j]
        for c in range(acc.shape[0]):
            t = xj - row[c]
            acc[c] += t * t
    best, first, second = 0, np.inf, np.inf
    for c in range(acc.shape[0]):
        if acc[c] < first:
            best, first, second = c, acc[c], first
        elif acc[c] < second:
            second = acc[c]
    return best, first, second


KMEANS_NEIGHBOURS = 256  # per centroid, its nearest centroids kept sorted for the ball search
BALL_MARGIN = 1e-9  # relative widening of the ball searched: rounding never leaves a candidate out


@njit(fastmath=_FASTMATH_WITH_INF, cache=True)
def _two_nearest_of(x: np.ndarray, centroids: np.ndarray, candidates: np.ndarray) -> tuple[int, float, float]:
    """:func:`_two_nearest` among ``candidates`` only (centroid indices, any order; the lower index
    first on ties, as a search of all would give)."""
    best, first, second = -1, np.inf, np.inf
    for c in candidates:
        sq = _sq_dist(x, centroids[c])
        if sq < first or (sq == first and c < best):
            best, first, second = c, sq, first
        elif sq < second:
            second = sq
    return best, first, second


@njit(parallel=True, cache=True, fastmath=_FASTMATH_WITH_INF)
def _assign(points: np.ndarray, centroids: np.ndarray, moved: np.ndarray, half_gap: np.ndarray,
            labels: np.ndarray, upper: np.ndarray, lower: np.ndarray, near: np.ndarray, near_dist: np.ndarray,
            block_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd assignment step with Hamerly's (2010) bounds, exact like brute force but mostly O(d).

    ``upper[i]`` bounds the distance of point ``i`` to its centroid ``labels[i]`` from above,
    ``lower[i]`` the distance to any other centroid from below; both are first loosened by the
    centroids' last moves ``moved [k]`` (infinite moves: bounds unknown, labels any in ``[0, k)``);
    ``half_gap[c]`` is half the distance from centroid ``c`` to its nearest other centroid. Points
    whose bounds cannot prove their label get a search, within the ball of radius
    ``2 d(x, c_a) + 2 half_gap[a]`` about their centroid ``c_a``, which holds the nearest and the
    second nearest centroid (Newling & Fleuret's Exponion, 2016): ``near [k, m]`` lists each
    centroid's ``m`` nearest centroids (itself first), ``near_dist`` their distances, ascending; a
    ball reaching beyond the list is searched whole. Returns per-block partial
    ``sums [n_blocks, k, d]`` and ``counts [n_blocks, k]`` by label, blocks of ``block_rows``
    points each summed in order (the caller adds the blocks in order: deterministic).
    """
    n, d = points.shape
    k = centroids.shape[0]
    cent_t = np.ascontiguousarray(centroids.T)
    order = np.argsort(moved)
    top, top_move = order[-1], moved[order[-1]]
    runner_up = moved[order[-2]] if k > 1 else 0.0
    n_blocks = (n + block_rows - 1) // block_rows
    sums = np.zeros((n_blocks, k, d))
    counts = np.zeros((n_blocks, k), dtype=np.int64)
    for blk in prange(n_blocks):
        acc = np.empty(k)
        for i in range(blk * block_rows, min(n, (blk + 1) * block_rows)):
            a = labels[i]
            upper[i] += moved[a]
            lower[i] -= runner_up if a == top else top_move
            bound = max(half_gap[a], lower[i])
            if upper[i] > bound:
                upper[i] = np.sqrt(_sq_dist(points[i], centroids[a]))
                if upper[i] > bound:
                    radius = (2.0 * upper[i] + 2.0 * half_gap[a]) * (1.0 + BALL_MARGIN)
                    count = np.searchsorted(near_dist[a], radius, side="right")
                    if count < near.shape[1] or near.shape[1] == k:
                        a, first, second = _two_nearest_of(points[i], centroids, near[a, :count])
                    else:
                        a, first, second = _two_nearest(points[i], cent_t, acc)
                    labels[i], upper[i], lower[i] = a, np.sqrt(first), np.sqrt(second)
            counts[blk, a] += 1
            for j in range(d):
                sums[blk, a, j] += points[i, j]
    return sums, counts


@njit(cache=True)
def _add_blocks(sums: np.ndarray, counts: np.ndarray, block_sums: np.ndarray, block_counts: np.ndarray) -> None:
    """``sums += block_sums[0]``, then ``[1]``, …: one block at a time, in order (no fastmath: the
    order of the additions is the result's definition)."""
    for b in range(block_sums.shape[0]):
        for c in range(block_sums.shape[1]):
            counts[c] += block_counts[b, c]
            for j in range(block_sums.shape[2]):
                sums[c, j] += block_sums[b, c, j]


def _neighbours(centroids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each centroid's ``KMEANS_NEIGHBOURS`` nearest centroids, itself first: indices ``[k, m]`` and
    distances ``[k, m]``, ascending (ties by index), in blocks of rows (memory ``O(k·m)``)."""
    k = len(centroids)
    m = min(k, KMEANS_NEIGHBOURS)
    near, near_dist = np.empty((k, m), dtype=np.int64), np.empty((k, m))
    for start in range(0, k, 1024):
        dist = cdist(centroids[start:start + 1024], centroids)
        dist[np.arange(len(dist)), np.arange(start, start + len(dist))] = -1.0  # itself first
        order = np.argsort(dist, axis=1, kind="stable")[:, :m]
        near[start:start + len(dist)] = order
        near_dist[start:start + len(dist)] = np.maximum(np.take_along_axis(dist, order, axis=1), 0.0)
    return near, near_dist


def _as_points(points: np.ndarray) -> np.ndarray:
    """float64 C-contiguous ``[N, d]`` (one compiled signature per kernel)."""
    return np.ascontiguousarray(points, dtype=np.float64)


def _as_chunk(points: np.ndarray) -> np.ndarray:
    """A chunk of points for the k-means kernels: float32 ones as they are (the kernels compute in
    float64, into which float32 converts exactly: the same results, no float64 copy), else float64."""
    points = np.asarray(points)
    return np.ascontiguousarray(points) if points.dtype == np.float32 else _as_points(points)


def _kmeans_pp(sample: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """Greedy k-means++ seeding (``2 + ln k`` candidates per step) of ``k`` centres from ``sample``."""
    n_trials = 2 + int(np.log(k))
    centres = np.empty((k, sample.shape[1]))
    centres[0] = sample[rng.integers(len(sample))]
    closest = ((sample - centres[0]) ** 2).sum(axis=1)
    for c in range(1, k):
        cumulative = np.cumsum(closest)
        candidates = np.minimum(np.searchsorted(cumulative, rng.random(n_trials) * cumulative[-1]),
                                len(sample) - 1)
        trial = np.minimum(closest, ((sample[None] - sample[candidates, None]) ** 2).sum(axis=2))
        best = np.argmin(trial.sum(axis=1))
        closest, centres[c] = trial[best], sample[candidates[best]]
    return centres


def _chunks(n: int, chunk_rows: int) -> list[slice]:
    """The chunks of ``n`` rows, ``chunk_rows`` rounded down to whole k-means blocks (at least one)
    so that no chunk splits a block."""
    step = max(KMEANS_BLOCK_ROWS, chunk_rows // KMEANS_BLOCK_ROWS * KMEANS_BLOCK_ROWS)
    return [slice(start, min(start + step, n)) for start in range(0, n, step)]


def _farthest_members(points, labels, centroids: np.ndarray, m: int, chunk_rows: int) -> np.ndarray:
    """The ``m`` points farthest from their cluster's centroid (farthest first, lower index first on
    ties), streamed over chunks of ``points [N, d]``; ``labels [N]``."""
    best_dist, best_index = np.empty(0), np.empty(0, dtype=np.int64)
    for rows in _chunks(len(points), chunk_rows):
        dist = _member_distances(_as_chunk(points[rows]), np.asarray(labels[rows]), centroids)
        kth = max(len(dist) - m, 0)
        keep = np.flatnonzero(dist >= np.partition(dist, kth)[kth])  # the m farthest and their ties
        dist, index = np.concatenate([best_dist, dist[keep]]), np.concatenate([best_index, rows.start + keep])
        order = np.lexsort((index, -dist))[:m]
        best_dist, best_index = dist[order], index[order]
    return best_index


def _update_centroids(points, sums: np.ndarray, counts: np.ndarray, labels, old: np.ndarray,
                      chunk_rows: int = KMEANS_BLOCK_ROWS) -> np.ndarray:
    """Means of the clusters; each empty cluster takes one of the points farthest from their centroid.
    ``points [N, d]`` and ``labels [N]`` are arrays or work arrays, read ``chunk_rows`` at a time."""
    empty = np.flatnonzero(counts == 0)
    if empty.size:
        far = _farthest_members(points, labels, old, empty.size, chunk_rows)
        far_points, far_labels = _as_points(points.take(far, axis=0)), labels.take(far, axis=0)
        np.subtract.at(sums, far_labels, far_points)
        np.subtract.at(counts, far_labels, 1)
        sums[empty], counts[empty] = far_points, 1
    new = old.copy()
    filled = counts > 0
    new[filled] = sums[filled] / counts[filled, None]
    return new


Rows = TypeVar("Rows")  # numpy arrays or the build's work arrays


@dataclass
class KMeansBounds(Generic[Rows]):
    """Per point: its cluster and Hamerly's bounds; numpy arrays or the build's work arrays (anything
    sliced by row ranges into writable arrays). Any content will do while the bounds are unknown."""

    labels: Rows  # int32 [N]
    upper: Rows   # float64 [N]
    lower: Rows   # float64 [N]

    FIELDS = (("labels", np.int32), ("upper", np.float64), ("lower", np.float64))

    @classmethod
    def in_memory(cls, n: int) -> KMeansBounds[np.ndarray]:
        return KMeansBounds(*(np.zeros(n, dtype=dtype) for _, dtype in cls.FIELDS))


@dataclass
class KMeansState:
    """A streamed k-means between two iterations: what a resumed build needs to go on."""

    centroids: np.ndarray       # [k, d] float64
    tol_abs: float              # converged when the summed squared centroid shift is at most this
    iteration: int = 0          # Lloyd iterations done
    shift: float = np.inf       # the last iteration's summed squared centroid shift
    moved: np.ndarray | None = None  # the centroids' last moves while the bounds hold; None: bounds unknown

    @property
    def converged(self) -> bool:
        return self.shift <= self.tol_abs


def kmeans_seed(points, k: int, seed: int = 0, tol: float = 1e-4) -> KMeansState:
    """Greedy k-means++ seeding on a seeded random sample of ``20 k`` of ``points [N, d]`` (an array or
    a work array); the tolerance is ``tol ×`` the sample's mean per-axis variance (sklearn's rule,
    on the sample: it only decides when to stop)."""
    n = len(points)
    if not 1 <= k <= n:
        raise ValueError(f"k must be in [1, {n}], got {k}")
    rng = np.random.default_rng(seed)
    sample = _as_points(points.take(np.sort(rng.choice(n, min(n, KMEANS_INIT_PER_CLUSTER * k), replace=False)),
                                    axis=0))
    return KMeansState(_kmeans_pp(sample, k, rng), tol * float(np.mean(np.var(sample, axis=0))))


@dataclass
class _LloydStep:
    """What every chunk of one assignment pass needs: the centroids ``[k, d]``, their last moves
    ``[k]`` (infinite: bounds unknown), half the gap to each one's nearest other centroid ``[k]``,
    and each one's nearest centroids ``near [k, m]`` at ``near_dist [k, m]``."""

    centroids: np.ndarray
    moved: np.ndarray
    half_gap: np.ndarray
    near: np.ndarray
    near_dist: np.ndarray

    @classmethod
    def of(cls, state: KMeansState) -> _LloydStep:
        k = len(state.centroids)
        near, near_dist = _neighbours(state.centroids)
        half_gap = 0.5 * near_dist[:, 1] if k > 1 else np.full(k, np.inf)
        moved = np.full(k, np.inf) if state.moved is None else state.moved
        return cls(state.centroids, moved, half_gap, near, near_dist)


def lloyd_task(job: tuple) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """One chunk of an assignment pass: ``job = (points, bounds, rows, step, members, durable)``.
    Assigns the chunk's points (their labels and bounds updated in place) and returns its per-block
    ``sums [blocks, k, d]`` and ``counts [blocks, k]``, and with ``members`` each cluster's member
    nearest its centroid among the chunk's (:func:`_nearest_members`); ``durable``: fsync the bounds
    (a task on another machine)."""
    points, bounds, rows, step, members, durable = job
    chunk, labels = _as_chunk(points[rows]), bounds.labels[rows]
    block_sums, block_counts = _assign(chunk, step.centroids, step.moved, step.half_gap, labels, bounds.upper[rows],
                                       bounds.lower[rows], step.near, step.near_dist, KMEANS_BLOCK_ROWS)
    nearest = _nearest_members(chunk, labels, step.centroids) if members else None
    if durable:
        for array in (bounds.labels, bounds.upper, bounds.lower):
            array.sync()
    return block_sums, block_counts, nearest


def _lloyd_pass(points, state: KMeansState, bounds: KMeansBounds, chunk_rows: int, tasks: Tasks,
                members: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """One assignment of every point to ``state.centroids``, chunk by chunk as ``tasks`` run them;
    returns the float64 ``sums [k, d]`` and ``counts [k]`` by cluster, added block by block in order
    (the same for any chunk size, thread count or cluster), and with ``members`` each cluster's member
    nearest its centroid (int64 ``[k]``, lowest index on ties, −1 if empty)."""
    k, d = state.centroids.shape
    step = tasks.share(_LloydStep.of(state))
    chunks = _chunks(len(points), tasks.chunk_rows(chunk_rows, len(points), KMEANS_BLOCK_ROWS))
    jobs = [(points, bounds, rows, step, members, tasks.remote) for rows in chunks]
    sums, counts = np.zeros((k, d)), np.zeros(k, dtype=np.int64)
    best, best_sq = np.full(k, -1, dtype=np.int64), np.full(k, np.inf)
    for rows, (block_sums, block_counts, nearest) in zip(chunks, tasks.in_order(lloyd_task, jobs)):
        _add_blocks(sums, counts, block_sums, block_counts)
        if nearest is not None:
            closer = nearest[1] < best_sq
            best[closer], best_sq[closer] = rows.start + nearest[0][closer], nearest[1][closer]
    return sums, counts, best if members else None


def kmeans_iterate(points, state: KMeansState, bounds: KMeansBounds, max_iter: int = 50,
                   chunk_rows: int = 1 << 20, progress: Callable[[KMeansState], object] | None = None,
                   tasks: Tasks | None = None) -> None:
    """Lloyd iterations of ``state`` over ``points [N, d]`` until converged or ``max_iter`` done,
    streamed ``chunk_rows`` points at a time (as ``tasks`` run them: here by default, or on a
    cluster); ``progress(state)`` after each iteration (where a build saves it). ``bounds`` may hold
    anything when ``state.moved`` is None (a resumed state)."""
    tasks = tasks or Tasks()
    while not state.converged and state.iteration < max_iter:
        sums, counts, _ = _lloyd_pass(points, state, bounds, chunk_rows, tasks)
        new = _update_centroids(points, sums, counts, bounds.labels, state.centroids, chunk_rows)
        state.moved = np.sqrt(((new - state.centroids) ** 2).sum(axis=1))
        state.centroids, state.iteration, state.shift = new, state.iteration + 1, float((state.moved ** 2).sum())
        if progress is not None:
            progress(state)


def kmeans_finish(points, state: KMeansState, bounds: KMeansBounds, chunk_rows: int = 1 << 20,
                  tasks: Tasks | None = None) -> np.ndarray:
    """The final assignment of every point to ``state.centroids`` (into ``bounds.labels``) and each
    cluster's representative: int64 ``[k]`` index of the member nearest its centroid (lowest index on
    ties; −1 for an empty cluster), streamed like :func:`kmeans_iterate`."""
    representatives = _lloyd_pass(points, state, bounds, chunk_rows, tasks or Tasks(), members=True)[2]
    assert representatives is not None, "a pass with members gives the representatives"
    return representatives


def kmeans(points: np.ndarray, k: int, seed: int = 0, max_iter: int = 50, tol: float = 1e-4,
           progress: Callable[[int, float], object] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lloyd's k-means of ``points [N, d]`` → ``(centroids float64 [k, d], labels int32 [N])``.

    Seeded by greedy k-means++ on a random subsample of ``20 k`` points (:func:`kmeans_seed`).
    Assignment steps use Hamerly's bounds (same result as brute force; once clusters settle most
    points skip the search) and search the others only in a ball about their centroid (on the
    6 M-projection CMU embedding, 56 of 500 centroids on average: half the time); update steps sum
    fixed blocks of ``KMEANS_BLOCK_ROWS`` points in parallel and add them in order. Iterates until
    the summed squared centroid shift is ≤ ``tol ×`` the mean per-axis variance of the sample or
    ``max_iter`` iterations;
    ``progress(iteration, shift)`` reports that shift. Labels are the final assignment to the
    returned centroids. An empty cluster is re-seeded with the point farthest from its centroid.
    Deterministic for a fixed ``seed`` whatever the thread count; the build streams the same steps
    over its work arrays (:func:`kmeans_iterate`, :func:`kmeans_finish`) and gets the same result.
    """
    points = _as_points(points)
    state = kmeans_seed(points, k, seed, tol)
    bounds = KMeansBounds.in_memory(len(points))
    report = None if progress is None else (lambda s: progress(s.iteration - 1, s.shift))
    kmeans_iterate(points, state, bounds, max_iter, len(points), report)
    kmeans_finish(points, state, bounds, len(points))
    return state.centroids, bounds.labels


@njit(cache=True)
def _nearest_members(points: np.ndarray, labels: np.ndarray, centroids: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per cluster, the index of its member nearest its centroid (first on ties; −1 if none) and
    that squared distance (inf if none)."""
    best = np.full(centroids.shape[0], -1, dtype=np.int64)
    best_sq = np.full(centroids.shape[0], np.inf)
    for i in range(points.shape[0]):
        c = labels[i]
        sq = _sq_dist(points[i], centroids[c])
        if sq < best_sq[c]:
            best[c], best_sq[c] = i, sq
    return best, best_sq


def representatives(points: np.ndarray, labels: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """int64 ``[k]``: per cluster, the index of the member of ``points [N, d]`` nearest its centroid
    (Euclidean, lowest index on ties; −1 for an empty cluster). ``labels [N]`` in ``[0, k)``."""
    return _nearest_members(_as_points(points), np.asarray(labels, dtype=np.int32), _as_points(centroids))[0]


def mean_member_distance(points: np.ndarray, labels: np.ndarray, centroids: np.ndarray) -> float:
    """Mean Euclidean distance from each point ``[N, d]`` to its cluster's centroid ``[k, d]``
    (embedding units); the method's criterion for choosing ``K``."""
    return float(_member_distances(_as_points(points), np.asarray(labels, dtype=np.int32),
                                   _as_points(centroids)).mean())
