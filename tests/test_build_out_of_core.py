"""The out-of-core build: chunk sizes never change the database, an interrupted build resumes where
it stopped (and a changed option or source restarts the stages it affects), the streamed k-means is
Lloyd's, Parquet is written in row groups, and memory stays flat under a small limit."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from scipy.spatial.distance import cdist

import mocapdb.builder.index_stage as index_stage
import mocapdb.builder.pose_stages as pose_stages
import mocapdb.builder.read_stage as read_stage
import mocapdb.builder.run as build_run
from mocapdb.builder.config import BuildError
from mocapdb.builder.kmeans import (
    KMEANS_BLOCK_ROWS,
    KMeansBounds,
    kmeans_finish,
    kmeans_iterate,
    kmeans_seed,
)
from mocapdb.builder.pipeline import build
from mocapdb.builder.work import STAGES, WorkArray, WorkFolder
from mocapdb.cli.main import main
from mocapdb.core.formats.database_reader import load_database

from . import test_builder
from .conftest import ROOT, SAMPLE_BVH
from .test_builder import CLIPS, _config

sources = test_builder.sources  # the fixture: two clips, 264 frames with their mirror images, 7,920 projections

TINY_MB = 64  # below the process's own memory: the smallest chunks (1,024 rows, one k-means block, one frame)
TABLES = ("positions", "quaternions", "keypoints_2d", "embedding", "cluster", "centroids", "representative",
          "cluster_size", "proj_frame", "proj_yaw", "frame_clip", "frame_index", "clip_first_frame")


@pytest.fixture(scope="module")
def whole(sources, tmp_path_factory):
    """The reference: one chunk per stage (a large limit)."""
    out = tmp_path_factory.mktemp("whole") / "db"
    build([str(sources)], out, _config(memory_limit_mb=8000))
    return out


def assert_same_database(a, b) -> None:
    a, b = load_database(a), load_database(b)
    for name in TABLES:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in ("x", "y", "rows", "columns", "cluster_start"):
        np.testing.assert_array_equal(getattr(a.search_index, name), getattr(b.search_index, name), err_msg=name)
    assert (a.clip_name, a.clip_credit) == (b.clip_name, b.clip_credit)
    assert {k: v for k, v in a.meta.items() if k != "created"} == {k: v for k, v in b.meta.items() if k != "created"}


def _row_groups(db, table: str) -> int:
    return pq.ParquetFile(db / f"{table}.parquet").num_row_groups


def test_smallest_chunks_give_the_same_database_as_one_chunk(sources, whole, tmp_path):
    summary = build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    assert_same_database(whole, tmp_path / "db")
    assert _row_groups(tmp_path / "db", "projections") == 8 and _row_groups(whole, "projections") == 1
    assert _row_groups(tmp_path / "db", "frames") == 1  # 264 frames
    assert "runs in its smallest chunks" in summary.warnings[0]
    assert sorted(os.listdir(tmp_path)) == ["db"]  # the work folder is gone
    assert summary.peak_memory_mb > 0 and summary.work_bytes > 7920 * 112  # the 2D poses were in it


class Interrupt(Exception):
    """Stands for a Ctrl-C or a kill (not an error about the inputs: the work folder stays)."""


def _fail_on_call(monkeypatch, module, name: str, call: int) -> list:
    """Make ``module.<name>`` raise :class:`Interrupt` on its ``call``-th call; returns the calls."""
    real, calls = getattr(module, name), []

    def wrapper(*args, **kwargs):
        calls.append(1)
        if len(calls) == call:
            raise Interrupt(name)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, wrapper)
    return calls


@pytest.mark.parametrize("stage, module, function, call, went_on", [
    ("read", read_stage, "_process_one", 2, "went on from files done 1"),
    ("project", pose_stages, "project_frames", 100, "went on from rows done 99"),
    ("embed", pose_stages, "fit_landmarks", 1, None),
    ("assign", pose_stages, "assign_to_representatives", 3, "went on from rows done 2,048"),
    ("index", index_stage, "gather_group", 20, "went on from columns done 2,334"),  # 8 chunks a group of clusters
])
def test_an_interrupted_build_goes_on_where_it_stopped(sources, whole, tmp_path, monkeypatch, stage, module, function,
                                                       call, went_on):
    monkeypatch.setattr(build_run, "COMMIT_INTERVAL_S", 0.0)  # progress saved after every chunk
    out = tmp_path / "db"
    with monkeypatch.context() as patch:
        _fail_on_call(patch, module, function, call)
        with pytest.raises(Interrupt):
            build([str(sources)], out, _config(memory_limit_mb=TINY_MB))
    assert not out.exists() and (tmp_path / "db.work" / "state.json").is_file()
    calls = _fail_on_call(monkeypatch, read_stage, "_process_one", 10**9)  # counts the files read again
    summary = build([str(sources)], out, _config(memory_limit_mb=TINY_MB))
    assert_same_database(whole, out)
    earlier = STAGES[:STAGES.index(stage)]
    went_on = {stage: went_on} if went_on else {}
    assert summary.resumed == {**dict.fromkeys(earlier, "done by an earlier run"), **went_on}
    assert not set(earlier) & set(summary.seconds) and stage in summary.seconds  # skipped: not timed
    assert len(calls) == (1 if stage == "read" else 0)  # only the file not read before
    assert sorted(os.listdir(tmp_path)) == ["db"]


def test_kmeans_goes_on_from_its_last_saved_iteration(sources, whole, tmp_path, monkeypatch):
    real, seen = pose_stages.kmeans_iterate, []

    def stop_after_two(points, state, bounds, max_iter, rows, progress, tasks):
        def report(s):
            progress(s)
            seen.append(s.iteration)
            if s.iteration == 2:
                raise Interrupt("k-means")
        real(points, state, bounds, max_iter, rows, report, tasks)

    with monkeypatch.context() as patch:
        patch.setattr(pose_stages, "kmeans_iterate", stop_after_two)
        with pytest.raises(Interrupt):
            build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    monkeypatch.setattr(pose_stages, "kmeans_iterate", lambda *a: (seen.append(a[1].iteration), real(*a)))
    summary = build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    assert seen == [1, 2, 2] and summary.resumed["cluster"] == "went on from iteration 2"
    assert_same_database(whole, tmp_path / "db")


def test_a_killed_build_resumes(sources, whole, tmp_path, capsys):
    """SIGKILL in the middle of the assign stage (no Python clean-up at all, like the OOM killer); a
    state save still under way is lost, so the build goes on from the one before."""
    code = ("import os, signal, sys\nimport mocapdb.builder.pipeline as p\nimport mocapdb.builder.pose_stages as s\n"
            "import mocapdb.builder.run as r\nfrom mocapdb.builder.config import BuildConfig\n"
            "r.COMMIT_INTERVAL_S = 0.0\nreal, calls = s.assign_to_representatives, []\n"
            "def assign(*a):\n    calls.append(1)\n    if len(calls) == 4:\n"
            "        os.kill(os.getpid(), signal.SIGKILL)\n    return real(*a)\ns.assign_to_representatives = assign\n"
            f"p.build([sys.argv[1]], sys.argv[2], BuildConfig(clusters=20, landmarks=300, workers=1, "
            f"memory_limit_mb={TINY_MB}))\n")
    done = subprocess.run([sys.executable, "-c", code, str(sources), str(tmp_path / "db")], cwd=ROOT)
    assert done.returncode == -9 and not (tmp_path / "db").exists()
    assert json.loads((tmp_path / "db.work" / "state.json").read_text())["stages"]["embed"]["done"]
    assert main(["build", str(sources), "--out", str(tmp_path / "db"), "--clusters", "20", "--landmarks", "300",
                 "--workers", "1", "--memory-limit", str(TINY_MB)]) == 0
    out = capsys.readouterr().out
    assert "resumed read: done by an earlier run\nresumed project: done by an earlier run\n" in out
    assert_same_database(whole, tmp_path / "db")
    assert sorted(os.listdir(tmp_path)) == ["db"]


def _interrupted(sources, out, monkeypatch, **config) -> None:
    """A build of ``sources`` stopped in its assign stage, its work folder left behind."""
    with monkeypatch.context() as patch:
        patch.setattr(build_run, "COMMIT_INTERVAL_S", 0.0)
        _fail_on_call(patch, pose_stages, "assign_to_representatives", 2)
        with pytest.raises(Interrupt):
            build([str(sources)], out, _config(memory_limit_mb=TINY_MB, **config))


def test_a_changed_option_restarts_the_stages_it_affects(sources, tmp_path, monkeypatch):
    _interrupted(sources, tmp_path / "db", monkeypatch)
    summary = build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB, clusters=12))
    assert summary.resumed == dict.fromkeys(["read", "project", "embed"], "done by an earlier run")
    assert "the cluster stage and those after it started again: its options or sources changed" in summary.warnings
    build([str(sources)], tmp_path / "fresh", _config(clusters=12))
    assert_same_database(tmp_path / "fresh", tmp_path / "db")
    _interrupted(sources, tmp_path / "db", monkeypatch)
    summary = build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB, yaw_step_deg=24.0))
    assert list(summary.resumed) == ["read"]


def test_a_changed_source_or_restart_starts_again(sources, whole, tmp_path, monkeypatch):
    folder = tmp_path / "src"
    shutil.copytree(sources, folder)
    _interrupted(folder, tmp_path / "db", monkeypatch)
    os.utime(folder / CLIPS[0], ns=(0, 0))
    summary = build([str(folder)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    assert summary.resumed == {} and "the read stage and those after it started again" in summary.warnings[-1]
    _interrupted(folder, tmp_path / "db", monkeypatch)
    assert build([str(folder)], tmp_path / "db", _config(restart=True)).resumed == {}
    assert_same_database(whole, tmp_path / "db")


def test_a_work_folder_in_use_or_holding_other_files_is_refused(sources, tmp_path):
    import fcntl

    from mocapdb.builder.work import WorkError

    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("mine")
    with pytest.raises(WorkError, match="is not a build's work folder"):
        build([str(sources)], tmp_path / "db", _config(work_dir=tmp_path / "mine"))
    assert os.listdir(tmp_path / "mine") == ["notes.txt"]
    (tmp_path / "busy").mkdir()
    with open(tmp_path / "busy" / "lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        with pytest.raises(WorkError, match="another build is using this work folder"):
            build([str(sources)], tmp_path / "db", _config(work_dir=tmp_path / "busy"))
    with pytest.raises(BuildError, match="lies inside the output"):
        build([str(sources)], tmp_path / "db", _config(work_dir=tmp_path / "db" / "work"))
    assert sorted(os.listdir(tmp_path)) == ["busy", "mine"]


def _lloyd_reference(points: np.ndarray, centroids: np.ndarray, tol_abs: float, max_iter: int):
    """Plain Lloyd by brute force (numpy): labels by argmin of all distances, means by cluster."""
    for iteration in range(1, max_iter + 1):
        labels = cdist(points, centroids).argmin(axis=1)
        assert np.bincount(labels, minlength=len(centroids)).min() > 0  # no empty cluster in this test
        new = np.stack([points[labels == c].mean(axis=0) for c in range(len(centroids))])
        shift, centroids = float(((new - centroids) ** 2).sum()), new
        if shift <= tol_abs:
            break
    return centroids, cdist(points, centroids).argmin(axis=1), iteration


def _streamed(points, k: int, chunk_rows: int, bounds: KMeansBounds | None = None):
    """Streamed k-means of ``points`` (seed 3): the final state, labels and representatives."""
    state = kmeans_seed(points, k, seed=3)
    bounds = bounds or KMeansBounds.in_memory(len(points))
    kmeans_iterate(points, state, bounds, 100, chunk_rows)
    reps = kmeans_finish(points, state, bounds, chunk_rows)
    return state, bounds.labels[0:len(points)], reps


def _blobs(n: int, k: int, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    centres = rng.normal(scale=4.0, size=(k, d))
    return (centres[rng.integers(0, k, n)] + rng.normal(size=(n, d))).astype(np.float32)


def test_streamed_kmeans_is_lloyd_and_independent_of_the_chunk_size():
    points = _blobs(30_000, 15, 5, seed=11)
    state, labels, reps = _streamed(points, 15, len(points))
    start = kmeans_seed(points, 15, seed=3)
    centroids, expected, iterations = _lloyd_reference(points.astype(np.float64), start.centroids, start.tol_abs, 100)
    assert state.iteration == iterations and state.converged
    np.testing.assert_array_equal(labels, expected)
    np.testing.assert_allclose(state.centroids, centroids, rtol=1e-10)
    dist = np.linalg.norm(points - state.centroids[labels], axis=1)
    assert all(labels[reps[c]] == c and dist[reps[c]] == dist[labels == c].min() for c in range(15))
    for chunk_rows in (KMEANS_BLOCK_ROWS, 3 * KMEANS_BLOCK_ROWS + 5):
        chunked, chunked_labels, chunked_reps = _streamed(points, 15, chunk_rows)
        np.testing.assert_array_equal(chunked.centroids, state.centroids)  # bit for bit
        np.testing.assert_array_equal(chunked_labels, labels)
        np.testing.assert_array_equal(chunked_reps, reps)


def test_streamed_kmeans_over_work_arrays_equals_in_memory(tmp_path):
    points = _blobs(20_000, 8, 3, seed=12)
    stored = WorkArray.create(tmp_path / "points.npy", np.float32, (3,), len(points))
    stored[0:len(points)] = points
    np.testing.assert_array_equal(np.load(tmp_path / "points.npy"), points)  # a plain .npy file
    bounds = KMeansBounds(*(WorkArray.create(tmp_path / f"{name}.npy", dtype, (), len(points))
                            for name, dtype in KMeansBounds.FIELDS))
    on_disk = _streamed(stored, 8, KMEANS_BLOCK_ROWS, bounds)
    in_memory = _streamed(points, 8, len(points))
    np.testing.assert_array_equal(on_disk[0].centroids, in_memory[0].centroids)
    np.testing.assert_array_equal(on_disk[1], in_memory[1])
    np.testing.assert_array_equal(on_disk[2], in_memory[2])


def test_work_arrays_grow_and_drop_what_was_not_committed(tmp_path):
    array = WorkArray.create(tmp_path / "rows.npy", np.float32, (15, 3))
    array.append(np.ones((4, 15, 3)))
    array.append(np.full((3, 15, 3), 2.0))
    np.testing.assert_array_equal(np.load(tmp_path / "rows.npy")[:, 0, 0], [1, 1, 1, 1, 2, 2, 2])
    again = WorkArray(tmp_path / "rows.npy")
    again.resize(5)
    assert len(again) == 5 and np.load(tmp_path / "rows.npy").shape == (5, 15, 3)
    np.testing.assert_array_equal(again.take(np.array([4, 0]))[:, 0, 0], [2, 1])


PEAK_CODE = """
import resource, sys
from mocapdb.builder.config import BuildConfig
from mocapdb.builder.pipeline import build
build(sys.argv[1:-2], sys.argv[-2], BuildConfig(yaw_step_deg=float(sys.argv[-1]), clusters=100, landmarks=300,
                                                workers=1, memory_limit_mb=64))
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
"""


def _peak_mb(files: list, out, yaw_step: float) -> float:
    done = subprocess.run([sys.executable, "-c", PEAK_CODE, *map(str, files), str(out), str(yaw_step)],
                          capture_output=True, text=True, check=True, cwd=ROOT)
    return float(done.stdout.split()[-1])


def test_memory_stays_flat_under_a_small_limit(tmp_path):
    """28× the projections (1 clip at 12°, all 7 sample clips at 2°: 232k projections, 26 MB of 2D
    poses alone, which the in-memory build held several times over) within a few MB."""
    small = _peak_mb([SAMPLE_BVH / "002_03.bvh"], tmp_path / "small", 12.0)
    large = _peak_mb([SAMPLE_BVH], tmp_path / "large", 2.0)
    assert load_database(tmp_path / "large").n_projections == 231_840
    assert large - small < 25, (small, large)


def test_a_new_work_array_leaves_a_hard_link_to_the_old_one_alone(tmp_path):
    """The database hard-links the search index from the work folder: a restarted index stage must
    make new files, not truncate the ones a database holds."""
    array = WorkArray.create(tmp_path / "index_x.npy", np.float32, (3,), 2)
    array[0:2] = np.ones((2, 3))
    os.link(tmp_path / "index_x.npy", tmp_path / "in_database.npy")
    WorkArray.create(tmp_path / "index_x.npy", np.float32, (3,), 2)
    np.testing.assert_array_equal(np.load(tmp_path / "in_database.npy"), np.ones((2, 3)))
    np.testing.assert_array_equal(np.load(tmp_path / "index_x.npy"), np.zeros((2, 3)))


def test_an_index_stage_interrupted_after_its_last_group_goes_on(sources, whole, tmp_path, monkeypatch):
    real = index_stage._finish_index

    def finish_then_stop(run, arrays):
        real(run, arrays)
        raise Interrupt("index finished, not yet recorded")

    with monkeypatch.context() as patch:
        patch.setattr(index_stage, "_finish_index", finish_then_stop)
        with pytest.raises(Interrupt):
            build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    summary = build([str(sources)], tmp_path / "db", _config(memory_limit_mb=TINY_MB))
    assert summary.resumed["index"].startswith("went on from columns done")
    assert_same_database(whole, tmp_path / "db")


def test_the_work_folder_size_skips_a_file_renamed_while_it_counts(tmp_path, monkeypatch):
    """A save under way renames its temporary state file between the listing and its stat."""
    with WorkFolder(tmp_path / "db.work", {stage: {} for stage in STAGES}) as work:
        work.save("centroids", np.zeros(1000))
        (work.path / ".state.json.tmp1").write_bytes(b"{}")
        real_stat = Path.stat

        def vanished(self, **kwargs):
            if self.name == ".state.json.tmp1":
                raise FileNotFoundError(self)
            return real_stat(self, **kwargs)

        monkeypatch.setattr(Path, "stat", vanished)
        assert work.size_bytes() >= 8000
