"""Two-level search against exact brute force in numpy."""
import numpy as np
import pytest

from mocapdb.core.geometry import normalize_pose_2d
from mocapdb.runtime.search import SearchIndex, search_clustered, search_exact


class _Db:
    """The few database fields the index reads: random normalised poses in 40 clusters."""

    def __init__(self, n: int = 4000, k: int = 40, seed: int = 0):
        rng = np.random.default_rng(seed)
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
