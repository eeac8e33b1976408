"""The on-disk motion database: a directory of Parquet tables described by ``manifest.json``.

The builder writes it (:func:`write_database`), the real-time runtime loads it
(:func:`load_database`). Layout, columns and guarantees: ``data_specs/database.md``.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import numbers
import os
import shutil
from collections.abc import Iterable, Mapping
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, NamedTuple

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import (
    MIB,
    fsync_dir,
    output_target,
    read_input_text,
    recover_interrupted,
    replace_folder,
    sibling,
    write_synced,
)
from mocapdb.core.formats.search_index import ARRAYS as INDEX_ARRAYS
from mocapdb.core.formats.search_index import SearchIndexArrays, SearchIndexError, index_entry, load_search_index
from mocapdb.core.formats.search_index import file_name as index_file_name

SCHEMA_VERSION = 2  # 2: clips.mirrored
FORMAT = "mocapdb"
MANIFEST = "manifest.json"
MAX_MANIFEST_BYTES = MIB  # the manifest names five tables and the build's settings
N_KEYPOINTS = 15
N_KEYPOINTS_2D = 14


class DatabaseError(MocapdbError, RuntimeError):
    """A database that cannot be written or loaded; the message names the path and the problem."""


class _Column(NamedTuple):
    field: str  # MotionDatabase attribute
    name: str  # Parquet column name
    dtype: str | None  # numpy dtype of the values; None for text
    shape: tuple[int | None, ...] = ()  # per-row shape; None: taken from the data


_TABLES: dict[str, tuple[_Column, ...]] = {
    "clips": (
        _Column("clip_name", "name", None),
        _Column("clip_source", "source", None),
        _Column("clip_source_fps", "source_fps", "float64"),
        _Column("clip_n_frames", "n_frames", "int32"),
        _Column("clip_first_frame", "first_frame", "int64"),
        _Column("clip_convention", "convention", None),
        _Column("clip_credit", "credit", None),
        _Column("clip_mirrored", "mirrored", "bool"),
    ),
    "frames": (
        _Column("frame_clip", "clip", "int32"),
        _Column("frame_index", "index", "int32"),
        _Column("quaternions", "quaternions", "float32", (None, 4)),
        _Column("positions", "positions", "float32", (N_KEYPOINTS, 3)),
    ),
    "projections": (
        _Column("proj_frame", "frame", "int64"),
        _Column("proj_yaw", "yaw", "int16"),
        _Column("keypoints_2d", "keypoints_2d", "float32", (N_KEYPOINTS_2D, 2)),
        _Column("embedding", "embedding", "float32", (None,)),
        _Column("cluster", "cluster", "int32"),
    ),
    "clusters": (
        _Column("centroids", "centroid", "float32", (None,)),
        _Column("representative", "representative", "int64"),
        _Column("cluster_size", "size", "int32"),
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
        _check_meta(self.meta)
        loaded = _TABLES if self.proj_frame is not None else {t: c for t, c in _TABLES.items() if t != "projections"}
        for table, columns in loaded.items():
            _check_columns(vars(self), table, columns)
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
            _check_index(self)


def _is_real(x: object) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def _check_meta(meta: object) -> None:
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


def _shape_text(col: _Column) -> str:
    return "[" + ", ".join(["rows", *("*" if s is None else str(s) for s in col.shape)]) + "]"


def _check_columns(values: Mapping[str, object], table: str, columns: tuple[_Column, ...]) -> None:
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
            raise DatabaseError(f"{col.field} has shape {value.shape}, expected {_shape_text(col)}")
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


def _check_index(db: MotionDatabase) -> None:
    """The search index agrees with the clusters table (sizes, each representative in its cluster's
    columns): O(K), nothing of the P columns read but the representatives'."""
    index = db.search_index
    if db.n_projections != db.n_frames * len(db.meta["yaws_deg"]):
        raise DatabaseError("the search index does not hold one projection per frame and yaw")
    if not np.array_equal(np.diff(index.cluster_start), db.cluster_size):
        raise DatabaseError("the search index's cluster sizes differ from cluster_size")
    filled = _filled_clusters(db)
    column = index.columns[db.representative[filled]]
    if np.any(column < index.cluster_start[filled]) or np.any(column >= index.cluster_start[filled + 1]):
        raise DatabaseError("a cluster's representative lies outside its columns of the search index")


# ----------------------------------------------------------------------------------- writing


def write_database(db: MotionDatabase, path: str | os.PathLike) -> int:
    """Validate ``db`` and write it atomically as directory ``path``; return its size in bytes.

    Replaces an existing mocapdb database or empty directory at ``path``; refuses anything else,
    and a database holding a NaN or infinite value. A symlink at ``path`` is followed: the database
    is written at its target and the link stays. Leftovers of interrupted writes to ``path`` are
    cleaned up first (:func:`recover_interrupted`). Each table is one row group.
    """
    db.validate()
    with DatabaseWriter(path, db.meta) as writer:
        for table, columns in _TABLES.items():
            writer.write_table(table, [{col.field: getattr(db, col.field) for col in columns}])
        return writer.finish()


class DatabaseWriter:
    """Writes a database table by table, row group by row group, as the rows come: never a whole
    table in memory. Files go to a temporary folder beside the target (``.<name>.tmp-<pid>``) that
    :meth:`finish` puts in place atomically, as :func:`write_database` does; leaving the ``with``
    block by an exception removes it. Each file's sha256 is computed while it is written.
    """

    def __init__(self, path: str | os.PathLike, meta: dict):
        _check_meta(meta)
        self.path = output_target(path)
        check_output_path(self.path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        recover_interrupted(self.path)
        self.meta = meta
        self.tables: dict[str, dict] = {}
        self.search_index: dict[str, dict] | None = None
        self._tmp = sibling(self.path, "tmp", os.getpid())
        self._tmp.mkdir()

    def __enter__(self) -> DatabaseWriter:
        return self

    def __exit__(self, kind, value, traceback) -> None:
        if kind is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)

    def write_table(self, table: str, chunks: Iterable[Mapping[str, np.ndarray | list[str]]]) -> None:
        """Write ``table`` from ``chunks`` (each: field → values of the next rows), one row group per
        chunk; each chunk's dtypes, row shapes and float values (finite) are checked first. At
        least one chunk, which may have no rows."""
        self.tables[table] = _write_table((_checked_arrow(chunk, table) for chunk in chunks),
                                          self._tmp / f"{table}.parquet")

    def add_search_index(self, files: Mapping[str, Path]) -> None:
        """Add the search index (``search_index.py``): each array's ``.npy`` file, hard-linked (copied
        across file systems) into the database, its block digests computed."""
        self.search_index = {}
        for name in INDEX_ARRAYS:
            target = self._tmp / index_file_name(name)
            try:
                os.link(files[name], target)
            except OSError:
                shutil.copyfile(files[name], target)
            self.search_index[name] = index_entry(target)

    def finish(self) -> int:
        """Write the manifest (last), put the database in place; return its size in bytes."""
        if set(self.tables) != set(_TABLES):
            raise DatabaseError(f"{self.path}: tables {sorted(set(_TABLES) - set(self.tables))} not written")
        manifest = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "meta": self.meta,
                    "tables": {name: self.tables[name] for name in _TABLES}}
        if self.search_index is not None:
            manifest["search_index"] = self.search_index
        data = json.dumps(manifest, indent=2).encode("utf-8")
        write_synced(self._tmp / MANIFEST, data)
        fsync_dir(self._tmp)
        _check_replaceable(self.path)
        replace_folder(self._tmp, self.path)
        index = self.search_index or {}
        return len(data) + sum(entry["bytes"] for entry in (*self.tables.values(), *index.values()))


def _is_float(col: _Column) -> bool:
    return col.dtype is not None and col.dtype.startswith("float")


def _nonfinite_row(values: np.ndarray) -> int | None:
    """The first row of ``values`` holding a NaN or infinity, None if there is none (vectorised)."""
    finite = np.isfinite(values)
    if finite.all():
        return None
    return int(np.argmin(finite.reshape(len(values), -1).all(axis=1)))


def _checked_arrow(values: Mapping[str, object], table: str) -> pa.Table:
    """Rows of ``table`` (field → values) as an Arrow table, once their columns are checked and
    their floats finite (else DatabaseError)."""
    _check_columns(values, table, _TABLES[table])
    _check_finite(values)
    return _to_arrow(values, table)


def _check_finite(values: Mapping[str, object]) -> None:
    bad = [field for field, value in values.items()
           if isinstance(value, np.ndarray) and value.dtype.kind == "f" and _nonfinite_row(value) is not None]
    if bad:
        raise DatabaseError(f"NaN or infinite values in {', '.join(bad)}: refusing to write them")


def _is_database(path: Path) -> bool:
    try:
        manifest = json.loads(read_input_text(path / MANIFEST, MAX_MANIFEST_BYTES, DatabaseError, "manifest"))
    except (DatabaseError, ValueError, RecursionError):
        return False
    return isinstance(manifest, dict) and manifest.get("format") == FORMAT


def _check_replaceable(path: Path) -> None:
    if not os.path.lexists(path):
        return
    if path.is_dir() and (not any(path.iterdir()) or _is_database(path)):
        return
    raise DatabaseError(
        f"{path}: exists and is not a mocapdb database (no {MANIFEST} with format {FORMAT!r}); "
        "refusing to replace it: choose another path or remove it yourself"
    )


def check_output_path(path: str | os.PathLike) -> None:
    """Raise DatabaseError unless :func:`write_database` may write ``path``: nothing there but an
    empty folder or a mocapdb database, in a folder that exists or can be created and that this
    process may write. Cheap, so a build checks it before any work."""
    path = output_target(path)
    _check_replaceable(path)
    folder = next(p for p in path.parents if os.path.lexists(p))
    if not folder.is_dir():
        raise DatabaseError(f"{path}: cannot create its folder {path.parent}: {folder} is not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise DatabaseError(f"{path}: cannot write in {folder} (permission denied or read-only)")


def _to_arrow(values: Mapping[str, object], table: str) -> pa.Table:
    arrays, fields = [], []
    for col in _TABLES[table]:
        value = values[col.field]
        if col.dtype is None:
            array = pa.array(value, pa.string())
        elif col.shape:
            item = pa.field("item", pa.float32(), nullable=False)
            array = pa.FixedSizeListArray.from_arrays(
                pa.array(np.ascontiguousarray(value).reshape(-1)),
                type=pa.list_(item, math.prod(value.shape[1:])),
            )
        else:
            array = pa.array(value)
        arrays.append(array)
        fields.append(pa.field(col.name, array.type, nullable=False))
    metadata = {"mocapdb.schema_version": str(SCHEMA_VERSION), "mocapdb.table": table}
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=metadata))


class _HashingFile(io.RawIOBase):
    """A binary file to write that keeps the sha256 and the size of what went through it."""

    def __init__(self, file: BinaryIO):
        super().__init__()
        self._file, self.size, self.sha256 = file, 0, hashlib.sha256()

    def writable(self) -> bool:
        return True

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        self.sha256.update(view)
        self.size += len(view)
        return self._file.write(view)

    def tell(self) -> int:
        return self.size


def _write_table(batches: Iterable[pa.Table], file: Path) -> dict:
    """Write ``batches`` (Arrow tables of one schema) as zstd Parquet to ``file``, one row group
    each, hashing as it goes; return the file's manifest entry. At least one batch."""
    rows, writer = 0, None
    with open(file, "wb") as raw:
        sink = _HashingFile(raw)
        try:
            for batch in batches:
                if writer is None:
                    scalar_columns = [f.name for f in batch.schema if not pa.types.is_fixed_size_list(f.type)]
                    writer = pq.ParquetWriter(sink, batch.schema, compression="zstd", use_dictionary=scalar_columns)
                writer.write_table(batch, row_group_size=max(batch.num_rows, 1))
                rows += batch.num_rows
        finally:
            if writer is not None:
                writer.close()
        if writer is None:
            raise ValueError(f"{file.name}: no rows given, not even an empty batch")
        raw.flush()
        os.fsync(raw.fileno())
    return {"file": file.name, "rows": rows, "bytes": sink.size, "sha256": sink.sha256.hexdigest()}


# ----------------------------------------------------------------------------------- loading


def load_database(path: str | os.PathLike, verify_checksums: bool = True, projections: bool = True
                  ) -> MotionDatabase:
    """Load and validate the database at ``path``; raise DatabaseError on any problem.

    Sizes are always checked against the manifest, and every float value must be finite; the
    files' sha256 checksums unless ``verify_checksums`` is False (``--no-verify``). The search index
    (databases built since it exists) is memory-mapped, not read; with ``projections`` False and
    an index, the projections table is not read either (its fields are None): what the runtime
    needs, in seconds at any size. It must still be there, of the manifest's size, with a Parquet
    footer naming that table and its rows (:func:`_check_unread`); ``mocapdb verify`` reads it all.
    """
    path = Path(path)
    manifest = _read_manifest(path)
    index_entries = manifest.get("search_index")
    skip = set() if projections or index_entries is None else {"projections"}
    for table in skip:
        _check_unread(path / manifest["tables"][table]["file"], table, manifest["tables"][table])
    columns = {col.field: None for table in skip for col in _TABLES[table]}
    with ThreadPoolExecutor(max_workers=1) as hasher:  # hashing overlaps Parquet decoding (both release the GIL)
        for table, entry in manifest["tables"].items():
            if table not in skip:
                columns.update(_read_table(path, table, entry, hasher if verify_checksums else None))
    db = MotionDatabase(meta=manifest["meta"], **columns)
    if index_entries is not None:
        try:
            db.search_index = load_search_index(path, index_entries, manifest["tables"]["projections"]["rows"],
                                                manifest["tables"]["clusters"]["rows"], verify_checksums)
        except SearchIndexError as exc:
            raise DatabaseError(str(exc)) from None
    try:
        db.validate()
    except DatabaseError as e:
        raise DatabaseError(f"{path}: inconsistent database: {e}") from None
    return db


_ENTRY_TYPES = {"file": str, "rows": int, "bytes": int, "sha256": str}


def _check_unread(file: Path, table: str, entry: dict) -> None:
    """A table file the load leaves unread: there, of the manifest's size, its Parquet footer
    naming that table, schema version and row count (a deleted, truncated or swapped file)."""
    if not file.is_file():
        raise DatabaseError(f"{file}: table file missing; rebuild the database")
    if (size := file.stat().st_size) != entry["bytes"]:
        raise DatabaseError(f"{file}: size {size} bytes, manifest says {entry['bytes']}: file truncated or modified")
    try:
        footer = pq.read_metadata(str(file))
    except (pa.ArrowException, OSError, ValueError) as e:
        raise DatabaseError(f"{file}: corrupt Parquet file, cannot read its footer ({e})") from None
    metadata = footer.metadata or {}
    tag = (metadata.get(b"mocapdb.table"), metadata.get(b"mocapdb.schema_version"))
    if tag != (table.encode(), str(SCHEMA_VERSION).encode()) or footer.num_rows != entry["rows"]:
        raise DatabaseError(f"{file}: not this database's {table!r} table ({footer.num_rows} rows, metadata {tag}; "
                            f"the manifest says {entry['rows']} rows)")


def verify_database(path: str | os.PathLike) -> list[tuple[str, str | None]]:
    """Every file of the database at ``path`` checked against its manifest, each on its own: the
    tables (size, sha256, Parquet, columns, finite values), the search index (size, dtype, shape,
    CRC-32 blocks), then the whole (shapes and value ranges across tables). Returns (what, the
    problem or None) per check; DatabaseError when there is no readable manifest."""
    path = Path(path)
    manifest = _read_manifest(path)
    report: list[tuple[str, str | None]] = []
    with ThreadPoolExecutor(max_workers=1) as hasher:
        for table, entry in manifest["tables"].items():
            report.append((entry["file"], _problem(lambda: _read_table(path, table, entry, hasher))))
    if (entries := manifest.get("search_index")) is not None:
        tables = manifest["tables"]
        report.append(("search index", _problem(lambda: load_search_index(
            path, entries, tables["projections"]["rows"], tables["clusters"]["rows"], True))))
    if not any(problem for _, problem in report):
        report.append(("the database as a whole", _problem(lambda: load_database(path))))
    return report


def _problem(check) -> str | None:
    """What ``check()`` raised (a DatabaseError or SearchIndexError), or None."""
    try:
        check()
    except (DatabaseError, SearchIndexError) as exc:
        return str(exc)
    return None


def _read_manifest(path: Path) -> dict:
    if not path.is_dir():
        raise DatabaseError(f"{path}: database directory not found")
    file = path / MANIFEST
    if not file.is_file():
        raise DatabaseError(f"{path}: not a mocapdb database (no {MANIFEST})")
    text = read_input_text(file, MAX_MANIFEST_BYTES, DatabaseError, "database manifest")
    try:
        manifest = json.loads(text)
    except (ValueError, RecursionError) as e:
        raise DatabaseError(f"{file}: unreadable manifest: {e}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise DatabaseError(f"{path}: not a mocapdb database ({MANIFEST} lacks format {FORMAT!r})")
    version = manifest.get("schema_version")
    if version != SCHEMA_VERSION:
        raise DatabaseError(
            f"{path}: database has schema version {version}, this code reads version {SCHEMA_VERSION}; "
            "rebuild the database with `mocapdb build`"
        )
    tables = manifest.get("tables")
    if not (
        isinstance(manifest.get("meta"), dict) and isinstance(tables, dict) and set(tables) == set(_TABLES)
        and all(isinstance(e, dict) and all(isinstance(e.get(k), t) for k, t in _ENTRY_TYPES.items())
                and Path(e["file"]).name == e["file"] for e in tables.values())
    ):
        raise DatabaseError(
            f"{file}: malformed manifest: needs a meta dict and tables {sorted(_TABLES)}, "
            f"each with {', '.join(_ENTRY_TYPES)}"
        )
    return manifest


def _read_bytes(file: Path, entry: dict) -> pa.Buffer:
    if not file.is_file():
        raise DatabaseError(f"{file}: table file missing; rebuild the database")
    size = file.stat().st_size
    if size != entry["bytes"]:
        raise DatabaseError(
            f"{file}: size {size} bytes, manifest says {entry['bytes']}: file truncated or modified"
        )
    try:
        with pa.OSFile(str(file)) as f:  # into Arrow's memory pool: faster than bytes
            return f.read_buffer()
    except OSError as e:
        raise DatabaseError(f"{file}: cannot read it ({e})") from None


def _sha256(data: pa.Buffer) -> str:
    return hashlib.sha256(data).hexdigest()


def _check_digest(file: Path, digest: Future | None, expected: str) -> None:
    if digest is not None and (actual := digest.result()) != expected:
        raise DatabaseError(
            f"checksum mismatch: {file} has sha256 {actual[:16]}…, the manifest says {expected[:16]}…; "
            "the database is damaged: rebuild it, or --no-verify to load it anyway"
        )


def _parse_parquet(file: Path, raw: pa.Buffer, entry: dict, hasher: ThreadPoolExecutor | None) -> pa.Table:
    """Decode the file's bytes; with a ``hasher``, its sha256 (computed meanwhile) must match first."""
    digest = hasher.submit(_sha256, raw) if hasher is not None else None
    try:
        data = pq.ParquetFile(pa.BufferReader(raw)).read()
    except (pa.ArrowException, OSError, ValueError) as e:
        _check_digest(file, digest, entry["sha256"])
        raise DatabaseError(f"{file}: corrupt Parquet file, cannot read it ({e})") from None
    _check_digest(file, digest, entry["sha256"])
    return data


def _read_table(path: Path, table: str, entry: dict, hasher: ThreadPoolExecutor | None) -> dict:
    file = path / entry["file"]
    data = _parse_parquet(file, _read_bytes(file, entry), entry, hasher)
    metadata = data.schema.metadata or {}
    tag = (metadata.get(b"mocapdb.table"), metadata.get(b"mocapdb.schema_version"))
    if tag != (table.encode(), str(SCHEMA_VERSION).encode()):
        raise DatabaseError(f"{file}: expected a mocapdb {table!r} table of schema version "
                            f"{SCHEMA_VERSION}, file metadata says {tag}")
    if data.num_rows != entry["rows"]:
        raise DatabaseError(f"{file}: {data.num_rows} rows, manifest says {entry['rows']}")
    columns = {col.field: _column_to_numpy(data, col, file) for col in _TABLES[table]}
    for col in filter(_is_float, _TABLES[table]):
        if (row := _nonfinite_row(columns[col.field])) is not None:
            raise DatabaseError(f"{file}: NaN or infinite value in table {table!r}, column {col.name!r} "
                                f"(row {row}); the database is damaged: rebuild it")
    return columns


def _column_to_numpy(data: pa.Table, col: _Column, file: Path) -> np.ndarray | list[str]:
    if col.name not in data.column_names:
        raise DatabaseError(f"{file}: column {col.name!r} missing")
    column = data.column(col.name)
    if col.dtype is None:
        ok, expected = column.type == pa.string(), "string"
    elif not col.shape:
        ok, expected = column.type == pa.from_numpy_dtype(col.dtype), col.dtype
    else:
        ok = pa.types.is_fixed_size_list(column.type) and column.type.value_type == pa.float32()
        expected = "fixed_size_list<float32>"
    if not ok:
        raise DatabaseError(f"{file}: column {col.name!r} has type {column.type}, expected {expected}")
    if column.null_count:
        raise DatabaseError(f"{file}: column {col.name!r} contains nulls")
    if col.dtype is None:
        return column.to_pylist()
    if not col.shape:
        return column.to_numpy()
    return _fixed_to_numpy(column, col, file)


def _fixed_to_numpy(column: pa.ChunkedArray, col: _Column, file: Path) -> np.ndarray:
    width = column.type.list_size
    known = math.prod(s for s in col.shape if s is not None)
    if width % known or (None not in col.shape and width != known):
        raise DatabaseError(f"{file}: column {col.name!r} has width {width}, incompatible with "
                            f"row shape {_shape_text(col)}")
    flats = [chunk.flatten() for chunk in column.chunks]
    if any(flat.null_count for flat in flats):
        raise DatabaseError(f"{file}: column {col.name!r} contains nulls")
    parts = [flat.to_numpy() for flat in flats]
    values = parts[0] if len(parts) == 1 else np.concatenate([np.zeros(0, np.float32), *parts])
    return values.reshape(len(column), *(width // known if s is None else s for s in col.shape))
