import json
import os
import shutil

import numpy as np
import pyarrow.parquet as pq
import pytest

from mocapdb import database
from mocapdb.database import SCHEMA_VERSION, DatabaseError, MotionDatabase, load_database, write_database


def make_db(seed: int = 0, counts=(4, 2, 5), n_rig: int = 3, dims: int = 3,
            n_clusters: int = 6) -> MotionDatabase:
    """A small consistent database with random content; the last cluster is empty."""
    rng = np.random.default_rng(seed)
    yaws = [0.0, 90.0, 180.0, 270.0]
    counts = np.array(counts, np.int32)
    first = (np.cumsum(counts) - counts).astype(np.int64)
    n_frames, n_clips = int(counts.sum()), len(counts)
    n_proj = n_frames * len(yaws)
    cluster = rng.integers(0, n_clusters - 1, n_proj).astype(np.int32)
    representative = np.array(
        [np.flatnonzero(cluster == k)[0] if (cluster == k).any() else -1 for k in range(n_clusters)], np.int64
    )
    return MotionDatabase(
        meta={"fps": 30.0, "yaws_deg": yaws, "dims": dims, "seed": seed},
        clip_name=[f"clip{i}" for i in range(n_clips)],
        clip_source=[f"data/clip{i}.bvh" for i in range(n_clips)],
        clip_source_fps=rng.choice([60.0, 120.0], n_clips),
        clip_n_frames=counts,
        clip_first_frame=first,
        clip_convention=["cmu"] * n_clips,
        clip_credit=["CC0 — test"] * n_clips,
        clip_mirrored=np.arange(n_clips) % 2 == 1,
        frame_clip=np.repeat(np.arange(n_clips, dtype=np.int32), counts),
        frame_index=(np.arange(n_frames) - np.repeat(first, counts)).astype(np.int32),
        quaternions=rng.standard_normal((n_frames, n_rig, 4), dtype=np.float32),
        positions=rng.standard_normal((n_frames, 15, 3), dtype=np.float32),
        proj_frame=np.repeat(np.arange(n_frames, dtype=np.int64), len(yaws)),
        proj_yaw=np.tile(np.arange(len(yaws), dtype=np.int16), n_frames),
        keypoints_2d=rng.standard_normal((n_proj, 14, 2), dtype=np.float32),
        embedding=rng.standard_normal((n_proj, dims), dtype=np.float32),
        cluster=cluster,
        centroids=rng.standard_normal((n_clusters, dims), dtype=np.float32),
        representative=representative,
        cluster_size=np.bincount(cluster, minlength=n_clusters).astype(np.int32),
    )


def assert_db_equal(a: MotionDatabase, b: MotionDatabase) -> None:
    assert a.meta == b.meta
    for name, value in vars(a).items():
        if isinstance(value, np.ndarray):
            other = getattr(b, name)
            assert other.dtype == value.dtype, name
            np.testing.assert_array_equal(other, value, err_msg=name)
        else:
            assert getattr(b, name) == value, name


def edit_manifest(path, edit) -> None:
    file = path / "manifest.json"
    manifest = json.loads(file.read_text())
    edit(manifest)
    file.write_text(json.dumps(manifest))


def rewrite_table(path, table: str, column: str, values) -> None:
    """Replace one column of a table file, keeping its metadata, and update the manifest."""
    file = path / f"{table}.parquet"
    data = pq.read_table(file)
    data = data.set_column(data.column_names.index(column), column, [values])
    pq.write_table(data, file)
    edit_manifest(path, lambda m: m["tables"][table].update(bytes=file.stat().st_size))


@pytest.fixture
def db_path(tmp_path):
    path = tmp_path / "DB"
    write_database(make_db(), path)
    return path


def test_round_trip(tmp_path):
    db = make_db()
    size = write_database(db, tmp_path / "DB")
    files = sorted(os.listdir(tmp_path / "DB"))
    assert files == ["clips.parquet", "clusters.parquet", "frames.parquet", "manifest.json",
                     "projections.parquet"]
    assert size == sum((tmp_path / "DB" / f).stat().st_size for f in files)
    loaded = load_database(tmp_path / "DB", verify_checksums=True)
    assert_db_equal(db, loaded)
    assert (loaded.n_clips, loaded.n_frames, loaded.n_projections, loaded.n_clusters) == (3, 11, 44, 6)
    assert loaded.representative[-1] == -1 and loaded.cluster_size[-1] == 0


def test_meta_and_file_metadata_round_trip(tmp_path):
    db = make_db()
    db.meta.update(
        yaw_step_deg=90.0,
        camera={"height_m": 1.6, "distance_m": 3.5, "focal_px": 900.0, "width_px": 1280, "height_px": 720},
        n_clusters=6,
        builder="mocapdb 0.1",
        created="2026-01-01T00:00:00+00:00",
        skeleton={"keypoints": [f"k{i}" for i in range(15)], "rig_joints": ["a", "b", "c"],
                  "bone_lengths": {"a-b": 0.25}},
    )
    write_database(db, tmp_path / "DB")
    assert load_database(tmp_path / "DB").meta == db.meta
    manifest = json.loads((tmp_path / "DB" / "manifest.json").read_text())
    assert (manifest["format"], manifest["schema_version"]) == ("mocapdb", SCHEMA_VERSION)
    assert manifest["tables"]["projections"]["rows"] == 44
    metadata = pq.read_schema(tmp_path / "DB" / "frames.parquet").metadata
    assert metadata[b"mocapdb.table"] == b"frames"
    assert metadata[b"mocapdb.schema_version"] == str(SCHEMA_VERSION).encode()


def test_replaces_existing_database(db_path):
    new = make_db(seed=1, counts=(7, 3), n_rig=5, dims=4, n_clusters=3)
    write_database(new, db_path)
    assert_db_equal(new, load_database(db_path))
    assert os.listdir(db_path.parent) == ["DB"]


def test_failed_write_keeps_old_database(db_path, monkeypatch):
    calls = []
    real_write_table = database._write_table

    def failing_write_table(table, file):
        calls.append(file.name)
        if len(calls) == 3:
            raise OSError("disk full")
        return real_write_table(table, file)

    monkeypatch.setattr(database, "_write_table", failing_write_table)
    with pytest.raises(OSError, match="disk full"):
        write_database(make_db(seed=1), db_path)
    assert len(calls) == 3
    assert_db_equal(make_db(), load_database(db_path, verify_checksums=True))
    assert os.listdir(db_path.parent) == ["DB"]


def test_refuses_to_replace_other_folder(tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"\xff\xd8")
    with pytest.raises(DatabaseError, match=r"photos: exists and is not a mocapdb database.*refusing"):
        write_database(make_db(), folder)
    assert os.listdir(folder) == ["holiday.jpg"]
    assert sorted(os.listdir(tmp_path)) == ["photos"]


def test_writes_into_empty_folder(tmp_path):
    (tmp_path / "DB").mkdir()
    write_database(make_db(), tmp_path / "DB")
    assert load_database(tmp_path / "DB").n_frames == 11


def test_write_rejects_inconsistent_database(tmp_path):
    db = make_db()
    db.frame_index = db.frame_index[::-1].copy()
    with pytest.raises(DatabaseError, match="frame_index is not 0, 1, 2"):
        write_database(db, tmp_path / "DB")
    assert os.listdir(tmp_path) == []


def _cut_in_half(path, fix_manifest: bool) -> None:
    file = path / "projections.parquet"
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    if fix_manifest:
        edit_manifest(path, lambda m: m["tables"]["projections"].update(bytes=len(data) // 2))


def _flip_byte(path) -> None:
    file = path / "frames.parquet"
    data = bytearray(file.read_bytes())
    data[len(data) // 2] ^= 0xFF
    file.write_bytes(bytes(data))


LOAD_ERRORS = {
    "missing dir": (shutil.rmtree, r"DB: database directory not found"),
    "missing manifest": (lambda p: (p / "manifest.json").unlink(),
                         r"DB: not a mocapdb database \(no manifest.json\)"),
    "wrong format": (lambda p: edit_manifest(p, lambda m: m.update(format="other")),
                     r"DB: not a mocapdb database"),
    "other schema version": (
        lambda p: edit_manifest(p, lambda m: m.update(schema_version=SCHEMA_VERSION + 1)),
        rf"schema version {SCHEMA_VERSION + 1}, this code reads version {SCHEMA_VERSION}; "
        r"rebuild the database with `mocapdb build`",
    ),
    "older schema version (no clips.mirrored)": (
        lambda p: edit_manifest(p, lambda m: m.update(schema_version=SCHEMA_VERSION - 1)),
        rf"schema version {SCHEMA_VERSION - 1}, this code reads version {SCHEMA_VERSION}; rebuild",
    ),
    "missing table": (lambda p: (p / "frames.parquet").unlink(), r"frames.parquet: table file missing"),
    "truncated": (lambda p: _cut_in_half(p, fix_manifest=False),
                  r"projections.parquet: size \d+ bytes, manifest says \d+: file truncated"),
    "unreadable parquet": (lambda p: _cut_in_half(p, fix_manifest=True),
                           r"projections.parquet: corrupt Parquet file, cannot read it"),
    "row count": (lambda p: edit_manifest(p, lambda m: m["tables"]["frames"].update(rows=12)),
                  r"frames.parquet: 11 rows, manifest says 12"),
    "cluster out of range": (
        lambda p: rewrite_table(p, "projections", "cluster", np.full(44, 6, np.int32)),
        r"DB: inconsistent database: cluster out of range: values span \[6, 6\], allowed \[0, 5\]",
    ),
    "proj_frame out of range": (
        lambda p: rewrite_table(p, "projections", "frame", np.arange(44, dtype=np.int64)),
        r"proj_frame out of range",
    ),
    "dims mismatch": (lambda p: edit_manifest(p, lambda m: m["meta"].update(dims=4)),
                      r"embedding width 3 differs from meta dims 4"),
}


@pytest.mark.parametrize("case", LOAD_ERRORS)
def test_load_errors(db_path, case):
    damage, message = LOAD_ERRORS[case]
    damage(db_path)
    with pytest.raises(DatabaseError, match=message):
        load_database(db_path)


def test_checksum_verification(db_path):
    _flip_byte(db_path)
    with pytest.raises(DatabaseError, match=r"frames.parquet: sha256 checksum differs from the manifest"):
        load_database(db_path, verify_checksums=True)
