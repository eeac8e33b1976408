"""`mocapdb build`: BVH clips → universal skeleton → yaw projections → MDS → k-means → database,
out of core: each stage streams chunks of a size set by ``--memory-limit`` between the work
folder's arrays, so memory does not grow with the library, and an interrupted build re-run with
the same command goes on where it stopped (``data_specs/build.md``).

Stage costs (N projections, F frames, V yaws, L landmarks, K clusters, d dims, I iterations):
reading and retargeting O(F·source joints); projection O(F·V); landmark MDS O(N·L·14);
k-means O(I·N·K·d); assignment O(N·K·14); the search index O(N · groups) and its sub-clusters
O(Σ n_c² / 1,260) over the clusters' sizes n_c (``builder/index.py``); writing O(N). The chunked
stages run here or as tasks on a Dask cluster (``builder/tasks.py``). ``tools/bench_build.py``
prints how each grows with N.

This module checks the options and the output before any work, runs the stages in order, each
unless an earlier run finished it (the stages: ``builder/read_stage.py``, ``builder/pose_stages.py``,
``builder/index_stage.py``, ``builder/write_stage.py``; what they share: ``builder/run.py``), and
fills the summary.
"""
from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, replace
from pathlib import Path

from mocapdb import __version__
from mocapdb.builder.config import BuildConfig, BuildError
from mocapdb.builder.index_stage import index_stage
from mocapdb.builder.memory import ChunkPlan, peak_memory_mb
from mocapdb.builder.pose_stages import assign_stage, cluster_stage, embed_stage, project_stage
from mocapdb.builder.read_stage import check_read, find_sources, joint_maps_of, read_stage
from mocapdb.builder.run import BuildRun, BuildSummary
from mocapdb.builder.tasks import DaskTasks, ProcessTasks, Tasks, connect
from mocapdb.builder.work import STAGES, WorkArray, WorkFolder
from mocapdb.builder.write_stage import write_stage
from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import output_target, recover_interrupted
from mocapdb.core.formats.database_writer import check_output_path
from mocapdb.core.joint_map import load_joint_map_file


def _check_before_work(out: str | os.PathLike, config: BuildConfig, summary: BuildSummary) -> Path:
    """Fail in milliseconds, before any file is read, on what would stop the build at the end; then
    clean up after interrupted earlier writes of ``out``. Returns the work folder."""
    config.check()
    for map_path in [config.joint_map, *(m for _, m in config.joint_maps)]:
        if map_path:
            load_joint_map_file(map_path)
    check_output_path(out)
    target = output_target(out)
    work = Path(os.path.abspath(config.work_dir)) if config.work_dir else target.with_name(target.name + ".work")
    if work == target or target in work.parents:
        raise BuildError(f"--work-dir {work} lies inside the output {target}: choose a folder beside it")
    summary.warnings += recover_interrupted(out)
    return work


def _fit_clusters(config: BuildConfig, n_projections: int, summary: BuildSummary) -> BuildConfig:
    """``config`` with at most one cluster per projection (a warning says when it had more)."""
    if config.clusters <= n_projections:
        return config
    summary.warnings.append(f"--clusters {config.clusters} is more than the {n_projections} projections: "
                            f"made {n_projections} clusters")
    return replace(config, clusters=n_projections)


def _file_stamp(path: Path) -> list:
    status = path.stat()
    return [str(path), status.st_size, status.st_mtime_ns]


def _fingerprints(config: BuildConfig, files: list[tuple[Path, Path]], maps: list[Path | None]) -> dict[str, dict]:
    """What each stage's result depends on (a change restarts the stage and those after it): for
    the read, every source and the joint map it is read with, by path, size and mtime."""
    options = asdict(config.clip_options())
    options["joint_map"] = _file_stamp(config.joint_map) if config.joint_map else None
    options["joint_maps"] = [[pattern, *_file_stamp(m)] for pattern, m in config.joint_maps]
    return {
        "read": {"builder_version": __version__, "options": options,
                 "sources": [[*_file_stamp(path), str(root), _file_stamp(m) if m else None]
                             for (path, root), m in zip(files, maps)]},
        "project": {"yaw_step_deg": config.yaw_step_deg, "camera": asdict(config.camera)},
        "embed": {"dims": config.dims, "landmarks": config.landmarks, "seed": config.seed},
        "cluster": {"clusters": config.clusters, "seed": config.seed},
        "assign": {},
        "index": {},
    }


_STAGE_BODIES: dict[str, Callable[[BuildRun], list[WorkArray]]] = {
    "project": project_stage, "embed": embed_stage, "cluster": cluster_stage, "assign": assign_stage,
    "index": index_stage}


def _run_stage(run: BuildRun, name: str, body: Callable[[BuildRun], list[WorkArray]]) -> None:
    """Run a stage unless an earlier run finished it; note in the summary what an earlier run did."""
    record = run.work.record(name)
    if record.get("done"):
        run.summary.resumed[name] = "done by an earlier run"
        return
    done = [f"{key.replace('_', ' ')} {record[key]:,}"
            for key in ("files_done", "rows_done", "iteration", "columns_done") if record.get(key)]
    if done:
        run.summary.resumed[name] = "went on from " + ", ".join(done)
    start = time.perf_counter()
    arrays = body(run)
    record["done"] = True
    run.work.commit(*arrays)
    run.summary.seconds[name] = time.perf_counter() - start
    run.note_disk()


def _stages(run: BuildRun, files: list[tuple[Path, Path]], out: str | os.PathLike) -> None:
    _run_stage(run, "read", lambda r: read_stage(r, files))
    read = run.work.record("read")
    check_read(read, run.config, run.summary)
    run.n_yaws, run.n_frames = len(run.config.yaws_deg), sum(c["n_frames"] for c in read["clips"])
    run.config = _fit_clusters(run.config, run.n_projections, run.summary)
    for name in STAGES[1:]:
        _run_stage(run, name, _STAGE_BODIES[name])
    start = time.perf_counter()
    run.summary.bytes_on_disk = write_stage(run, out)
    run.summary.seconds["write"] = time.perf_counter() - start


def build(sources: list[str], out: str | os.PathLike, config: BuildConfig,
          exclude: Iterable[str] = (), client=None) -> BuildSummary:
    """Build a database at ``out`` from BVH files and folders; returns the summary.

    The work folder (``config.work_dir``, else ``out`` + ``.work``) holds each stage's arrays and the
    state; it is removed after the database is written, and when the build fails on its inputs
    (:class:`~mocapdb.core.errors.MocapdbError`). An interrupted build leaves it: the same call goes
    on where it stopped (``config.restart`` starts again).

    The tasks run here, or on a Dask cluster: ``client`` (a ``dask.distributed.Client``, left open)
    or ``config.scheduler`` (connected to, and closed after). The work folder and the sources must
    then be at the same paths on every worker (a shared disk); the database is the same either way.
    """
    summary = BuildSummary(memory_limit_mb=config.limit_mb)
    work_dir = _check_before_work(out, config, summary)
    files = find_sources(sources, list(exclude))
    if not files:
        raise BuildError(f"no .bvh file found in {', '.join(sources)}")
    maps = joint_maps_of(config, files)
    plan = ChunkPlan(config.limit_mb)
    if plan.below_base:
        summary.warnings.append(f"--memory-limit {config.limit_mb} MB is below what the process itself takes "
                                "(data_specs/build.md): the build runs in its smallest chunks")
    warm = (__name__,)   # a worker imports the build's modules once, not on its first task
    tasks = (DaskTasks(client, warm=warm) if client is not None
             else connect(config.scheduler, warm) if config.scheduler else None)
    try:
        with WorkFolder(work_dir, _fingerprints(config, files, maps), config.restart) as work:
            summary.warnings += work.notes
            run = BuildRun(config, work, plan, summary, tasks or Tasks(), tasks or ProcessTasks(config.workers))
            try:
                _stages(run, files, out)
            except MocapdbError:
                work.remove()
                raise
            work.remove()
        _finish_summary(run, len(files))
    finally:
        if tasks is not None:
            tasks.close()
    return summary


def _finish_summary(run: BuildRun, n_files: int) -> None:
    summary, clips = run.summary, run.work.record("read")["clips"]
    summary.files = n_files - len(summary.skipped)
    summary.clips, summary.frames = len(clips), run.n_frames
    summary.mirrored = sum(c["mirrored"] for c in clips)
    summary.projections, summary.clusters = run.n_projections, run.config.clusters
    summary.peak_memory_mb = peak_memory_mb()
    if isinstance(run.chunks, DaskTasks):
        summary.cluster = run.chunks.describe()
        summary.worker_peak_mb = max(run.chunks.client.run(peak_memory_mb).values())
    elif run.config.workers > 1:
        summary.reader_peak_mb = peak_memory_mb(children=True)
