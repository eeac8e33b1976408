"""How much memory a build may take: the default ``--memory-limit``, chunk sizes from it, the peak
measured (``data_specs/build.md``, "Memory").

The limit is the peak resident memory the build aims at. The process itself takes about
:data:`PROCESS_BASE_MB` (interpreter, numpy, numba, pyarrow, the compiled kernels, the landmark
MDS and k-means seeding samples); the rest, up to :data:`CHUNK_BYTES_MAX`, is each stage's chunk.
Larger chunks are no faster, so memory stays flat however large the library is.
"""
from __future__ import annotations

import os
import resource
import sys
from dataclasses import dataclass

MB = 1 << 20
DEFAULT_FRACTION = 0.25        # --memory-limit by default: this share of the machine's memory
PROCESS_BASE_MB = 400          # measured: a build's process before its chunks (data_specs/build.md)
CHUNK_BYTES_MAX = 256 * MB     # no stage's chunk is larger: bigger ones are no faster


def machine_memory_mb() -> int:
    """The machine's physical memory in MB (4096 where the system does not say)."""
    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE") // MB
    except (ValueError, OSError, AttributeError):
        return 4096


def default_memory_limit_mb() -> int:
    """``--memory-limit`` when it is not given: :data:`DEFAULT_FRACTION` of the machine's memory."""
    return int(machine_memory_mb() * DEFAULT_FRACTION)


def peak_memory_mb(children: bool = False) -> float:
    """Peak resident memory in MB of this process (or of its largest ended child process)."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN if children else resource.RUSAGE_SELF).ru_maxrss
    return usage / MB if sys.platform == "darwin" else usage / 1024  # bytes on macOS, KiB elsewhere


@dataclass(frozen=True)
class ChunkPlan:
    """Chunk sizes under a memory limit of ``limit_mb``."""

    limit_mb: int

    @property
    def chunk_bytes(self) -> int:
        """Bytes one stage's chunk may take: the limit less the process's own, at most
        :data:`CHUNK_BYTES_MAX` (0 when the limit is below the process's own memory)."""
        return max(0, min(CHUNK_BYTES_MAX, (self.limit_mb - PROCESS_BASE_MB) * MB))

    @property
    def below_base(self) -> bool:
        """The limit leaves nothing for chunks: the build runs in its smallest ones."""
        return self.chunk_bytes == 0

    @property
    def budget_bytes(self) -> int:
        """All the limit leaves beside the process's own memory (for a stage that is faster in
        fewer, larger pieces, up to a cap of its own: the search index's groups)."""
        return max(0, (self.limit_mb - PROCESS_BASE_MB) * MB)

    def rows(self, bytes_per_row: float, multiple: int = 1) -> int:
        """Rows per chunk at ``bytes_per_row``: a whole multiple of ``multiple``, at least one."""
        return max(1, int(self.chunk_bytes // bytes_per_row) // multiple) * multiple
