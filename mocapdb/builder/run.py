"""One build's shared pieces: :class:`BuildRun` (its options, work folder, chunk plan, tasks and
:class:`BuildSummary`, what it reports), and the loop the chunked stages share: chunks of rows an
earlier run has not done, run as tasks, progress saved every :data:`COMMIT_INTERVAL_S`.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from mocapdb.builder.config import BuildConfig
from mocapdb.builder.memory import ChunkPlan
from mocapdb.builder.tasks import Tasks
from mocapdb.builder.work import WorkArray, WorkFolder
from mocapdb.core.progress import progress

COMMIT_INTERVAL_S = 10.0  # a stage's progress is saved at most this often (and at its end)
MIN_CHUNK_ROWS = 1024  # chunks of rows (poses, projections, frames written) are whole multiples of this


@dataclass
class BuildSummary:
    """What a build did, for its report (:meth:`report`): counts, skipped files, time per stage,
    what an earlier run had done, memory and disk."""

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


@dataclass
class BuildRun:
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


def checkpoint(run: BuildRun, arrays: list[WorkArray]) -> None:
    """Save the progress (``arrays`` made durable) when the last save is :data:`COMMIT_INTERVAL_S` old."""
    if time.monotonic() - run.work.last_commit > COMMIT_INTERVAL_S:
        run.work.commit(*arrays)


def run_chunks(run: BuildRun, stage: str, total: int, rows: int, task: Callable,
               job: Callable[[int, int], object], arrays: list[WorkArray], desc: str, unit: str,
               multiple: int = 1) -> None:
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
        checkpoint(run, arrays)
    bar.close()


def stage_output(run: BuildRun, stage: str, name: str, dtype: type, row_shape: tuple[int, ...],
                 rows: int) -> WorkArray:
    """The stage's output array: made anew when the stage starts, the earlier run's when it resumes."""
    if "rows_done" in run.work.record(stage):
        return run.work.array(name)
    return run.work.new_array(name, dtype, row_shape, rows)


def row_ranges(total: int, rows: int) -> Iterator[tuple[int, int]]:
    """``(start, stop)`` of ``total`` rows, ``rows`` at a time."""
    return ((start, min(start + rows, total)) for start in range(0, total, rows))
