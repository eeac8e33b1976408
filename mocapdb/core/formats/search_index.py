"""The database's search index: the projections' 2D poses grouped by cluster, joint-major, as plain
``.npy`` files the runtime memory-maps instead of decoding and sorting the projections table (a
25 M-projection database starts in seconds, and its pages are shared between processes).

Files (``data_specs/database.md``, "Search index"), P projections, K clusters:

==================  =========  ===========  =====================================================
file                dtype      shape        holds
==================  =========  ===========  =====================================================
``index_x.npy``     float32    [14, P]      x of every joint, columns grouped by cluster
``index_y.npy``     float32    [14, P]      y, likewise
``index_rows.npy``  int64      [P]          the projection row of each column
``index_columns.npy`` int64    [P]          the column of each projection row (inverse of rows)
``index_cluster_start.npy`` int64 [K + 1]  cluster c is columns start[c]:start[c + 1]
``index_cluster_subs.npy`` int64 [K + 1]   cluster c's sub-clusters are subs[c]:subs[c + 1]
``index_sub_start.npy`` int64   [S + 1]     sub-cluster s is columns sub_start[s]:sub_start[s + 1]
``index_sub_rep.npy`` int64     [S]         the column of sub-cluster s's representative
==================  =========  ===========  =====================================================

Within a cluster the columns are grouped by sub-cluster, and follow the projection rows within one. Each file's manifest
entry has its size and the CRC-32 of every :data:`BLOCK_BYTES` block, checked in parallel threads: the tables keep
their sha256, the index (3.5 GB at 28 M projections) is checked at start-up, where CRC-32 (2.3 GB/s a core here)
takes half of sha256's time (1.3 GB/s) and still finds any damage short of a deliberate forgery.
"""
from __future__ import annotations

import os
import zlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError

BLOCK_BYTES = 64 << 20  # one CRC-32 per 64 MiB block: checked in parallel
N_JOINTS_2D = 14
ARRAYS = {"x": "float32", "y": "float32", "rows": "int64", "columns": "int64", "cluster_start": "int64",
          "cluster_subs": "int64", "sub_start": "int64", "sub_rep": "int64"}


class SearchIndexError(MocapdbError, RuntimeError):
    """A search index that does not match its manifest or its database."""


@dataclass
class SearchIndexArrays:
    """The index's arrays (read-only memory maps when loaded)."""

    x: np.ndarray              # [14, P] float32
    y: np.ndarray              # [14, P] float32
    rows: np.ndarray           # [P] int64
    columns: np.ndarray        # [P] int64
    cluster_start: np.ndarray  # [K + 1] int64
    cluster_subs: np.ndarray   # [K + 1] int64
    sub_start: np.ndarray      # [S + 1] int64
    sub_rep: np.ndarray        # [S] int64


def file_name(name: str) -> str:
    return f"index_{name}.npy"


def block_digests(file: Path, workers: int | None = None) -> list[str]:
    """CRC-32 (8 hex digits) of each :data:`BLOCK_BYTES` block of ``file``, in ``workers`` threads (zlib
    releases the GIL); read with ``pread``, so nothing is mapped into this process."""
    size = file.stat().st_size
    offsets = range(0, max(size, 1), BLOCK_BYTES)
    fd = os.open(file, os.O_RDONLY)
    try:
        def digest(offset: int) -> str:
            return f"{zlib.crc32(os.pread(fd, min(BLOCK_BYTES, size - offset), offset)):08x}"
        with ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
            return list(pool.map(digest, offsets))
    finally:
        os.close(fd)


def index_entry(file: Path) -> dict:
    """The manifest entry of an index file written at ``file``: name, bytes and block digests."""
    return {"file": file.name, "bytes": file.stat().st_size, "block_bytes": BLOCK_BYTES,
            "crc32_blocks": block_digests(file)}


def _check_entry(name: str, entry: object) -> None:
    if not (isinstance(entry, dict) and entry.get("file") == file_name(name) and isinstance(entry.get("bytes"), int)
            and entry.get("block_bytes") == BLOCK_BYTES and isinstance(entry.get("crc32_blocks"), list)):
        raise SearchIndexError(f"malformed search index entry {name!r} in the manifest")


def load_search_index(path: Path, entries: dict, n_projections: int, n_clusters: int,
                      verify_checksums: bool = True) -> SearchIndexArrays:
    """The index files of the database at ``path``, memory-mapped read-only, after checking each
    one's size, dtype and shape (and, with ``verify_checksums``, its block digests) against the
    manifest ``entries`` and the database's ``n_projections`` and ``n_clusters``."""
    if not isinstance(entries, dict) or set(entries) != set(ARRAYS):
        raise SearchIndexError(f"{path}: the manifest's search index needs the arrays {sorted(ARRAYS)}")
    shapes = {"x": (N_JOINTS_2D, n_projections), "y": (N_JOINTS_2D, n_projections), "rows": (n_projections,),
              "columns": (n_projections,), "cluster_start": (n_clusters + 1,), "cluster_subs": (n_clusters + 1,)}
    arrays: dict[str, np.ndarray] = {}
    for name, dtype in ARRAYS.items():
        if name == "sub_start":  # S sub-clusters: the last of cluster_subs, read before
            n_subs = int(arrays["cluster_subs"][-1])
            shapes.update(sub_start=(n_subs + 1,), sub_rep=(n_subs,))
        _check_entry(name, entries[name])
        file = path / file_name(name)
        if not file.is_file() or file.stat().st_size != entries[name]["bytes"]:
            raise SearchIndexError(f"{file}: missing, or not the manifest's {entries[name]['bytes']} bytes")
        if verify_checksums and block_digests(file) != entries[name]["crc32_blocks"]:
            raise SearchIndexError(f"checksum mismatch: {file} is damaged: rebuild the database, or --no-verify "
                                   "to load it anyway")
        try:
            arrays[name] = np.load(file, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise SearchIndexError(f"{file}: not a .npy array ({exc})") from None
        if arrays[name].dtype != np.dtype(dtype) or arrays[name].shape != shapes[name]:
            raise SearchIndexError(f"{file}: {arrays[name].dtype} {arrays[name].shape}, expected {dtype} "
                                   f"{shapes[name]}")
    _check_ranges(path, arrays, n_projections)
    return SearchIndexArrays(**arrays)


def _check_ranges(path: Path, arrays: dict, n_projections: int) -> None:
    """Clusters and sub-clusters cover the columns in order, each sub-cluster inside its cluster and
    holding its representative: O(K + S), the columns themselves are not read."""
    start, subs, sub_start, sub_rep = (arrays[k] for k in ("cluster_start", "cluster_subs", "sub_start", "sub_rep"))
    for name, values, last in (("cluster starts", start, n_projections),
                               ("sub-cluster starts", sub_start, n_projections),
                               ("clusters' sub-clusters", subs, len(sub_rep))):
        if values[0] != 0 or values[-1] != last or np.any(np.diff(values) < 0):
            raise SearchIndexError(f"{path}: the search index's {name} are not 0 … {last}, rising")
    if not np.array_equal(sub_start[subs[:-1]][np.diff(subs) > 0], start[:-1][np.diff(subs) > 0]):
        raise SearchIndexError(f"{path}: the search index's sub-clusters do not start where their clusters do")
    if np.any(sub_rep < sub_start[:-1]) or np.any(sub_rep >= sub_start[1:]):
        raise SearchIndexError(f"{path}: a sub-cluster's representative lies outside it")
