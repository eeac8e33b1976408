"""The database's search index (issue 21): the builder's out-of-core counting sort equals the runtime's
in-memory sort of the projections table, the runtime loads it memory-mapped without the projections
table and finds the same poses, damage is found by its block digests, and a database without one
(built before it existed) still runs."""
import json
import shutil
import zlib

import numpy as np
import pytest

from mocapdb.builder.index import columns_of, subclusters_of
from mocapdb.builder.pipeline import build
from mocapdb.builder.pose_distance import pose_distances
from mocapdb.core.formats import search_index as S
from mocapdb.core.formats.database import DatabaseError
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.search_rules import subclusters_for
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.search import SearchIndex, search_clustered

from . import test_builder
from .test_build_out_of_core import TINY_MB, whole  # noqa: F401 - the fixture
from .test_builder import _config

sources = test_builder.sources  # the fixture: two clips, 7,920 projections


def _sorted_here(db) -> SearchIndex:
    """The index as the runtime sorts it from the projections table (no index files)."""
    db.search_index = None
    return SearchIndex.from_database(db)


def test_counting_sort_columns_are_a_stable_sort_by_cluster():
    labels = np.array([2, 0, 2, 1, 0, 2], dtype=np.int32)
    start = np.array([0, 2, 3])  # cluster 0: 2 members, 1: 1, 2: 3
    columns = np.empty(6, dtype=np.int64)
    columns_of(labels[:4], start.copy(), columns[:4])  # by hand: 3 4 5 | 0 1 | 2
    np.testing.assert_array_equal(columns[:4], [3, 0, 4, 2])
    next_free = start.copy()
    columns_of(labels, next_free, columns)
    np.testing.assert_array_equal(columns, np.argsort(np.argsort(labels, kind="stable"), kind="stable"))


def test_the_built_index_holds_every_pose_in_its_cluster(whole):  # noqa: F811
    db = load_database(whole)
    built = SearchIndex.from_database(db)
    assert isinstance(db.search_index.x, np.memmap) and not db.search_index.x.flags.writeable
    here = _sorted_here(load_database(whole))  # the projections sorted by cluster, rows in order
    for name in ("cluster_start", "rep_x", "rep_y", "rep_cluster", "frame_clip"):
        np.testing.assert_array_equal(getattr(built, name), getattr(here, name), err_msg=name)
    start = built.cluster_start
    for c in range(len(start) - 1):  # the same members, ordered by sub-cluster within the cluster
        np.testing.assert_array_equal(np.sort(built.rows[start[c]:start[c + 1]]), here.rows[start[c]:start[c + 1]])
    np.testing.assert_array_equal(built.x, db.keypoints_2d[built.rows][..., 0].T)
    np.testing.assert_array_equal(built.y, db.keypoints_2d[built.rows][..., 1].T)
    np.testing.assert_array_equal(built.column_of_row[built.rows], np.arange(db.n_projections))


def test_the_runtime_loads_no_projections_and_matches_the_same(whole):  # noqa: F811
    full, lean = load_database(whole), load_database(whole, projections=False)
    assert lean.proj_frame is None and lean.keypoints_2d is None and lean.n_projections == full.n_projections
    rng = np.random.default_rng(0)
    rows = rng.choice(full.n_projections, 20, replace=False)
    config = EngineConfig(refine=False)
    engines = Engine(full, config), Engine(lean, config)
    for row in rows:
        query = full.keypoints_2d[row].astype(np.float64) + rng.normal(0, 0.01, (14, 2))
        visible = np.ones(14, dtype=bool)
        found = [engine.pipeline.search(query, visible) for engine in engines]
        np.testing.assert_array_equal(found[0][0], found[1][0])
        np.testing.assert_array_equal(found[0][1], found[1][1])
    np.testing.assert_array_equal(engines[1].pipeline.index.pose(int(rows[0])), full.keypoints_2d[rows[0]])


def test_a_damaged_index_file_is_found_by_its_blocks(whole, tmp_path):  # noqa: F811
    db = tmp_path / "db"
    shutil.copytree(whole, db)
    with open(db / "index_x.npy", "r+b") as f:
        f.seek(200)
        byte = f.read(1)
        f.seek(200)
        f.write(bytes([byte[0] ^ 1]))
    with pytest.raises(DatabaseError, match="checksum mismatch: .*index_x.npy"):
        load_database(db, projections=False)
    assert load_database(db, verify_checksums=False, projections=False).search_index is not None
    (db / "index_rows.npy").write_bytes(b"\x93NUMPY")
    with pytest.raises(DatabaseError, match="index_rows.npy: missing, or not the manifest's"):
        load_database(db, verify_checksums=False)


def test_a_database_without_an_index_still_runs(whole, tmp_path):  # noqa: F811
    db = tmp_path / "db"
    shutil.copytree(whole, db)
    manifest = json.loads((db / "manifest.json").read_text())
    del manifest["search_index"]
    (db / "manifest.json").write_text(json.dumps(manifest))
    for name in S.ARRAYS:
        (db / S.file_name(name)).unlink()
    old = load_database(db, projections=False)  # no index: the projections are read after all
    assert old.search_index is None and old.keypoints_2d is not None
    index = SearchIndex.from_database(old)  # sorted here: one sub-cluster per cluster
    np.testing.assert_array_equal(index.x, _sorted_here(load_database(whole)).x)
    np.testing.assert_array_equal(index.sub_start, index.cluster_start)
    assert Engine(old, EngineConfig(refine=False)).pipeline.index.n_yaws == len(old.meta["yaws_deg"])


def test_block_digests_cover_the_file_in_blocks(tmp_path, monkeypatch):
    monkeypatch.setattr(S, "BLOCK_BYTES", 1000)
    file = tmp_path / "a.npy"
    data = np.arange(700, dtype=np.float32)
    np.save(file, data)
    raw = file.read_bytes()
    assert S.block_digests(file) == [f"{zlib.crc32(raw[i:i + 1000]):08x}" for i in range(0, len(raw), 1000)]


def test_the_index_under_a_tiny_memory_limit_is_built_in_groups(sources, whole, tmp_path):  # noqa: F811
    build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    tiny, ref = load_database(tmp_path / "db", projections=False), load_database(whole, projections=False)
    for name in S.ARRAYS:
        np.testing.assert_array_equal(getattr(tiny.search_index, name), getattr(ref.search_index, name))


def test_subclusters_put_every_member_with_its_nearest_representative():
    rng = np.random.default_rng(1)
    centres = rng.normal(size=(6, 14, 2))
    poses = (centres[rng.integers(0, 6, 4000)] + 0.3 * rng.normal(size=(4000, 14, 2))).astype(np.float32)
    embedding = poses.reshape(4000, -1)[:, :5].copy()
    order, sizes, reps = subclusters_of(poses, embedding, 17, seed=0)
    assert len(sizes) == subclusters_for(4000) == 4 and sizes.sum() == 4000 and (sizes > 0).all()
    assert sorted(order) == list(range(4000))
    ends = np.cumsum(sizes)
    assert np.all(reps < ends) and np.all(reps >= ends - sizes)  # each representative inside its sub-cluster
    ordered = poses[order]
    dist = pose_distances(ordered, ordered[reps])  # Eq. 1, by brute force
    label = np.repeat(np.arange(len(sizes)), sizes)
    assert np.all(dist[np.arange(4000), label] <= dist.min(axis=1) + 1e-5)
    for s in range(len(sizes)):  # rows in order within a sub-cluster
        assert np.all(np.diff(order[ends[s] - sizes[s]:ends[s]]) > 0)
    small, sizes_small, reps_small = subclusters_of(poses[:1000], embedding[:1000], 17, seed=0)
    np.testing.assert_array_equal(small, np.arange(1000))
    assert list(sizes_small) == [1000] and list(reps_small) == [17]  # one sub-cluster: the cluster as it was


@pytest.fixture(scope="module")
def few_clusters(sources, tmp_path_factory):
    """Clusters of ~2,600 projections each: two or three sub-clusters per cluster."""
    out = tmp_path_factory.mktemp("few") / "db"
    build([str(sources)], out, _config(clusters=3))
    return out


def test_the_second_level_searched_whole_is_the_method(few_clusters):
    db = load_database(few_clusters)
    assert np.diff(db.search_index.cluster_subs).max() > 1
    built = SearchIndex.from_database(db)
    here = _sorted_here(load_database(few_clusters))
    rng = np.random.default_rng(2)
    for row in rng.choice(db.n_projections, 30, replace=False):
        query = db.keypoints_2d[row] + rng.normal(0, 0.02, (14, 2)).astype(np.float32)
        visible = rng.random(14) > 0.15
        two_level = search_clustered(built, query, visible, 2, 10, 0, 10**6)[1]
        flat = search_clustered(here, query, visible, 2, 10, 0)[1]
        np.testing.assert_allclose(np.sort(two_level), np.sort(flat), rtol=1e-6)
        one_sub = search_clustered(built, query, visible, 2, 10, 0, 1)[1]
        assert one_sub.min() >= two_level.min() - 1e-7


def test_subclusters_do_not_depend_on_the_memory_limit(sources, few_clusters, tmp_path):
    build([str(sources)], tmp_path / "db", _config(clusters=3, memory_limit_mb=TINY_MB))
    tiny, ref = load_database(tmp_path / "db", projections=False), load_database(few_clusters, projections=False)
    for name in S.ARRAYS:
        np.testing.assert_array_equal(getattr(tiny.search_index, name), getattr(ref.search_index, name))


def test_the_nearest_subclusters_of_the_nearest_clusters_are_searched(few_clusters):
    db = load_database(few_clusters)
    index = SearchIndex.from_database(db)
    rng = np.random.default_rng(3)
    for row in rng.choice(db.n_projections, 20, replace=False):
        query = db.keypoints_2d[row] + rng.normal(0, 0.05, (14, 2)).astype(np.float32)
        visible = np.ones(14, dtype=bool)
        rows, dist = search_clustered(index, query, visible, 2, 10, 0, 1)  # 2 clusters, 2 × 1 sub-clusters
        rep = pose_distances(query[None], np.stack([index.rep_x.T, index.rep_y.T], axis=-1))[0]  # by brute force
        clusters = index.rep_cluster[np.argsort(rep, kind="stable")[:2]]
        subs = np.concatenate([np.arange(index.cluster_subs[c], index.cluster_subs[c + 1]) for c in clusters])
        sub = pose_distances(query[None], np.stack([index.sub_x[:, subs].T, index.sub_y[:, subs].T], axis=-1))[0]
        chosen = subs[np.argsort(sub, kind="stable")[:2]]
        members = np.concatenate([np.arange(index.sub_start[s], index.sub_start[s + 1]) for s in chosen])
        member = pose_distances(query[None], np.stack([index.x[:, members].T, index.y[:, members].T], axis=-1))[0]
        np.testing.assert_allclose(dist.min(), member.min(), rtol=1e-5)
        assert set(index.column_of_row[rows]) <= set(members)
