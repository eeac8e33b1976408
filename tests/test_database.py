import hashlib
import json
import os
import shutil
import subprocess
import sys

import numpy as np
import pyarrow.parquet as pq
import pytest

from mocapdb.core import files
from mocapdb.core.files import recover_interrupted
from mocapdb.core.formats import database_writer
from mocapdb.core.formats.database import SCHEMA_VERSION, DatabaseError, MotionDatabase
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.formats.database_writer import write_database


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


def fix_manifest(path, table: str) -> None:
    """Make the manifest's size and checksum of ``table`` match its (edited) file."""
    data = (path / f"{table}.parquet").read_bytes()
    edit_manifest(path, lambda m: m["tables"][table].update(bytes=len(data), sha256=hashlib.sha256(data).hexdigest()))


def rewrite_table(path, table: str, column: str, values) -> None:
    """Replace one column of a table file, keeping its metadata, and update the manifest."""
    file = path / f"{table}.parquet"
    data = pq.read_table(file)
    data = data.set_column(data.column_names.index(column), column, [values])
    pq.write_table(data, file)
    fix_manifest(path, table)


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
    real_write_table = database_writer._write_table

    def failing_write_table(table, file):
        calls.append(file.name)
        if len(calls) == 3:
            raise OSError("disk full")
        return real_write_table(table, file)

    monkeypatch.setattr(database_writer, "_write_table", failing_write_table)
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


def _cut_in_half(path, fix: bool) -> None:
    file = path / "projections.parquet"
    data = file.read_bytes()
    file.write_bytes(data[: len(data) // 2])
    if fix:
        fix_manifest(path, "projections")


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
    "truncated": (lambda p: _cut_in_half(p, fix=False),
                  r"projections.parquet: size \d+ bytes, manifest says \d+: file truncated"),
    "unreadable parquet": (lambda p: _cut_in_half(p, fix=True),
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


def _flip_bit(file, position: int, bit: int = 0) -> None:
    data = bytearray(file.read_bytes())
    data[position] ^= 1 << bit
    file.write_bytes(bytes(data))


DAMAGED = r"the database is damaged: rebuild it, or --no-verify to load it anyway"


@pytest.mark.parametrize("table", ["clips", "frames", "projections", "clusters"])
@pytest.mark.parametrize("where", [0.0, 0.5, 1.0])
def test_any_bit_flip_is_detected(db_path, table, where):
    file = db_path / f"{table}.parquet"
    _flip_bit(file, round(where * (file.stat().st_size - 1)), bit=3)
    with pytest.raises(DatabaseError, match=rf"^checksum mismatch: {file} has sha256 .*; {DAMAGED}$"):
        load_database(db_path)


def test_damaged_file_loads_without_verification(db_path):
    file = db_path / "frames.parquet"
    data = file.read_bytes()
    _flip_bit(file, data.index(b"parquet-cpp-arrow"))  # the writer's name in the footer: harmless
    with pytest.raises(DatabaseError, match=rf"checksum mismatch: .*frames.parquet .*{DAMAGED}"):
        load_database(db_path)
    assert_db_equal(make_db(), load_database(db_path, verify_checksums=False))


def test_manifest_records_the_files_sha256(db_path):
    manifest = json.loads((db_path / "manifest.json").read_text())
    for table, entry in manifest["tables"].items():
        data = (db_path / entry["file"]).read_bytes()
        assert (entry["bytes"], entry["sha256"]) == (len(data), hashlib.sha256(data).hexdigest()), table


NON_FINITE = {  # field, index, value → table and column the error must name
    "clip_source_fps": ((1,), np.nan, "clips", "source_fps", 1),
    "positions": ((3, 2, 1), np.inf, "frames", "positions", 3),
    "quaternions": ((10, 0, 0), -np.inf, "frames", "quaternions", 10),
    "keypoints_2d": ((43, 13, 1), np.nan, "projections", "keypoints_2d", 43),
    "embedding": ((7, 2), np.nan, "projections", "embedding", 7),
    "centroids": ((5, 0), np.inf, "clusters", "centroid", 5),
}


@pytest.mark.parametrize("field", NON_FINITE)
def test_non_finite_value_on_load_names_table_and_column(tmp_path, monkeypatch, field):
    index, value, table, column, row = NON_FINITE[field]
    db = make_db()
    getattr(db, field)[index] = value
    monkeypatch.setattr(database_writer, "_check_finite", lambda db: None)  # as a writer without the check would
    write_database(db, tmp_path / "DB")
    for verify in (True, False):
        with pytest.raises(DatabaseError, match=rf"{table}.parquet: NaN or infinite value in table '{table}', "
                                                rf"column '{column}' \(row {row}\)"):
            load_database(tmp_path / "DB", verify_checksums=verify)


def _dead_pid() -> int:
    """The id of a process that has ended."""
    return int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True).stdout)


def test_stale_temporary_folders_of_dead_writers_are_removed(db_path):
    dead, alive = _dead_pid(), os.getppid()
    for name in [f".DB.tmp-{dead}", f".DB.old-{dead}", f".DB.tmp-{alive}", f".OTHER.tmp-{dead}"]:
        (db_path.parent / name).mkdir()
        (db_path.parent / name / "projections.parquet").write_bytes(b"half written")
    write_database(make_db(seed=1), db_path)
    assert sorted(os.listdir(db_path.parent)) == [".DB.tmp-" + str(alive), ".OTHER.tmp-" + str(dead), "DB"]
    assert_db_equal(make_db(seed=1), load_database(db_path))


def test_crash_between_the_renames_is_recovered(db_path):
    """A writer killed after moving the old database aside: the next writer (or build) puts it back."""
    dead = _dead_pid()
    write_database(make_db(seed=1), db_path.parent / f".DB.tmp-{dead}")  # the finished new one
    os.rename(db_path, db_path.parent / f".DB.old-{dead}")
    assert recover_interrupted(db_path) == [f"restored {db_path} from .DB.old-{dead}, left by an interrupted write",
                                            f"removed .DB.tmp-{dead}, left by an interrupted write"]
    assert os.listdir(db_path.parent) == ["DB"]
    assert_db_equal(make_db(), load_database(db_path))


def test_failure_between_the_renames_restores_the_old_database(db_path, monkeypatch):
    """Without an atomic swap: old aside, new in; a failure in between puts the old back."""
    monkeypatch.setattr(files, "_exchange", lambda a, b: False)
    real_rename, calls = os.rename, []

    def rename(src, dst):
        calls.append((os.path.basename(src), os.path.basename(dst)))
        if len(calls) == 2:
            assert not os.path.lexists(db_path)  # the moment a reader could miss it
            raise OSError("simulated failure")
        real_rename(src, dst)

    monkeypatch.setattr(database_writer.os, "rename", rename)
    with pytest.raises(OSError, match="simulated failure"):
        write_database(make_db(seed=1), db_path)
    pid = os.getpid()
    assert calls == [("DB", f".DB.old-{pid}"), (f".DB.tmp-{pid}", "DB"), (f".DB.old-{pid}", "DB")]
    assert os.listdir(db_path.parent) == ["DB"]
    assert_db_equal(make_db(), load_database(db_path))


def test_replace_by_renames_without_atomic_swap(db_path, monkeypatch):
    monkeypatch.setattr(files, "_exchange", lambda a, b: False)
    write_database(make_db(seed=1), db_path)
    assert os.listdir(db_path.parent) == ["DB"]
    assert_db_equal(make_db(seed=1), load_database(db_path))


def test_replace_is_an_atomic_swap_where_supported(db_path, monkeypatch):
    swaps = []

    def exchange(a, b):
        swaps.append(real(a, b))
        return swaps[-1]

    real = files._exchange
    monkeypatch.setattr(files, "_exchange", exchange)
    write_database(make_db(seed=1), db_path)
    if swaps != [True]:
        pytest.skip("no renameat2(RENAME_EXCHANGE) on this system or file system")
    assert os.listdir(db_path.parent) == ["DB"]
    assert_db_equal(make_db(seed=1), load_database(db_path))


def test_symlinked_output_is_written_at_its_target(tmp_path):
    (tmp_path / "store").mkdir()
    write_database(make_db(), tmp_path / "store" / "DB")
    (tmp_path / "link").symlink_to(tmp_path / "store" / "DB")
    write_database(make_db(seed=1), tmp_path / "link")
    assert (tmp_path / "link").is_symlink() and sorted(os.listdir(tmp_path)) == ["link", "store"]
    assert os.listdir(tmp_path / "store") == ["DB"]
    assert_db_equal(make_db(seed=1), load_database(tmp_path / "link"))
    (tmp_path / "dangling").symlink_to(tmp_path / "store" / "new" / "DB2")  # target created
    write_database(make_db(), tmp_path / "dangling")
    assert (tmp_path / "dangling").is_symlink()
    assert_db_equal(make_db(), load_database(tmp_path / "store" / "new" / "DB2"))


def test_symlink_to_other_content_is_refused(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "cat.jpg").write_text("mine")
    (tmp_path / "link").symlink_to(tmp_path / "photos")
    with pytest.raises(DatabaseError, match=r"photos: exists and is not a mocapdb database"):
        write_database(make_db(), tmp_path / "link")
    assert (tmp_path / "link").is_symlink() and os.listdir(tmp_path / "photos") == ["cat.jpg"]


def _copy_db(small_db_path, tmp_path):
    import shutil

    target = tmp_path / "db"
    shutil.copytree(small_db_path, target)
    return target


def test_verify_checks_every_file_and_says_which_is_damaged(small_db_path, tmp_path, capsys):
    from mocapdb.cli.main import main
    from mocapdb.core.formats.database_reader import verify_database

    db = _copy_db(small_db_path, tmp_path)
    report = verify_database(db)
    assert [what for what, _ in report][-2:] == ["search index", "the database as a whole"]
    assert not any(problem for _, problem in report)
    assert main(["verify", str(db)]) == 0 and "all 6 checks passed" in capsys.readouterr().out
    table = db / "projections.parquet"
    data = bytearray(table.read_bytes())
    data[len(data) // 2] ^= 0xFF  # one bit flipped mid-file: only the sha256 sees it
    table.write_bytes(bytes(data))
    assert main(["verify", str(db)]) == 1
    out = capsys.readouterr().out
    assert "FAIL  projections.parquet: checksum mismatch" in out and "ok    clusters.parquet" in out


@pytest.mark.parametrize("damage", ["deleted", "truncated", "swapped"])
def test_the_runtime_refuses_a_projections_table_it_does_not_read_when_it_is_gone_or_another(
        small_db_path, tmp_path, damage):
    """The runtime loads a database without reading its projections table (the search index holds
    what it needs), but a deleted, truncated or other database's table is still refused."""
    from mocapdb.core.formats.database import DatabaseError
    from mocapdb.core.formats.database_reader import load_database

    db = _copy_db(small_db_path, tmp_path)
    table = db / "projections.parquet"
    if damage == "deleted":
        table.unlink()
    elif damage == "truncated":
        table.write_bytes(table.read_bytes()[:-100])
    else:  # the clusters table under the projections' name, padded to the manifest's size
        size = table.stat().st_size
        other = (db / "clusters.parquet").read_bytes()
        table.write_bytes(other[:-8] + b"\0" * (size - len(other)) + other[-8:] if len(other) < size else other)
    with pytest.raises(DatabaseError, match="projections.parquet"):
        load_database(db, projections=False)
