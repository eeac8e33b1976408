"""Loading and verifying the motion database (``data_specs/database.md``): :func:`load_database`
(the manifest, the tables' sizes, checksums and columns, the search index memory-mapped, then the
whole validated) and :func:`verify_database` (every file checked on its own, for ``mocapdb verify``).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from mocapdb.core.files import read_input_text
from mocapdb.core.formats.database import (
    FORMAT,
    MANIFEST,
    MAX_MANIFEST_BYTES,
    SCHEMA_VERSION,
    TABLES,
    Column,
    DatabaseError,
    MotionDatabase,
    nonfinite_row,
    shape_text,
)
from mocapdb.core.formats.search_index import SearchIndexError, load_search_index


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
    # MotionDatabase's fields by name: arrays, lists of text, None for an unread table's (its fields
    # differ in type, so the mapping's values are Any; MotionDatabase.validate checks them)
    columns: dict[str, Any] = {col.field: None for table in skip for col in TABLES[table]}
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
        isinstance(manifest.get("meta"), dict) and isinstance(tables, dict) and set(tables) == set(TABLES)
        and all(isinstance(e, dict) and all(isinstance(e.get(k), t) for k, t in _ENTRY_TYPES.items())
                and Path(e["file"]).name == e["file"] for e in tables.values())
    ):
        raise DatabaseError(
            f"{file}: malformed manifest: needs a meta dict and tables {sorted(TABLES)}, "
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
    columns = {col.field: _column_to_numpy(data, col, file) for col in TABLES[table]}
    for col in filter(_is_float, TABLES[table]):
        values = columns[col.field]
        assert isinstance(values, np.ndarray), f"{col.name}: a float column is read as an array"
        if (row := nonfinite_row(values)) is not None:
            raise DatabaseError(f"{file}: NaN or infinite value in table {table!r}, column {col.name!r} "
                                f"(row {row}); the database is damaged: rebuild it")
    return columns


def _is_float(col: Column) -> bool:
    return col.dtype is not None and col.dtype.startswith("float")


def _column_to_numpy(data: pa.Table, col: Column, file: Path) -> np.ndarray | list[str]:
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


def _fixed_to_numpy(column: pa.ChunkedArray, col: Column, file: Path) -> np.ndarray:
    width = column.type.list_size
    known = math.prod(s for s in col.shape if s is not None)
    if width % known or (None not in col.shape and width != known):
        raise DatabaseError(f"{file}: column {col.name!r} has width {width}, incompatible with "
                            f"row shape {shape_text(col)}")
    flats = [chunk.flatten() for chunk in column.chunks]
    if any(flat.null_count for flat in flats):
        raise DatabaseError(f"{file}: column {col.name!r} contains nulls")
    parts = [flat.to_numpy() for flat in flats]
    values = parts[0] if len(parts) == 1 else np.concatenate([np.zeros(0, np.float32), *parts])
    return values.reshape(len(column), *(width // known if s is None else s for s in col.shape))
