"""The on-disk motion database's format: a directory of Parquet tables described by
``manifest.json``; here its schema (tables, columns, versions), :class:`MotionDatabase` (its
content) and the checks that content is consistent. The builder writes it
(:mod:`~mocapdb.core.formats.database_writer`), the runtime loads it
(:mod:`~mocapdb.core.formats.database_reader`). Layout, columns and guarantees:
``data_specs/database.md``.
"""
from __future__ import annotations

import json
import math
import numbers
from collections.abc import Mapping
from dataclasses import dataclass
from typing import NamedTuple, TypeGuard

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB
from mocapdb.core.formats.search_index import SearchIndexArrays

SCHEMA_VERSION = 2  # 2: clips.mirrored
FORMAT = "mocapdb"
MANIFEST = "manifest.json"
MAX_MANIFEST_BYTES = MIB  # the manifest names five tables and the build's settings
N_KEYPOINTS = 15
N_KEYPOINTS_2D = 14


class DatabaseError(MocapdbError, RuntimeError):
    """A database that cannot be written or loaded; the message names the path and the problem."""


class Column(NamedTuple):
    """One column of a table: where it is in :class:`MotionDatabase` and in the Parquet file."""

    field: str  # MotionDatabase attribute
    name: str  # Parquet column name
    dtype: str | None  # numpy dtype of the values; None for text
    shape: tuple[int | None, ...] = ()  # per-row shape; None: taken from the data


TABLES: dict[str, tuple[Column, ...]] = {
    "clips": (
        Column("clip_name", "name", None),
        Column("clip_source", "source", None),
        Column("clip_source_fps", "source_fps", "float64"),
        Column("clip_n_frames", "n_frames", "int32"),
        Column("clip_first_frame", "first_frame", "int64"),
        Column("clip_convention", "convention", None),
        Column("clip_credit", "credit", None),
        Column("clip_mirrored", "mirrored", "bool"),
    ),
    "frames": (
        Column("frame_clip", "clip", "int32"),
        Column("frame_index", "index", "int32"),
        Column("quaternions", "quaternions", "float32", (None, 4)),
        Column("positions", "positions", "float32", (N_KEYPOINTS, 3)),
    ),
    "projections": (
        Column("proj_frame", "frame", "int64"),
        Column("proj_yaw", "yaw", "int16"),
        Column("keypoints_2d", "keypoints_2d", "float32", (N_KEYPOINTS_2D, 2)),
        Column("embedding", "embedding", "float32", (None,)),
        Column("cluster", "cluster", "int32"),
    ),
    "clusters": (
        Column("centroids", "centroid", "float32", (None,)),
        Column("representative", "representative", "int64"),
        Column("cluster_size", "size", "int32"),
    ),
}


@dataclass(eq=False)
class MotionDatabase:
    """Database content; shapes and meanings of every field are in ``data_specs/database.md``.

    Text columns are ``list[str]``, all others numpy arrays of exactly the documented dtype.
    Arrays returned by :func:`load_database` may be read-only views of Arrow memory. The
    ``projections`` fields are None when it was loaded without them (the runtime reads the poses
    from ``search_index``, memory-mapped).
    """

    meta: dict
    clip_name: list[str]
    clip_source: list[str]
    clip_source_fps: np.ndarray
    clip_n_frames: np.ndarray
    clip_first_frame: np.ndarray
    clip_convention: list[str]
    clip_credit: list[str]
    clip_mirrored: np.ndarray
    frame_clip: np.ndarray
    frame_index: np.ndarray
    quaternions: np.ndarray
    positions: np.ndarray
    proj_frame: np.ndarray
    proj_yaw: np.ndarray
    keypoints_2d: np.ndarray
    embedding: np.ndarray
    cluster: np.ndarray
    centroids: np.ndarray
    representative: np.ndarray
    cluster_size: np.ndarray
    search_index: SearchIndexArrays | None = None  # the builder's cluster-ordered poses (search_index.py)

    @property
    def n_clips(self) -> int:
        return len(self.clip_name)

    @property
    def n_frames(self) -> int:
        return len(self.frame_clip)

    @property
    def n_projections(self) -> int:
        return len(self.proj_frame) if self.proj_frame is not None else len(self.search_index.rows)

    @property
    def n_clusters(self) -> int:
        return len(self.centroids)

    def validate(self) -> None:
        """Raise DatabaseError if dtypes, shapes, meta or cross-table indices are inconsistent."""
        check_meta(self.meta)
        loaded = TABLES if self.proj_frame is not None else {t: c for t, c in TABLES.items() if t != "projections"}
        for table, columns in loaded.items():
            check_columns(vars(self), table, columns)
        for name in ("embedding", "centroids") if self.embedding is not None else ("centroids",):
            width = getattr(self, name).shape[1]
            if width != self.meta["dims"]:
                raise DatabaseError(f"{name} width {width} differs from meta dims {self.meta['dims']}")
        _check_clips(self)
        if self.proj_frame is not None:
            _check_range("proj_frame", self.proj_frame, 0, self.n_frames)
            _check_range("proj_yaw", self.proj_yaw, 0, len(self.meta["yaws_deg"]))
            _check_clusters(self)
        if self.search_index is not None:
            _check_index(self, self.search_index)


def _is_real(x: object) -> TypeGuard[float]:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def check_meta(meta: object) -> None:
    if not isinstance(meta, dict):
        raise DatabaseError(f"meta must be a dict, got {type(meta).__name__}")
    try:
        json.dumps(meta, allow_nan=False)
    except (TypeError, ValueError) as e:
        raise DatabaseError(f"meta is not JSON-serialisable: {e}") from None
    fps, yaws, dims = meta.get("fps"), meta.get("yaws_deg"), meta.get("dims")
    if not (_is_real(fps) and fps > 0):
        raise DatabaseError(f"meta fps must be a positive number, got {fps!r}")
    if not (isinstance(yaws, list) and yaws and all(_is_real(y) for y in yaws)):
        raise DatabaseError(f"meta yaws_deg must be a non-empty list of numbers, got {yaws!r}")
    if not (isinstance(dims, int) and not isinstance(dims, bool) and dims >= 1):
        raise DatabaseError(f"meta dims must be a positive int, got {dims!r}")


def shape_text(col: Column) -> str:
    return "[" + ", ".join(["rows", *("*" if s is None else str(s) for s in col.shape)]) + "]"


def check_columns(values: Mapping[str, object], table: str, columns: tuple[Column, ...]) -> None:
    """DatabaseError unless ``values`` (field → column) holds every column of ``table`` with its dtype
    and row shape, all of one length."""
    lengths = {}
    for col in columns:
        value = values[col.field]
        if col.dtype is None:
            if not (isinstance(value, list) and all(isinstance(s, str) for s in value)):
                raise DatabaseError(f"{col.field} must be a list of str")
        elif not isinstance(value, np.ndarray) or value.dtype != col.dtype:
            got = value.dtype if isinstance(value, np.ndarray) else type(value).__name__
            raise DatabaseError(f"{col.field} must be a numpy {col.dtype} array, got {got}")
        elif value.ndim != 1 + len(col.shape) or any(
            v < 1 if s is None else v != s for s, v in zip(col.shape, value.shape[1:])
        ):
            raise DatabaseError(f"{col.field} has shape {value.shape}, expected {shape_text(col)}")
        lengths[col.field] = len(value)
    if len(set(lengths.values())) > 1:
        raise DatabaseError(f"{table} columns have different lengths: {lengths}")


def _check_range(name: str, values: np.ndarray, lo: int, hi: int) -> None:
    if values.size and (values.min() < lo or values.max() >= hi):
        raise DatabaseError(
            f"{name} out of range: values span [{values.min()}, {values.max()}], allowed [{lo}, {hi - 1}]"
        )


def _check_clips(db: MotionDatabase) -> None:
    counts = db.clip_n_frames.astype(np.int64)
    starts = np.cumsum(counts) - counts
    if (counts < 0).any() or counts.sum() != db.n_frames or not np.array_equal(db.clip_first_frame, starts):
        raise DatabaseError(
            f"clip_first_frame/clip_n_frames do not cover the {db.n_frames} frames contiguously in clip order"
        )
    if not np.array_equal(db.frame_clip, np.repeat(np.arange(db.n_clips), counts)):
        raise DatabaseError("frame_clip does not match the clips' frame ranges")
    if not np.array_equal(db.frame_index, np.arange(db.n_frames) - np.repeat(starts, counts)):
        raise DatabaseError("frame_index is not 0, 1, 2, ... within each clip")


def _filled_clusters(db: MotionDatabase) -> np.ndarray:
    """The clusters with members (by ``cluster_size``), once every representative is a projection row
    exactly for them and −1 for the empty ones."""
    _check_range("representative", db.representative, -1, db.n_projections)
    filled = db.cluster_size > 0
    if not np.array_equal(db.representative >= 0, filled):
        raise DatabaseError("representative must be -1 exactly for the empty clusters")
    return np.flatnonzero(filled)


def _check_clusters(db: MotionDatabase) -> None:
    _check_range("cluster", db.cluster, 0, db.n_clusters)
    sizes = np.bincount(db.cluster, minlength=db.n_clusters)
    if not np.array_equal(sizes, db.cluster_size):
        raise DatabaseError("cluster_size differs from the number of projections in each cluster")
    filled = _filled_clusters(db)
    if not np.array_equal(db.cluster[db.representative[filled]], filled):
        raise DatabaseError("a cluster's representative projection belongs to another cluster")


def _check_index(db: MotionDatabase, index: SearchIndexArrays) -> None:
    """The search ``index`` agrees with the clusters table (sizes, each representative in its cluster's
    columns): O(K), nothing of the P columns read but the representatives'."""
    if db.n_projections != db.n_frames * len(db.meta["yaws_deg"]):
        raise DatabaseError("the search index does not hold one projection per frame and yaw")
    if not np.array_equal(np.diff(index.cluster_start), db.cluster_size):
        raise DatabaseError("the search index's cluster sizes differ from cluster_size")
    filled = _filled_clusters(db)
    column = index.columns[db.representative[filled]]
    if np.any(column < index.cluster_start[filled]) or np.any(column >= index.cluster_start[filled + 1]):
        raise DatabaseError("a cluster's representative lies outside its columns of the search index")


def nonfinite_row(values: np.ndarray) -> int | None:
    """The first row of ``values`` holding a NaN or infinity, None if there is none (vectorised)."""
    finite = np.isfinite(values)
    if finite.all():
        return None
    return int(np.argmin(finite.reshape(len(values), -1).all(axis=1)))
