"""The database's search index (issue 21): the builder's out-of-core counting sort equals the runtime's
in-memory sort of the projections table, the runtime loads it memory-mapped without the projections
table and finds the same poses, damage is found by its block digests, and a database without one
(built before it existed) still runs."""
import hashlib
import json
import shutil

import numpy as np
import pytest

from mocapdb.builder.index import columns_of
from mocapdb.builder.pipeline import build
from mocapdb.core.formats import search_index as S
from mocapdb.core.formats.database import DatabaseError, load_database
from mocapdb.runtime.engine import Engine, EngineConfig
from mocapdb.runtime.search import SearchIndex

from . import test_builder
from .test_build_out_of_core import TINY_MB, whole  # noqa: F401 - the fixture
from .test_builder import _config

sources = test_builder.sources  # the fixture: two clips, 7,920 projections

FIELDS = ("x", "y", "rows", "cluster_start", "rep_x", "rep_y", "rep_cluster", "column_of_row", "frame_clip")


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


def test_the_built_index_is_the_runtime_sort(whole):  # noqa: F811
    db = load_database(whole)
    built = SearchIndex.from_database(db)
    assert isinstance(db.search_index.x, np.memmap) and not db.search_index.x.flags.writeable
    here = _sorted_here(db)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(built, name), getattr(here, name), err_msg=name)


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
        found = [engine._search(query, visible) for engine in engines]
        np.testing.assert_array_equal(found[0][0], found[1][0])
        np.testing.assert_array_equal(found[0][1], found[1][1])
    np.testing.assert_array_equal(engines[1].index.pose(int(rows[0])), full.keypoints_2d[rows[0]])


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
    index = SearchIndex.from_database(old)
    np.testing.assert_array_equal(index.x, SearchIndex.from_database(load_database(whole)).x)


def test_block_digests_cover_the_file_in_blocks(tmp_path, monkeypatch):
    monkeypatch.setattr(S, "BLOCK_BYTES", 1000)
    file = tmp_path / "a.npy"
    data = np.arange(700, dtype=np.float32)
    np.save(file, data)
    raw = file.read_bytes()
    assert S.block_digests(file) == [hashlib.sha256(raw[i:i + 1000]).hexdigest() for i in range(0, len(raw), 1000)]


def test_the_index_under_a_tiny_memory_limit_is_built_in_groups(sources, whole, tmp_path):  # noqa: F811
    build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    tiny, ref = load_database(tmp_path / "db", projections=False), load_database(whole, projections=False)
    for name in S.ARRAYS:
        np.testing.assert_array_equal(getattr(tiny.search_index, name), getattr(ref.search_index, name))
