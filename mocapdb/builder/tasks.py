"""Where a build's tasks run: here (chunks in this process, BVH files in reader processes) or on a Dask
cluster (``mocapdb build --scheduler``). The tasks and their results are the same either way; only who
runs them changes (``data_specs/build.md``, "On a Dask cluster").

A task is a module-level function of one job (picklable: paths, slices, small arrays); the stage
takes the results in the jobs' order, so its progress is the prefix of jobs done, as in a local build.
"""
from __future__ import annotations

import math
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from typing import Protocol

from mocapdb import __version__
from mocapdb.core.errors import MocapdbError

AHEAD_PER_SLOT = 4     # tasks submitted ahead of the one awaited, per task slot (results never pile up)
CHUNKS_PER_SLOT = 4    # a distributed stage is cut into at least this many chunks per task slot
CONNECT_TIMEOUT_S = 30


class TasksError(MocapdbError, RuntimeError):
    """A cluster that cannot be used: Dask missing, the scheduler unreachable, workers of another version."""


class Tasks:
    """Runs jobs one after the other in this process (the local build's chunked stages)."""

    slots = 1        # tasks that run at once
    remote = False   # tasks run in other processes, which must make what they write durable themselves

    def in_order(self, task: Callable, jobs: Iterable) -> Iterator:
        """``task(job)`` for every job, yielded in the jobs' order."""
        return map(task, jobs)

    def share(self, value: object) -> object:
        """``value`` as the tasks should receive it (on a cluster: sent to every worker once)."""
        return value

    def chunk_rows(self, rows: int, total: int, multiple: int = 1) -> int:
        """Rows per chunk: ``rows`` (the memory plan's), made smaller where that leaves task slots idle
        (at least :data:`CHUNKS_PER_SLOT` chunks per slot), a whole multiple of ``multiple``."""
        if self.slots == 1:
            return rows
        spread = math.ceil(total / (CHUNKS_PER_SLOT * self.slots) / multiple) * multiple
        return max(multiple, min(rows, spread))

    def close(self) -> None:
        """Let go of the processes or the cluster connection this holds."""


class ProcessTasks(Tasks):
    """Runs jobs in ``workers`` local processes (the read stage's BVH files)."""

    def __init__(self, workers: int):
        self.slots = workers

    def in_order(self, task: Callable, jobs: Iterable) -> Iterator:
        jobs = list(jobs)
        if self.slots == 1 or len(jobs) < 2:
            yield from map(task, jobs)
            return
        with ProcessPoolExecutor(max_workers=self.slots) as pool:
            yield from _windowed(pool.submit, task, jobs, AHEAD_PER_SLOT * self.slots)


class DaskTasks(Tasks):
    """Runs jobs on a Dask cluster through ``client`` (a ``dask.distributed.Client``). A client it was
    given stays open; one :func:`connect` made (and its ``local:N`` cluster) is closed with it.
    ``warm``: modules each worker imports at once (their numba kernels load from their cache), so the
    first task of a stage does not pay for it."""

    remote = True

    def __init__(self, client, cluster=None, owned: bool = False, warm: tuple[str, ...] = ()):
        self.client, self.cluster, self.owned = client, cluster, owned
        try:
            versions = client.run(_prepare_worker, warm)
        except Exception as exc:  # noqa: BLE001 - whatever a worker raised, the build cannot use it
            raise TasksError(f"the Dask workers cannot run mocapdb's build (pip install 'mocapdb[dask]' on each): "
                             f"{type(exc).__name__}: {exc}") from None
        other = {worker: version for worker, version in versions.items() if version != __version__}
        if other:
            raise TasksError(f"workers run another mocapdb than this {__version__}: {other}")
        self.slots = max(1, sum(client.nthreads().values()))

    def describe(self) -> str:
        """"3 Dask workers (3 threads) at tcp://127.0.0.1:40123"."""
        threads = self.client.nthreads()
        return f"{len(threads)} Dask workers ({sum(threads.values())} threads) at {self.client.scheduler.address}"

    def in_order(self, task: Callable, jobs: Iterable) -> Iterator:
        def submit(function: Callable, job: object):
            return self.client.submit(_on_worker, function, job, pure=False)
        return _windowed(submit, task, list(jobs), AHEAD_PER_SLOT * self.slots)

    def share(self, value: object) -> object:
        return self.client.scatter(value, broadcast=True, hash=False)

    def close(self) -> None:
        if self.owned:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def connect(scheduler: str, warm: tuple[str, ...] = ()) -> DaskTasks:
    """The cluster named by ``scheduler``: ``local:N`` starts a cluster of N worker processes on this
    machine (one thread each); anything else is a scheduler's address (``tcp://host:8786``); ``warm``:
    as :class:`DaskTasks`'."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as exc:
        raise TasksError(f"--scheduler {scheduler} needs Dask: pip install 'mocapdb[dask]' ({exc})") from None
    if scheduler.startswith("local:"):
        workers = _local_workers(scheduler)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=40)
        client = Client(cluster)
    else:
        cluster = None
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S)
        except (OSError, TimeoutError, ValueError) as exc:
            raise TasksError(f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})") from None
    try:
        return DaskTasks(client, cluster, owned=True, warm=warm)
    except BaseException:
        client.close()
        if cluster is not None:
            cluster.close()
        raise


def _local_workers(scheduler: str) -> int:
    count = scheduler.removeprefix("local:")
    if not count.isdigit() or not 1 <= int(count) <= 256:
        raise TasksError(f"--scheduler {scheduler}: 'local:N' needs N workers from 1 to 256")
    return int(count)


class _Future(Protocol):
    """What ``submit`` gives: a concurrent.futures or a Dask future."""

    def result(self) -> object: ...


def _windowed(submit: Callable[[Callable, object], _Future], task: Callable, jobs: list, ahead: int) -> Iterator:
    """Results of ``submit(task, job)`` futures in the jobs' order, at most ``ahead`` in flight."""
    pending: deque[_Future] = deque()
    for job in jobs:
        pending.append(submit(task, job))
        if len(pending) >= ahead:
            yield pending.popleft().result()
    while pending:
        yield pending.popleft().result()


def _prepare_worker(modules: tuple[str, ...]) -> str:
    """Imports ``modules`` on a worker (their numba kernels load from their cache); returns the
    worker's mocapdb version."""
    import importlib

    for name in modules:
        importlib.import_module(name)

    return __version__


def _on_worker(task: Callable, job: object) -> object:
    """``task(job)`` on a Dask worker, its numba kernels on as many threads as the worker has."""
    import numba
    from dask.distributed import get_worker

    threads = getattr(get_worker().state, "nthreads", None) or os.cpu_count() or 1
    # numba.config sets NUMBA_NUM_THREADS from the environment at run time: mypy sees no such attribute
    numba.set_num_threads(max(1, min(threads, numba.config.NUMBA_NUM_THREADS)))  # type: ignore[attr-defined]
    return task(job)
