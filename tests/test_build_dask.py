"""The build on a Dask cluster (issue 21, item 3): a LocalCluster of three worker processes gives the
database the local build gives (same clusters from the same seed, same rows, byte for byte the same
Parquet tables), in small chunks spread over the workers; a build interrupted on the cluster goes on
locally; a bad --scheduler is a clear error before any work."""
import json

import pytest

import mocapdb.builder.pipeline as pipeline
from mocapdb.builder.pipeline import build
from mocapdb.builder.tasks import CHUNKS_PER_SLOT, Tasks, TasksError, connect
from mocapdb.cli.main import main

from . import test_builder
from .test_build_out_of_core import TINY_MB, assert_same_database, whole  # noqa: F401 - the fixture
from .test_builder import _config

sources = test_builder.sources  # the fixture: two clips, 7,920 projections

distributed = pytest.importorskip("dask.distributed")


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=3, threads_per_worker=1, processes=True, dashboard_address=None,
                                       silence_logs=40)
    with distributed.Client(cluster) as client:
        yield client
    cluster.close()


def _table_digests(db) -> dict:
    return {name: entry["sha256"] for name, entry in json.loads((db / "manifest.json").read_text())["tables"].items()}


def test_a_three_worker_cluster_builds_the_local_database(sources, whole, client, tmp_path):  # noqa: F811
    out = tmp_path / "db"
    summary = build([str(sources)], out, _config(memory_limit_mb=8000), client=client)  # as `whole`
    assert_same_database(out, whole)
    assert _table_digests(out) == _table_digests(whole)  # the write's row groups follow the limit
    assert summary.cluster.startswith("3 Dask workers (3 threads)") and summary.worker_peak_mb > 0
    assert client.status == "running"  # a client it was given stays open


def test_a_cluster_cuts_the_stages_into_chunks_for_every_worker():
    class Three(Tasks):
        slots = 3

    rows = Three().chunk_rows(1 << 20, 7920, 1024)
    assert rows == 1024 and -(-7920 // rows) >= CHUNKS_PER_SLOT * 2
    assert Tasks().chunk_rows(1 << 20, 7920, 1024) == 1 << 20  # here: the memory plan's chunk, one task


def test_a_build_interrupted_on_the_cluster_goes_on_here(sources, whole, client, tmp_path, monkeypatch):  # noqa: F811
    out = tmp_path / "db"

    def interrupted(run):
        raise KeyboardInterrupt

    with monkeypatch.context() as patch:
        patch.setitem(pipeline._STAGE_BODIES, "assign", interrupted)
        with pytest.raises(KeyboardInterrupt):
            build([str(sources)], out, _config(memory_limit_mb=TINY_MB), client=client)
    summary = build([str(sources)], out, _config(memory_limit_mb=TINY_MB))
    assert set(summary.resumed) == {"read", "project", "embed", "cluster"}
    assert_same_database(out, whole)


def test_the_cli_starts_a_local_cluster(sources, tmp_path, capsys):
    args = ["build", str(sources), "--memory-limit", "64", "--landmarks", "200", "--clusters", "40"]
    assert main([*args, "--out", str(tmp_path / "here")]) == 0
    assert main([*args, "--out", str(tmp_path / "dask"), "--scheduler", "local:2"]) == 0
    assert "tasks ran on 2 Dask workers (2 threads)" in capsys.readouterr().out
    assert_same_database(tmp_path / "dask", tmp_path / "here")


@pytest.mark.parametrize("scheduler", ["local:0", "local:x", "local:-1"])
def test_a_bad_local_cluster_is_named(scheduler):
    with pytest.raises(TasksError, match="'local:N' needs N workers"):
        connect(scheduler)


def test_workers_that_cannot_run_the_build_are_named(client, monkeypatch):
    from mocapdb.builder import tasks

    def broken(modules):
        raise ModuleNotFoundError("No module named 'mocapdb'")

    monkeypatch.setattr(tasks, "_prepare_worker", broken)
    with pytest.raises(TasksError, match="cannot run mocapdb's build.*No module named 'mocapdb'"):
        tasks.DaskTasks(client)
