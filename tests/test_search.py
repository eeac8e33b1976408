"""Two-level search against exact brute force in numpy."""
import numpy as np
import pytest

from mocapdb.core.geometry import normalize_pose_2d
from mocapdb.runtime.search import GRID_STEPS, SearchIndex, search_clustered, search_exact


class _Db:
    """The few database fields the index reads: random normalised poses in 40 clusters, rows frame-major
    (``n_yaws`` per frame) over frames of clips of ``clip_frames`` frames."""

    def __init__(self, n: int = 4000, k: int = 40, seed: int = 0, n_yaws: int = 20, clip_frames: int = 50):
        rng = np.random.default_rng(seed)
        self.search_index = None  # sorted in memory, as for a database built without one
        self.meta = {"yaws_deg": list(np.arange(n_yaws) * 360.0 / n_yaws)}
        self.frame_clip = np.arange(n // n_yaws) // clip_frames
        centres = rng.normal(size=(k, 14, 2))
        self.cluster = rng.integers(0, k, n).astype(np.int32)
        raw = centres[self.cluster] + 0.2 * rng.normal(size=(n, 14, 2))
        self.keypoints_2d = normalize_pose_2d(raw)[0].astype(np.float32)
        self.n_clusters = k
        # Representative: first member of each cluster (any member will do for the search).
        self.representative = np.array([np.flatnonzero(self.cluster == c)[0] for c in range(k)])


def _reference(poses: np.ndarray, query: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Eq. 1 over visible joints after renormalising every pose over them, in plain numpy."""
    vis = np.broadcast_to(visible, poses.shape[:2])
    renorm, _, _ = normalize_pose_2d(poses.astype(np.float64), vis)
    return np.linalg.norm(renorm - query, axis=-1)[:, visible].sum(axis=1)


@pytest.mark.parametrize("hidden", [[], [0, 4], [8, 13]])
def test_exact_search_matches_numpy(hidden):
    db = _Db()
    index = SearchIndex.from_database(db)
    rng = np.random.default_rng(1)
    visible = np.ones(14, bool)
    visible[hidden] = False
    query, _, _ = normalize_pose_2d(db.keypoints_2d[17] + 0.05 * rng.normal(size=(14, 2)), visible)
    rows, dist = search_exact(index, query, visible, k=10)
    ref = _reference(db.keypoints_2d, query, visible)
    np.testing.assert_array_equal(rows, np.argsort(ref, kind="stable")[:10])
    np.testing.assert_allclose(dist, np.sort(ref)[:10], rtol=1e-5)


def test_clustered_search_is_the_method_two_levels():
    db = _Db()
    index = SearchIndex.from_database(db)
    visible = np.ones(14, bool)
    query = db.keypoints_2d[5].astype(np.float64) + 0.01
    rows, dist = search_clustered(index, query, visible, n_clusters=3, per_cluster=4)
    ref = _reference(db.keypoints_2d, query, visible)
    rep_dist = ref[db.representative]
    expected = []
    for c in np.argsort(rep_dist)[:3]:
        members = np.flatnonzero(db.cluster == c)
        expected.extend(members[np.argsort(ref[members], kind="stable")[:4]])
    assert sorted(rows.tolist()) == sorted(expected)
    np.testing.assert_allclose(dist, ref[rows], rtol=1e-5)


def test_every_cluster_searched_is_exact_search():
    """Searching every cluster with room for every member finds the exact nearest projection."""
    db = _Db()
    index = SearchIndex.from_database(db)
    rng = np.random.default_rng(2)
    for hidden in ([], [1, 9]):
        visible = np.ones(14, bool)
        visible[hidden] = False
        query, _, _ = normalize_pose_2d(db.keypoints_2d[33] + 0.1 * rng.normal(size=(14, 2)), visible)
        rows, dist = search_clustered(index, query, visible, n_clusters=db.n_clusters, per_cluster=len(db.cluster),
                                      descents=3)
        ref = _reference(db.keypoints_2d, query, visible)
        assert rows[np.argmin(dist)] == np.argmin(ref)
        np.testing.assert_allclose(dist.min(), ref.min(), rtol=1e-5)


class _SmoothDb(_Db):
    """Poses that change smoothly along each clip's frames and with the yaw (as projections of motion do),
    each in the cluster of its nearest representative under Eq. 1 (as the builder assigns them)."""

    def __init__(self, n: int = 4000, k: int = 40, seed: int = 0):
        super().__init__(n, k, seed)
        rng = np.random.default_rng(seed)
        n_yaws = len(self.meta["yaws_deg"])
        frames = np.cumsum(0.05 * rng.normal(size=(n // n_yaws, 14, 2)), axis=0)
        frames[self.frame_clip != np.roll(self.frame_clip, 1)] += rng.normal(size=(14, 2))  # each clip elsewhere
        turn = np.sin(np.radians(self.meta["yaws_deg"]))[:, None, None] * rng.normal(size=(14, 2))
        self.keypoints_2d = normalize_pose_2d((frames[:, None] + turn[None]).reshape(n, 14, 2))[0].astype(np.float32)
        self.representative = np.sort(rng.choice(n, k, replace=False))
        visible = np.ones(14, bool)
        dist = [_reference(self.keypoints_2d, self.keypoints_2d[r].astype(np.float64), visible)
                for r in self.representative]
        self.cluster = np.argmin(dist, axis=0).astype(np.int32)
        self.cluster[self.representative] = np.arange(k)


def _grid_neighbours(row: int, db: _Db) -> list[int]:
    n_yaws = len(db.meta["yaws_deg"])
    f, v = divmod(row, n_yaws)
    return [(f + df) * n_yaws + (v + dv) % n_yaws for df, dv in GRID_STEPS
            if 0 <= f + df < len(db.frame_clip) and db.frame_clip[f + df] == db.frame_clip[f]]


@pytest.mark.parametrize("hidden", [[], [0, 13]])
def test_grid_descent_ends_nearer_at_a_local_minimum(hidden):
    """Each descent that moved ends nearer than every candidate it could start from, at a projection no grid
    neighbour of which (same clip, next or previous frame or yaw) is nearer; the clustered candidates are kept."""
    db = _SmoothDb()
    index = SearchIndex.from_database(db)
    visible = np.ones(14, bool)
    visible[hidden] = False
    rng = np.random.default_rng(3)
    ref_all = []
    for n in range(20):
        query, _, _ = normalize_pose_2d(db.keypoints_2d[197 * n] + 0.02 * rng.normal(size=(14, 2)), visible)
        plain_rows, plain_dist = search_clustered(index, query, visible, 1, 3)
        rows, dist = search_clustered(index, query, visible, 1, 3, descents=3)
        ref = _reference(db.keypoints_2d, query, visible)
        np.testing.assert_array_equal(rows[:len(plain_rows)], plain_rows)
        np.testing.assert_allclose(dist, ref[rows], rtol=1e-5)
        for row, d in zip(rows[len(plain_rows):], dist[len(plain_rows):]):
            assert d < np.sort(plain_dist)[:3].max()
            assert min(ref[_grid_neighbours(row, db)]) >= d * (1 - 1e-6)
        ref_all.append(len(rows) - len(plain_rows))
    assert sum(ref_all) > 0  # some descents moved
