"""The build's ``index`` stage: the search index's columns in cluster order, then groups of whole
clusters as large as the memory limit allows, cut into sub-clusters and written to the work
folder, resumable group by group. The kernels and the method are in :mod:`mocapdb.builder.index`.
"""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from mocapdb.builder.index import BYTES_PER_COLUMN, columns_of, gather_group, subclusters_of
from mocapdb.builder.run import MIN_CHUNK_ROWS, BuildRun, row_ranges
from mocapdb.builder.work import WorkArray
from mocapdb.core.progress import progress

# Memory per chunk row of each stage, bytes (measured, with margin; data_specs/build.md "Memory"):
INDEX_BYTES_PER_ROW = 256            # the index: a pose read, its label and column
INDEX_GROUP_BYTES_MAX = 1 << 30      # the index's column groups: larger ones save a pass over the poses
                                     # (~1 s at 28 M) but would make memory grow with the library


def _index_columns(run: BuildRun) -> np.ndarray:
    """Pass 1 of the index: every projection's column in cluster order (``index_sorted``, scratch),
    streamed over the labels; returns the cluster starts ``[K + 1]``."""
    cluster = run.work.array("cluster")
    rows = run.plan.rows(INDEX_BYTES_PER_ROW, MIN_CHUNK_ROWS)
    counts = np.zeros(run.config.clusters, dtype=np.int64)
    for start, stop in row_ranges(len(cluster), rows):
        counts += np.bincount(cluster[start:stop], minlength=len(counts))
    cluster_start = np.concatenate([[0], np.cumsum(counts)])
    columns = run.work.new_array("index_sorted", np.int64, (), len(cluster))
    next_free = cluster_start[:-1].copy()
    for start, stop in row_ranges(len(cluster), rows):
        columns_of(cluster[start:stop], next_free, columns[start:stop])
    return cluster_start


def _cluster_groups(cluster_start: np.ndarray, first: int, max_columns: int) -> Iterator[tuple[int, int]]:
    """``(c0, c1)``: runs of whole clusters from ``first`` on, each at most ``max_columns`` columns
    (or one cluster)."""
    c0, k = first, len(cluster_start) - 1
    while c0 < k:
        c1 = max(c0 + 1, int(np.searchsorted(cluster_start, cluster_start[c0] + max_columns, side="right")) - 1)
        yield c0, min(c1, k)
        c0 = min(c1, k)


def _start_index(run: BuildRun, record: dict) -> None:
    """The index's pass 1 and its empty output arrays (a fresh stage)."""
    n = run.n_projections
    run.work.save("index_cluster_start", _index_columns(run))
    run.work.new_array("index_x", np.float32, (n,), 14)
    run.work.new_array("index_y", np.float32, (n,), 14)
    for name in ("index_rows", "index_columns"):
        run.work.new_array(name, np.int64, (), n)
    for name in ("index_sub_start", "index_sub_rep", "index_subs_of"):
        run.work.new_array(name, np.int64)
    record.update(clusters_done=0, columns_done=0, subs_done=0)
    run.work.commit(run.work.array("index_sorted"))


def _subcluster_group(run: BuildRun, lo: int, c0: int, c1: int, buffers: tuple, outputs: dict) -> None:
    """Cut clusters ``c0:c1`` (columns from ``lo`` in the group's ``buffers``) into sub-clusters:
    their columns reordered in place, sub-cluster starts, representatives (columns) and counts
    appended to ``outputs``."""
    gx, gy, grows = buffers
    cluster_start, reps = outputs["cluster_start"], outputs["representatives"]
    embedding = np.load(run.work.path / "embedding.npy", mmap_mode="r")
    for c in range(c0, c1):
        a, b = cluster_start[c] - lo, cluster_start[c + 1] - lo
        if a == b:
            outputs["index_subs_of"].append(np.array([0]))
            continue
        members = grows[a:b]
        poses = np.stack([gx[:, a:b].T, gy[:, a:b].T], axis=-1)
        own = int(np.searchsorted(members, reps[c]))
        order, sizes, rep_pos = subclusters_of(poses, embedding[members], own, run.config.seed + c)
        gx[:, a:b], gy[:, a:b], grows[a:b] = gx[:, a:b][:, order], gy[:, a:b][:, order], members[order]
        outputs["index_sub_start"].append(lo + a + np.concatenate([[0], np.cumsum(sizes)[:-1]]))
        outputs["index_sub_rep"].append(lo + a + rep_pos)
        outputs["index_subs_of"].append(np.array([len(sizes)]))


def index_stage(run: BuildRun) -> list[WorkArray]:
    """The search index (``builder/index.py``): columns in cluster order, then groups of whole
    clusters as large as the memory limit allows copied, cut into sub-clusters and written; a
    resumed run goes on from the groups done."""
    record, n = run.work.record("index"), run.n_projections
    if "columns_done" not in record:
        _start_index(run, record)
    names = ("index_x", "index_y", "index_rows", "index_columns", "index_sub_start", "index_sub_rep", "index_subs_of")
    arrays = {name: run.work.array(name) for name in names}
    for name, done in (("index_sub_start", "subs_done"), ("index_sub_rep", "subs_done"),
                       ("index_subs_of", "clusters_done")):
        arrays[name].resize(record[done])  # what an interrupted run appended after its last commit goes
    keypoints, sorted_columns = run.work.array("keypoints_2d"), run.work.array("index_sorted")
    cluster_start = run.work.load("index_cluster_start")
    outputs = {"cluster_start": cluster_start, "representatives": run.work.load("representatives"), **arrays}
    chunk = run.plan.rows(INDEX_BYTES_PER_ROW, MIN_CHUNK_ROWS)
    group_bytes = min(run.plan.budget_bytes, INDEX_GROUP_BYTES_MAX) - chunk * INDEX_BYTES_PER_ROW
    group = max(MIN_CHUNK_ROWS, group_bytes // BYTES_PER_COLUMN)
    bar = progress(total=n, initial=record["columns_done"], desc="index", unit="projection")
    for c0, c1 in _cluster_groups(cluster_start, record["clusters_done"], group):
        lo, hi = int(cluster_start[c0]), int(cluster_start[c1])
        buffers = np.empty((14, hi - lo), np.float32), np.empty((14, hi - lo), np.float32), np.empty(hi - lo, np.int64)
        for start, stop in row_ranges(n, chunk):
            gather_group(keypoints[start:stop], sorted_columns[start:stop], start, lo, hi, *buffers)
        _subcluster_group(run, lo, c0, c1, buffers, outputs)
        for joint in range(14):
            arrays["index_x"].write_at(joint, lo, buffers[0][joint])
            arrays["index_y"].write_at(joint, lo, buffers[1][joint])
        arrays["index_rows"][lo:hi] = buffers[2]
        arrays["index_columns"].put(buffers[2], np.arange(lo, hi))
        record.update(clusters_done=c1, columns_done=hi, subs_done=len(arrays["index_sub_start"]))
        run.work.commit(*arrays.values())
        bar.update(hi - lo)
    bar.close()
    _finish_index(run, arrays)
    return list(arrays.values())


def _finish_index(run: BuildRun, arrays: dict) -> None:
    """The index's small arrays in their final form: sub-cluster starts ending at P, each cluster's
    first sub-cluster ``[K + 1]`` (the scratch column order stays until the work folder goes: a run
    interrupted here goes on from it)."""
    starts = np.array(arrays["index_sub_start"][0:len(arrays["index_sub_start"])])
    subs_of = np.array(arrays["index_subs_of"][0:len(arrays["index_subs_of"])])
    run.work.save("index_cluster_subs", np.concatenate([[0], np.cumsum(subs_of)]))
    run.work.save("index_sub_start", np.concatenate([starts, [run.n_projections]]))  # a resume cuts it back
    arrays["index_sub_start"] = run.work.array("index_sub_start")
