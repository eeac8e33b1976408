"""Writing the motion database (``data_specs/database.md``): :func:`write_database` for a whole
:class:`~mocapdb.core.formats.database.MotionDatabase`, :class:`DatabaseWriter` table by table and
row group by row group, each file hashed as it is written and the folder put in place atomically;
:func:`check_output_path`, what may be replaced.
"""
from __future__ import annotations

import hashlib
import io
import json
import math
import os
import shutil
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import BinaryIO

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mocapdb.core.files import (
    fsync_dir,
    output_target,
    read_input_text,
    recover_interrupted,
    replace_folder,
    sibling,
    write_synced,
)
from mocapdb.core.formats.database import (
    FORMAT,
    MANIFEST,
    MAX_MANIFEST_BYTES,
    SCHEMA_VERSION,
    TABLES,
    DatabaseError,
    MotionDatabase,
    check_columns,
    check_meta,
    nonfinite_row,
)
from mocapdb.core.formats.search_index import ARRAYS as INDEX_ARRAYS
from mocapdb.core.formats.search_index import file_name as index_file_name
from mocapdb.core.formats.search_index import index_entry


def write_database(db: MotionDatabase, path: str | os.PathLike) -> int:
    """Validate ``db`` and write it atomically as directory ``path``; return its size in bytes.

    Replaces an existing mocapdb database or empty directory at ``path``; refuses anything else,
    and a database holding a NaN or infinite value. A symlink at ``path`` is followed: the database
    is written at its target and the link stays. Leftovers of interrupted writes to ``path`` are
    cleaned up first (:func:`recover_interrupted`). Each table is one row group.
    """
    db.validate()
    with DatabaseWriter(path, db.meta) as writer:
        for table, columns in TABLES.items():
            writer.write_table(table, [{col.field: getattr(db, col.field) for col in columns}])
        return writer.finish()


class DatabaseWriter:
    """Writes a database table by table, row group by row group, as the rows come: never a whole
    table in memory. Files go to a temporary folder beside the target (``.<name>.tmp-<pid>``) that
    :meth:`finish` puts in place atomically, as :func:`write_database` does; leaving the ``with``
    block by an exception removes it. Each file's sha256 is computed while it is written.
    """

    def __init__(self, path: str | os.PathLike, meta: dict):
        check_meta(meta)
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
        if set(self.tables) != set(TABLES):
            raise DatabaseError(f"{self.path}: tables {sorted(set(TABLES) - set(self.tables))} not written")
        manifest = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "meta": self.meta,
                    "tables": {name: self.tables[name] for name in TABLES}}
        if self.search_index is not None:
            manifest["search_index"] = self.search_index
        data = json.dumps(manifest, indent=2).encode("utf-8")
        write_synced(self._tmp / MANIFEST, data)
        fsync_dir(self._tmp)
        _check_replaceable(self.path)
        replace_folder(self._tmp, self.path)
        index = self.search_index or {}
        return len(data) + sum(entry["bytes"] for entry in (*self.tables.values(), *index.values()))


def _checked_arrow(values: Mapping[str, object], table: str) -> pa.Table:
    """Rows of ``table`` (field → values) as an Arrow table, once their columns are checked and
    their floats finite (else DatabaseError)."""
    check_columns(values, table, TABLES[table])
    _check_finite(values)
    return _to_arrow(values, table)


def _check_finite(values: Mapping[str, object]) -> None:
    bad = [field for field, value in values.items()
           if isinstance(value, np.ndarray) and value.dtype.kind == "f" and nonfinite_row(value) is not None]
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
    for col in TABLES[table]:
        value = values[col.field]
        if col.dtype is None:
            array = pa.array(value, pa.string())
        elif col.shape:
            item = pa.field("item", pa.float32(), nullable=False)
            rows = np.ascontiguousarray(value)
            array = pa.FixedSizeListArray.from_arrays(
                pa.array(rows.reshape(-1)),
                type=pa.list_(item, math.prod(rows.shape[1:])),
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
