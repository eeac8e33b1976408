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
"""
from __future__ import annotations

import fnmatch
import os
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from mocapdb import __version__
from mocapdb.builder.embedding import (
    KMEANS_BLOCK_ROWS,
    KMeansBounds,
    KMeansState,
    fit_landmarks,
    kmeans_finish,
    kmeans_iterate,
    kmeans_seed,
    landmark_pool,
    nearest_poses,
)
from mocapdb.builder.index import BYTES_PER_COLUMN, columns_of, gather_group, subclusters_of
from mocapdb.builder.memory import ChunkPlan, default_memory_limit_mb, peak_memory_mb
from mocapdb.builder.tasks import DaskTasks, ProcessTasks, Tasks, connect
from mocapdb.builder.work import STAGES, WorkArray, WorkFolder
from mocapdb.core import domains as D
from mocapdb.core.cameras import DatabaseCamera
from mocapdb.core.clips import Clip, ClipOptions, clips_from_bvh, joint_map_for
from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import output_target, recover_interrupted
from mocapdb.core.formats.bvh import BvhError
from mocapdb.core.formats.database import DatabaseWriter, check_output_path
from mocapdb.core.formats.search_index import ARRAYS as INDEX_ARRAYS
from mocapdb.core.geometry import normalize_pose_2d, project_views
from mocapdb.core.joint_map import UNITS, UP_AXES, JointMapError, load_joint_map_file
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import (
    BONE_LENGTHS_M,
    KEYPOINTS,
    N_KEYPOINTS_2D,
    N_POINTS,
    PELVIS,
    RIG_JOINTS,
)

MAX_YAWS = 32767  # projections.yaw is int16
KMEANS_MAX_ITER = 50
COMMIT_INTERVAL_S = 10.0  # a stage's progress is saved at most this often (and at its end)
MIN_CHUNK_ROWS = 1024  # chunks of rows (poses, projections, frames written) are whole multiples of this
# Memory per chunk row of each stage, bytes (measured, with margin; data_specs/build.md "Memory"):
PROJECT_BYTES_PER_PROJECTION = 2048  # float64 views, pixels and normalisation of one projection
EMBED_BYTES_PER_POSE = 256           # the pose read, its coordinates written
KMEANS_BYTES_PER_POINT = 64          # the point, its label and bounds
ASSIGN_BYTES_PER_POSE = 256          # the pose read, its label written
WRITE_BYTES_PER_PROJECTION = 1024    # the row read, its Arrow and Parquet encodings
WRITE_BYTES_PER_FRAME = 2048
INDEX_BYTES_PER_ROW = 256            # the index: a pose read, its label and column
INDEX_GROUP_BYTES_MAX = 1 << 30      # the index's column groups: larger ones save a pass over the poses
                                     # (~1 s at 28 M) but would make memory grow with the library


class BuildError(MocapdbError, RuntimeError):
    """A build that cannot go on; the message says why, ``skipped`` names the files skipped before
    it stopped, each with its reason (``(path, reason)`` pairs)."""

    def __init__(self, message: str, skipped: list[tuple[str, str]] = ()):
        super().__init__(message)
        self.skipped = list(skipped)


@dataclass
class BuildConfig:
    """Parameters of a database build (defaults are the method's)."""

    fps: float = D.DATABASE_FPS_HZ.default
    yaw_step_deg: float = D.YAW_STEP_DEG.default
    camera: DatabaseCamera = field(default_factory=DatabaseCamera)
    clusters: int = D.CLUSTERS.default
    dims: int = D.DIMS.default
    seed: int = 0
    landmarks: int = D.LANDMARKS.default
    workers: int = 1
    strict: bool = False
    joint_map: Path | None = None  # for the files no other map covers
    joint_maps: tuple[tuple[str, Path], ...] = ()  # (glob pattern, map), first match first
    unit: str | None = None
    up_axis: str | None = None
    credit: str | None = None
    mirror: bool = True  # also store every clip's left-right mirror image
    memory_limit_mb: int | None = None  # peak memory aimed at; None: default_memory_limit_mb()
    work_dir: Path | None = None  # the work folder; None: the output's path with ".work" appended
    restart: bool = False  # ignore an interrupted build's work and start again
    scheduler: str | None = None  # run the tasks on Dask: a scheduler's address, or "local:N" workers here

    def clip_options(self) -> ClipOptions:
        """The options that turn a BVH file into clips (:mod:`mocapdb.core.clips`)."""
        return ClipOptions(self.fps, self.joint_map, self.unit, self.up_axis, self.credit, self.mirror,
                           self.joint_maps)

    @property
    def yaws_deg(self) -> np.ndarray:
        step = D.YAW_STEP_DEG.check(self.yaw_step_deg, "--yaw-step")
        ratio = 360.0 / step
        n = round(ratio) if ratio < MAX_YAWS + 1 else 0
        if n < 1 or abs(n * step - 360.0) > 1e-6:
            raise BuildError(f"--yaw-step {step} does not divide 360 degrees into 1 to {MAX_YAWS} yaws")
        return np.arange(n) * step

    @property
    def limit_mb(self) -> int:
        """The memory limit in MB: the one given, else the default (a share of the machine's)."""
        return default_memory_limit_mb() if self.memory_limit_mb is None else self.memory_limit_mb

    def check(self) -> None:
        """Raise DomainError or BuildError naming the first option (by its ``mocapdb build`` flag)
        that cannot work."""
        for flag, domain, value in [
                ("--fps", D.FPS_HZ, self.fps), ("--camera-height", D.CAMERA_HEIGHT_M, self.camera.height_m),
                ("--camera-distance", D.CAMERA_DISTANCE_M, self.camera.distance_m),
                ("--focal", D.FOCAL_PX, self.camera.focal_px), ("--clusters", D.CLUSTERS, self.clusters),
                ("--dims", D.DIMS, self.dims), ("--landmarks", D.LANDMARKS, self.landmarks),
                ("--workers", D.WORKERS, self.workers), ("--seed", D.SEED, self.seed),
                ("camera width_px", D.IMAGE_SIDE_PX, self.camera.width_px),
                ("camera height_px", D.IMAGE_SIDE_PX, self.camera.height_px)]:
            domain.check(value, flag)
        D.MEMORY_LIMIT_MB.check_optional(self.memory_limit_mb, "--memory-limit")
        self.yaws_deg
        if self.landmarks <= self.dims:
            raise BuildError(f"--landmarks {self.landmarks} is too few for --dims {self.dims}: "
                             "landmark MDS needs at least dims + 1 landmarks")
        if self.unit not in (None, *UNITS) or self.up_axis not in (None, *UP_AXES):
            raise BuildError(f"unknown --unit {self.unit!r} or --up-axis {self.up_axis!r}: "
                             f"units {', '.join(UNITS)}; up axes {', '.join(UP_AXES)}")


@dataclass
class BuildSummary:
    files: int = 0
    clips: int = 0
    mirrored: int = 0
    frames: int = 0
    projections: int = 0
    clusters: int = 0
    skipped: list[tuple[str, str]] = field(default_factory=list)
    rigs: dict[str, int] = field(default_factory=dict)  # files read per detected rig (and map)
    seconds: dict[str, float] = field(default_factory=dict)
    bytes_on_disk: int = 0
    warnings: list[str] = field(default_factory=list)
    resumed: dict[str, str] = field(default_factory=dict)  # stage → what an earlier run had done of it
    memory_limit_mb: int = 0
    peak_memory_mb: float = 0.0  # this process's peak resident memory
    reader_peak_mb: float = 0.0  # the largest reader process's (0: read in this process)
    cluster: str = ""  # where the tasks ran, when not here: "3 Dask workers (3 threads) at tcp://..."
    worker_peak_mb: float = 0.0  # the largest Dask worker process's peak resident memory
    work_bytes: int = 0  # the work folder's largest size on disk

    def report(self) -> str:
        lines = [f"files {self.files}, clips {self.clips} (files split at jumps in the data; {self.mirrored} of them "
                 f"mirrored copies), frames {self.frames}, projections {self.projections}, "
                 f"clusters {self.clusters}, size on disk {self.bytes_on_disk / 1e6:.1f} MB"]
        if self.rigs:
            lines.append("files per rig: " + "; ".join(f"{rig} {n}" for rig, n in sorted(self.rigs.items())))
        lines += [f"resumed {stage}: {what}" for stage, what in self.resumed.items()]
        lines += [f"  {stage:<12} {sec:8.2f} s" for stage, sec in self.seconds.items()]
        lines.append(f"  {'total':<12} {sum(self.seconds.values()):8.2f} s")
        readers = f", reader processes {self.reader_peak_mb:.0f} MB" if self.reader_peak_mb else ""
        workers = f", Dask workers {self.worker_peak_mb:.0f} MB" if self.cluster else ""
        lines.append(f"peak memory {self.peak_memory_mb:.0f} MB (limit {self.memory_limit_mb} MB){readers}{workers}; "
                     f"work folder up to {self.work_bytes / 1e6:.1f} MB")
        if self.cluster:
            lines.append(f"tasks ran on {self.cluster}")
        lines += [f"skipped {path}: {why}" for path, why in self.skipped]
        lines += [f"warning: {text}" for text in self.warnings]
        return "\n".join(lines)


def find_sources(sources: list[str], exclude: list[str] = ()) -> list[tuple[Path, Path]]:
    """BVH files named or found (recursively) under ``sources``, minus ``exclude`` glob patterns.

    Returns sorted ``(file, source_root)`` pairs; a pattern matches the file name or its path.
    """
    found: dict[Path, Path] = {}
    for src in sources:
        root = Path(src)
        if root.is_dir():
            files = [p for p in root.rglob("*") if p.suffix.lower() == ".bvh" and p.is_file()]
        elif root.is_file():
            files, root = [root], root.parent
        else:
            raise BuildError(f"source {src!r} is neither a BVH file nor a folder")
        for f in files:
            if not any(fnmatch.fnmatch(f.name, pat) or fnmatch.fnmatch(str(f), pat) for pat in exclude):
                found.setdefault(f, root)
    return sorted(found.items())


def _process_one(args: tuple[Path, Path, BuildConfig]) -> list[Clip] | tuple[str, str]:
    """One file's clips, or ``(file, reason)`` when anything goes wrong: one bad file never ends a build."""
    path, root, config = args
    try:
        return clips_from_bvh(path, root, config.clip_options())
    except (BvhError, JointMapError) as exc:
        return (str(path), str(exc))
    except Exception as exc:  # noqa: BLE001 - any failure on one file is that file's skip reason
        return (str(path), f"unexpected {type(exc).__name__}: {exc}")


# ----------------------------------------------------------------------------------- read


def _clip_row(clip: Clip) -> dict:
    return {"name": clip.name, "source": clip.source, "source_fps": clip.source_fps, "convention": clip.convention,
            "credit": clip.credit, "mirrored": clip.mirrored, "n_frames": len(clip.positions)}


def _read_stage(run: _Run, files: list[tuple[Path, Path]]) -> list[WorkArray]:
    """Every file's clips (in ``config.workers`` processes) appended to the frame arrays in the files'
    order; the clip table and the skipped files go to the stage's record."""
    record = run.work.record("read")
    if "files_done" not in record:
        record.update(files_done=0, clips=[], skipped=[], rigs={})
        run.work.new_array("positions", np.float32, (N_POINTS, 3))
        run.work.new_array("quaternions", np.float32, (len(RIG_JOINTS), 4))
    arrays = [run.work.array("positions"), run.work.array("quaternions")]
    frames = sum(c["n_frames"] for c in record["clips"])
    for array in arrays:
        array.resize(frames)  # what an interrupted run appended after its last commit goes
    jobs = [(path, root, run.config) for path, root in files[record["files_done"]:]]
    bar = progress(total=len(files), initial=record["files_done"], desc="read+retarget", unit="file")
    for job, result in zip(jobs, run.readers.in_order(_process_one, jobs)):
        if isinstance(result, tuple):
            record["skipped"].append(list(result))
        else:
            rig = _rig_of(result[0], joint_map_for(job[0], job[1], run.config.clip_options()))
            record["rigs"][rig] = record["rigs"].get(rig, 0) + 1
        for clip in result if isinstance(result, list) else []:
            arrays[0].append(clip.positions)
            arrays[1].append(clip.quaternions)
            record["clips"].append(_clip_row(clip))
        record["files_done"] += 1
        bar.update()
        _checkpoint(run, arrays)
    bar.close()
    return arrays


def _rig_of(clip: Clip, joint_map: Path | None) -> str:
    """How a file's rig was read, for the summary: its convention label, and the joint map."""
    return f"{clip.convention} ({joint_map})" if joint_map else clip.convention


def _check_read(record: dict, config: BuildConfig, summary: BuildSummary) -> None:
    """The skipped files into the summary; :class:`BuildError` with ``--strict`` and a skip, or without
    any clip."""
    summary.skipped = [tuple(s) for s in record["skipped"]]
    summary.rigs = dict(record.get("rigs", {}))
    if summary.skipped and config.strict:
        raise BuildError("--strict: " + "; ".join(f"{p}: {why}" for p, why in summary.skipped))
    if not record["clips"]:
        why = f": all {len(summary.skipped)} BVH file(s) were skipped" if summary.skipped else ""
        raise BuildError(f"no readable BVH clip among the sources{why}", summary.skipped)


# ----------------------------------------------------------------------------------- chunked stages


@dataclass
class _Run:
    """One build's shared pieces."""

    config: BuildConfig
    work: WorkFolder
    plan: ChunkPlan
    summary: BuildSummary
    chunks: Tasks = field(default_factory=Tasks)   # runs the chunked stages' tasks
    readers: Tasks = field(default_factory=Tasks)  # reads the BVH files
    n_yaws: int = 0
    n_frames: int = 0

    @property
    def n_projections(self) -> int:
        return self.n_frames * self.n_yaws

    def note_disk(self) -> None:
        """Keep the work folder's largest size so far in the summary."""
        self.summary.work_bytes = max(self.summary.work_bytes, self.work.size_bytes())


def _checkpoint(run: _Run, arrays: list[WorkArray]) -> None:
    """Save the progress (``arrays`` made durable) when the last save is :data:`COMMIT_INTERVAL_S` old."""
    if time.monotonic() - run.work.last_commit > COMMIT_INTERVAL_S:
        run.work.commit(*arrays)


def _chunked(run: _Run, stage: str, total: int, rows: int, task: Callable, job: Callable[[int, int], object],
             arrays: list[WorkArray], desc: str, unit: str, multiple: int = 1) -> None:
    """``task(job(start, stop))`` for the chunks of the stage's ``total`` rows that an earlier run has
    not done, ``rows`` at a time (fewer where that leaves a cluster's task slots idle); a chunk counts
    as done once its task has returned and every chunk before it has (progress saved every
    :data:`COMMIT_INTERVAL_S`)."""
    record = run.work.record(stage)
    done = record.setdefault("rows_done", 0)
    rows = run.chunks.chunk_rows(rows, total - done, multiple)
    ranges = [(start, min(start + rows, total)) for start in range(done, total, rows)]
    bar = progress(total=total, initial=done, desc=desc, unit=unit)
    for (start, stop), _ in zip(ranges, run.chunks.in_order(task, [job(*r) for r in ranges])):
        record["rows_done"] = stop
        bar.update(stop - start)
        _checkpoint(run, arrays)
    bar.close()


def _output(run: _Run, stage: str, name: str, dtype: type, row_shape: tuple[int, ...], rows: int) -> WorkArray:
    """The stage's output array: made anew when the stage starts, the earlier run's when it resumes."""
    if "rows_done" in run.work.record(stage):
        return run.work.array(name)
    return run.work.new_array(name, dtype, row_shape, rows)


def project_frames(positions_m: np.ndarray, config: BuildConfig) -> np.ndarray:
    """Normalised 2D poses ``[F·V, 14, 2]`` float32 (frame-major) of frames ``[F, 15, 3]`` from every yaw."""
    positions_m = positions_m.astype(np.float64)
    pixels = project_views(positions_m, positions_m[:, PELVIS], config.yaws_deg, 0.0, config.camera)
    normalised, _, _ = normalize_pose_2d(pixels[..., :N_KEYPOINTS_2D, :])
    return normalised.reshape(-1, N_KEYPOINTS_2D, 2).astype(np.float32)


def _project_task(job: tuple) -> None:
    positions, keypoints, config, start, stop, durable = job
    n_yaws = len(config.yaws_deg)
    keypoints[start * n_yaws:stop * n_yaws] = project_frames(positions[start:stop], config)
    if durable:  # written on another machine: on the shared disk before the task returns
        keypoints.sync()


def _project_stage(run: _Run) -> list[WorkArray]:
    positions = run.work.array("positions")
    keypoints = _output(run, "project", "keypoints_2d", np.float32, (N_KEYPOINTS_2D, 2), run.n_projections)
    frames = run.plan.rows(PROJECT_BYTES_PER_PROJECTION * run.n_yaws)
    config = run.chunks.share(run.config)
    _chunked(run, "project", run.n_frames, frames, _project_task,
             lambda start, stop: (positions, keypoints, config, start, stop, run.chunks.remote),
             [keypoints], "project", "frame")
    return [keypoints]


def _embed_task(job: tuple) -> None:
    keypoints, embedding, landmarks, start, stop, durable = job
    landmarks.place(keypoints[start:stop], embedding[start:stop])
    if durable:  # written on another machine: on the shared disk before the task returns
        embedding.sync()


def _embed_stage(run: _Run) -> list[WorkArray]:
    """Landmark MDS: landmarks from a seeded sample (fitted again, identically, on a resume), then
    every pose placed chunk by chunk."""
    keypoints, config = run.work.array("keypoints_2d"), run.config
    rng = np.random.default_rng(config.seed)
    pool = landmark_pool(len(keypoints), config.landmarks, rng)
    landmarks = run.chunks.share(fit_landmarks(keypoints.take(pool), config.dims, config.landmarks, rng))
    embedding = _output(run, "embed", "embedding", np.float32, (config.dims,), len(keypoints))
    rows = run.plan.rows(EMBED_BYTES_PER_POSE, MIN_CHUNK_ROWS)
    _chunked(run, "embed", len(keypoints), rows, _embed_task,
             lambda start, stop: (keypoints, embedding, landmarks, start, stop, run.chunks.remote),
             [embedding], "embed (MDS)", "pose", MIN_CHUNK_ROWS)
    return [embedding]


def _kmeans_bounds(run: _Run, n: int, fresh: bool) -> KMeansBounds:
    """The labels and bounds of every point: new arrays, or an interrupted run's (any content will do)."""
    names = [(f"kmeans_{name}", dtype) for name, dtype in KMeansBounds.FIELDS]
    if fresh or not all((run.work.path / f"{name}.npy").is_file() for name, _ in names):
        return KMeansBounds(*(run.work.new_array(name, dtype, (), n) for name, dtype in names))
    return KMeansBounds(*(run.work.array(name) for name, _ in names))


def _cluster_stage(run: _Run) -> list[WorkArray]:
    """Streamed k-means of the embedding (saved after every iteration), then each cluster's
    representative; the bounds' scratch arrays are deleted at the end."""
    embedding, config, record = run.work.array("embedding"), run.config, run.work.record("cluster")
    resumed = "iteration" in record
    if resumed:
        state = KMeansState(run.work.load("centroids"), record["tol_abs"], record["iteration"], record["shift"])
    else:
        state = kmeans_seed(embedding, config.clusters, config.seed)
    bounds = _kmeans_bounds(run, len(embedding), fresh=not resumed)
    partial_bytes = 8 * config.clusters * (config.dims + 1) / KMEANS_BLOCK_ROWS  # block sums, per point
    rows = run.plan.rows(KMEANS_BYTES_PER_POINT + partial_bytes, KMEANS_BLOCK_ROWS)
    bar = progress(total=KMEANS_MAX_ITER, initial=state.iteration, desc="k-means", unit="iter")

    def save(state: KMeansState) -> None:
        run.work.save("centroids", state.centroids)
        record.update(iteration=state.iteration, shift=state.shift, tol_abs=state.tol_abs)
        run.work.commit()
        run.work.wait()  # the state of this iteration is on disk before the next one's centroids
        bar.update()

    kmeans_iterate(embedding, state, bounds, KMEANS_MAX_ITER, rows, save, run.chunks)
    bar.close()
    run.work.save("representatives", kmeans_finish(embedding, state, bounds, rows, run.chunks))
    run.note_disk()
    for array in (bounds.labels, bounds.upper, bounds.lower):
        array.path.unlink()
    return []


def assign_to_representatives(poses: np.ndarray, reps: np.ndarray, rep_poses: np.ndarray,
                              first_row: int = 0) -> np.ndarray:
    """Cluster (int32) of each of ``poses [n, 14, 2]`` (rows ``first_row…`` of the projections) = its
    nearest representative under Eq. 1; ``rep_poses`` are the poses of the non-empty clusters'
    representatives ``reps[reps >= 0]``. A representative always belongs to its own cluster (ties).

    k-means works in the 5-D MDS space, which keeps Eq. 1 neighbourhoods only roughly: on the
    CMU set, a projection's own k-means cluster was among the 5 clusters with the nearest
    representatives for only ~70 % of queries. Re-assigning members to their nearest
    representative makes the runtime's "nearest representatives, then their members" search
    find the exact nearest projection (recall ~1.0, see ``mocapdb eval``). Cost O(n·K).
    """
    valid = np.flatnonzero(reps >= 0)
    labels = valid[nearest_poses(poses, rep_poses)].astype(np.int32)
    own = (reps[valid] >= first_row) & (reps[valid] < first_row + len(poses))
    labels[reps[valid][own] - first_row] = valid[own]
    return labels


def _assign_task(job: tuple) -> None:
    keypoints, cluster, reps, rep_poses, start, stop, durable = job
    cluster[start:stop] = assign_to_representatives(keypoints[start:stop], reps, rep_poses, start)
    if durable:  # written on another machine: on the shared disk before the task returns
        cluster.sync()


def _assign_stage(run: _Run) -> list[WorkArray]:
    keypoints, reps = run.work.array("keypoints_2d"), run.work.load("representatives")
    rep_poses = run.chunks.share(keypoints.take(reps[reps >= 0]))
    cluster = _output(run, "assign", "cluster", np.int32, (), len(keypoints))
    rows = run.plan.rows(ASSIGN_BYTES_PER_POSE, MIN_CHUNK_ROWS)
    _chunked(run, "assign", len(keypoints), rows, _assign_task,
             lambda start, stop: (keypoints, cluster, reps, rep_poses, start, stop, run.chunks.remote),
             [cluster], "assign", "pose", MIN_CHUNK_ROWS)
    return [cluster]


def _index_columns(run: _Run) -> np.ndarray:
    """Pass 1 of the index: every projection's column in cluster order (``index_sorted``, scratch),
    streamed over the labels; returns the cluster starts ``[K + 1]``."""
    cluster = run.work.array("cluster")
    rows = run.plan.rows(INDEX_BYTES_PER_ROW, MIN_CHUNK_ROWS)
    counts = np.zeros(run.config.clusters, dtype=np.int64)
    for start, stop in _row_ranges(len(cluster), rows):
        counts += np.bincount(cluster[start:stop], minlength=len(counts))
    cluster_start = np.concatenate([[0], np.cumsum(counts)])
    columns = run.work.new_array("index_sorted", np.int64, (), len(cluster))
    next_free = cluster_start[:-1].copy()
    for start, stop in _row_ranges(len(cluster), rows):
        columns_of(cluster[start:stop], next_free, columns[start:stop])
    return cluster_start


def _cluster_groups(cluster_start: np.ndarray, first: int, max_columns: int) -> Iterator[tuple[int, int]]:
    """``(c0, c1)``: runs of whole clusters from ``first`` on, each at most ``max_columns`` columns
    (or one cluster)."""
    c0, k = first, len(cluster_start) - 1
    while c0 < k:
        c1 = max(c0 + 1, int(np.searchsorted(cluster_start, cluster_start[c0] + max_columns, side="right")) - 1)
        yield c0, min(c1, k)
        c0 = min(c1, k)


def _start_index(run: _Run, record: dict) -> None:
    """The index's pass 1 and its empty output arrays (a fresh stage)."""
    n = run.n_projections
    run.work.save("index_cluster_start", _index_columns(run))
    run.work.new_array("index_x", np.float32, (n,), 14)
    run.work.new_array("index_y", np.float32, (n,), 14)
    for name in ("index_rows", "index_columns"):
        run.work.new_array(name, np.int64, (), n)
    for name in ("index_sub_start", "index_sub_rep", "index_subs_of"):
        run.work.new_array(name, np.int64)
    record.update(clusters_done=0, columns_done=0, subs_done=0)
    run.work.commit(run.work.array("index_sorted"))


def _subcluster_group(run: _Run, lo: int, c0: int, c1: int, buffers: tuple, outputs: dict) -> None:
    """Cut clusters ``c0:c1`` (columns from ``lo`` in the group's ``buffers``) into sub-clusters:
    their columns reordered in place, sub-cluster starts, representatives (columns) and counts
    appended to ``outputs``."""
    gx, gy, grows = buffers
    cluster_start, reps = outputs["cluster_start"], outputs["representatives"]
    embedding = np.load(run.work.path / "embedding.npy", mmap_mode="r")
    for c in range(c0, c1):
        a, b = cluster_start[c] - lo, cluster_start[c + 1] - lo
        if a == b:
            outputs["index_subs_of"].append(np.array([0]))
            continue
        members = grows[a:b]
        poses = np.stack([gx[:, a:b].T, gy[:, a:b].T], axis=-1)
        own = int(np.searchsorted(members, reps[c]))
        order, sizes, rep_pos = subclusters_of(poses, embedding[members], own, run.config.seed + c)
        gx[:, a:b], gy[:, a:b], grows[a:b] = gx[:, a:b][:, order], gy[:, a:b][:, order], members[order]
        outputs["index_sub_start"].append(lo + a + np.concatenate([[0], np.cumsum(sizes)[:-1]]))
        outputs["index_sub_rep"].append(lo + a + rep_pos)
        outputs["index_subs_of"].append(np.array([len(sizes)]))


def _index_stage(run: _Run) -> list[WorkArray]:
    """The search index (``builder/index.py``): columns in cluster order, then groups of whole
    clusters as large as the memory limit allows copied, cut into sub-clusters and written; a
    resumed run goes on from the groups done."""
    record, n = run.work.record("index"), run.n_projections
    if "columns_done" not in record:
        _start_index(run, record)
    names = ("index_x", "index_y", "index_rows", "index_columns", "index_sub_start", "index_sub_rep", "index_subs_of")
    arrays = {name: run.work.array(name) for name in names}
    for name, done in (("index_sub_start", "subs_done"), ("index_sub_rep", "subs_done"),
                       ("index_subs_of", "clusters_done")):
        arrays[name].resize(record[done])  # what an interrupted run appended after its last commit goes
    keypoints, sorted_columns = run.work.array("keypoints_2d"), run.work.array("index_sorted")
    outputs = {"cluster_start": run.work.load("index_cluster_start"),
               "representatives": run.work.load("representatives"), **arrays}
    chunk = run.plan.rows(INDEX_BYTES_PER_ROW, MIN_CHUNK_ROWS)
    group_bytes = min(run.plan.budget_bytes, INDEX_GROUP_BYTES_MAX) - chunk * INDEX_BYTES_PER_ROW
    group = max(MIN_CHUNK_ROWS, group_bytes // BYTES_PER_COLUMN)
    bar = progress(total=n, initial=record["columns_done"], desc="index", unit="projection")
    for c0, c1 in _cluster_groups(outputs["cluster_start"], record["clusters_done"], group):
        lo, hi = int(outputs["cluster_start"][c0]), int(outputs["cluster_start"][c1])
        buffers = np.empty((14, hi - lo), np.float32), np.empty((14, hi - lo), np.float32), np.empty(hi - lo, np.int64)
        for start, stop in _row_ranges(n, chunk):
            gather_group(keypoints[start:stop], sorted_columns[start:stop], start, lo, hi, *buffers)
        _subcluster_group(run, lo, c0, c1, buffers, outputs)
        for joint in range(14):
            arrays["index_x"].write_at(joint, lo, buffers[0][joint])
            arrays["index_y"].write_at(joint, lo, buffers[1][joint])
        arrays["index_rows"][lo:hi] = buffers[2]
        arrays["index_columns"].put(buffers[2], np.arange(lo, hi))
        record.update(clusters_done=c1, columns_done=hi, subs_done=len(arrays["index_sub_start"]))
        run.work.commit(*arrays.values())
        bar.update(hi - lo)
    bar.close()
    _finish_index(run, arrays)
    return list(arrays.values())


def _finish_index(run: _Run, arrays: dict) -> None:
    """The index's small arrays in their final form: sub-cluster starts ending at P, each cluster's
    first sub-cluster ``[K + 1]`` (the scratch column order stays until the work folder goes: a run
    interrupted here goes on from it)."""
    starts = np.array(arrays["index_sub_start"][0:len(arrays["index_sub_start"])])
    subs_of = np.array(arrays["index_subs_of"][0:len(arrays["index_subs_of"])])
    run.work.save("index_cluster_subs", np.concatenate([[0], np.cumsum(subs_of)]))
    run.work.save("index_sub_start", np.concatenate([starts, [run.n_projections]]))  # a resume cuts it back
    arrays["index_sub_start"] = run.work.array("index_sub_start")


# ----------------------------------------------------------------------------------- write


def _row_ranges(total: int, rows: int) -> Iterator[tuple[int, int]]:
    return ((start, min(start + rows, total)) for start in range(0, total, rows))


def _clip_table(clips: list[dict]) -> dict:
    n_frames = np.array([c["n_frames"] for c in clips], dtype=np.int64)
    return {
        "clip_name": [c["name"] for c in clips], "clip_source": [c["source"] for c in clips],
        "clip_source_fps": np.array([c["source_fps"] for c in clips], dtype=np.float64),
        "clip_n_frames": n_frames.astype(np.int32), "clip_first_frame": np.cumsum(n_frames) - n_frames,
        "clip_convention": [c["convention"] for c in clips], "clip_credit": [c["credit"] for c in clips],
        "clip_mirrored": np.array([c["mirrored"] for c in clips], dtype=bool),
    }


def _frame_rows(run: _Run, first_frame: np.ndarray) -> Iterator[dict]:
    positions, quaternions = run.work.array("positions"), run.work.array("quaternions")
    for start, stop in _row_ranges(run.n_frames, run.plan.rows(WRITE_BYTES_PER_FRAME, MIN_CHUNK_ROWS)):
        frames = np.arange(start, stop)
        clip = np.searchsorted(first_frame, frames, side="right") - 1
        yield {"frame_clip": clip.astype(np.int32), "frame_index": (frames - first_frame[clip]).astype(np.int32),
               "quaternions": quaternions[start:stop], "positions": positions[start:stop]}


def _projection_rows(run: _Run, cluster_size: np.ndarray, bar) -> Iterator[dict]:
    """The projections table in chunks; counts each chunk's clusters into ``cluster_size``."""
    keypoints, embedding, cluster = (run.work.array(n) for n in ("keypoints_2d", "embedding", "cluster"))
    for start, stop in _row_ranges(run.n_projections, run.plan.rows(WRITE_BYTES_PER_PROJECTION, MIN_CHUNK_ROWS)):
        rows = np.arange(start, stop)
        labels = cluster[start:stop]
        cluster_size += np.bincount(labels, minlength=len(cluster_size))
        yield {"proj_frame": rows // run.n_yaws, "proj_yaw": (rows % run.n_yaws).astype(np.int16),
               "keypoints_2d": keypoints[start:stop], "embedding": embedding[start:stop], "cluster": labels}
        bar.update(stop - start)


def _write_stage(run: _Run, out: str | os.PathLike) -> int:
    """The database, table by table, row group by row group; returns its size in bytes."""
    clips = _clip_table(run.work.record("read")["clips"])
    reps, centroids = run.work.load("representatives"), run.work.load("centroids")
    cluster_size = np.zeros(len(reps), dtype=np.int64)
    bar = progress(total=run.n_projections, desc="write", unit="projection")
    with DatabaseWriter(out, _meta(run.config)) as writer:
        writer.write_table("clips", [clips])
        writer.write_table("frames", _frame_rows(run, clips["clip_first_frame"]))
        writer.write_table("projections", _projection_rows(run, cluster_size, bar))
        writer.write_table("clusters", [{"centroids": centroids.astype(np.float32), "representative": reps,
                                         "cluster_size": cluster_size.astype(np.int32)}])
        writer.add_search_index({name: run.work.path / f"index_{name}.npy" for name in INDEX_ARRAYS})
        size = writer.finish()
    bar.close()
    return size


def _meta(config: BuildConfig) -> dict:
    return {
        "fps": config.fps, "yaw_step_deg": config.yaw_step_deg,
        "yaws_deg": config.yaws_deg.tolist(), "camera": asdict(config.camera),
        "dims": config.dims, "n_clusters": config.clusters, "seed": config.seed,
        "landmarks": config.landmarks, "mirror": config.mirror, "builder_version": __version__,
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "skeleton": {"keypoints": list(KEYPOINTS), "rig_joints": list(RIG_JOINTS),
                     "bone_lengths_m": BONE_LENGTHS_M},
    }


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


def _maps_of(config: BuildConfig, files: list[tuple[Path, Path]]) -> list[Path | None]:
    """Each file's joint map (:func:`~mocapdb.core.clips.joint_map_for`), every one loaded once:
    a bad one raises :class:`JointMapError` before any file is read."""
    options = config.clip_options()
    maps = [joint_map_for(path, root, options) for path, root in files]
    for map_path in dict.fromkeys(m for m in maps if m):
        load_joint_map_file(map_path)
    return maps


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


_STAGE_BODIES: dict[str, Callable[[_Run], list[WorkArray]]] = {
    "project": _project_stage, "embed": _embed_stage, "cluster": _cluster_stage, "assign": _assign_stage,
    "index": _index_stage}


def _run_stage(run: _Run, name: str, body: Callable[[_Run], list[WorkArray]]) -> None:
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


def _stages(run: _Run, files: list[tuple[Path, Path]], out: str | os.PathLike) -> None:
    _run_stage(run, "read", lambda r: _read_stage(r, files))
    read = run.work.record("read")
    _check_read(read, run.config, run.summary)
    run.n_yaws, run.n_frames = len(run.config.yaws_deg), sum(c["n_frames"] for c in read["clips"])
    run.config = _fit_clusters(run.config, run.n_projections, run.summary)
    for name in STAGES[1:]:
        _run_stage(run, name, _STAGE_BODIES[name])
    start = time.perf_counter()
    run.summary.bytes_on_disk = _write_stage(run, out)
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
    maps = _maps_of(config, files)
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
            run = _Run(config, work, plan, summary, tasks or Tasks(), tasks or ProcessTasks(config.workers))
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


def _finish_summary(run: _Run, n_files: int) -> None:
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
