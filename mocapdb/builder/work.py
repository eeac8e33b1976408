"""The build's work folder: each stage's arrays as ``.npy`` files read and written by row ranges, and
a state file saying which stages (and how much of the current one) are done, so that an interrupted
build re-run with the same command goes on where it stopped (``data_specs/build.md``).
"""
from __future__ import annotations

import fcntl
import json
import os
import shutil
import stat
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TextIO

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import write_atomic

WORK_FORMAT = 1
STATE_FILE = "state.json"
LOCK_FILE = "lock"
STAGES = ("read", "project", "embed", "cluster", "assign", "index")  # the resumable stages, in order


class WorkError(MocapdbError, RuntimeError):
    """A work folder that cannot be used (another build holds it, or it is not a work folder)."""


class WorkArray:
    """A ``.npy`` file of rows ``[n, *row_shape]``, read and written by row ranges through memory maps
    of just those rows (a stage's memory is its chunk, not the array); it grows along its first
    axis in place (numpy's headers leave room for the longer shape)."""

    def __init__(self, path: Path):
        self.path = Path(path)
        with open(self.path, "rb") as f:
            if np.lib.format.read_magic(f) != (1, 0):
                raise WorkError(f"{self.path}: not a work array (.npy version 1.0)")
            shape, fortran, self.dtype = np.lib.format.read_array_header_1_0(f)
            self.offset = f.tell()
        self.shape = tuple(shape)
        self.row_bytes = int(np.prod(self.shape[1:], dtype=np.int64)) * self.dtype.itemsize

    @classmethod
    def create(cls, path: Path, dtype: np.dtype | type, row_shape: tuple[int, ...] = (), rows: int = 0) -> WorkArray:
        """A new array of ``rows`` zero rows at ``path`` (replacing any file there by a new one: a database
        holding a hard link to the old one keeps it; sparse on disk)."""
        Path(path).unlink(missing_ok=True)
        with open(path, "wb") as f:
            _write_header(f, np.dtype(dtype), (rows, *row_shape))
            f.truncate(f.tell() + rows * int(np.prod(row_shape, dtype=np.int64)) * np.dtype(dtype).itemsize)
        return cls(path)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, rows: slice) -> np.ndarray:
        """Rows ``start:stop`` as a writable array mapped on the file (step 1 only)."""
        start, stop, step = rows.indices(len(self))
        if step != 1:
            raise IndexError("work arrays are read by contiguous row ranges")
        count = max(stop - start, 0)
        if count == 0:
            return np.empty((0, *self.shape[1:]), self.dtype)
        return np.asarray(np.memmap(self.path, self.dtype, "r+", self.offset + start * self.row_bytes,
                                    (count, *self.shape[1:])))

    def __setitem__(self, rows: slice, values: np.ndarray) -> None:
        """Write rows ``start:stop``."""
        self[rows][...] = values

    def take(self, indices: np.ndarray, axis: int = 0) -> np.ndarray:
        """A copy of the rows at ``indices`` (a sample), read row by row: no map of the whole file
        (``axis`` 0 only, as numpy's ``take`` is called on rows)."""
        if axis != 0:
            raise IndexError("work arrays are taken by rows (axis 0)")
        out = np.empty((len(indices), *self.shape[1:]), self.dtype)
        flat = out.reshape(len(indices), -1).view(np.uint8)
        with open(self.path, "rb") as f:
            for i, row in enumerate(np.asarray(indices, dtype=np.int64)):
                f.seek(self.offset + int(row) * self.row_bytes)
                f.readinto(flat[i])
        return out

    def write_at(self, row: int, column: int, values: np.ndarray) -> None:
        """Write ``values [m]`` into row ``row`` from column ``column`` on (a stretch of one row of a
        ``[rows, columns]`` array; nothing else is mapped)."""
        values = np.ascontiguousarray(values, dtype=self.dtype)
        fd = os.open(self.path, os.O_WRONLY)
        try:
            os.pwrite(fd, values.tobytes(), self.offset + row * self.row_bytes + column * self.dtype.itemsize)
        finally:
            os.close(fd)

    def put(self, rows: np.ndarray, values: np.ndarray) -> None:
        """Write ``values`` at the scattered ``rows`` (the whole file mapped while it writes)."""
        mapped = np.memmap(self.path, self.dtype, "r+", self.offset, self.shape)
        mapped[np.asarray(rows)] = values
        mapped.flush()
        del mapped

    def append(self, values: np.ndarray) -> None:
        """Add ``values [m, *row_shape]`` after the last row."""
        values = np.ascontiguousarray(values, dtype=self.dtype)
        if values.shape[1:] != self.shape[1:]:
            raise ValueError(f"{self.path.name}: rows of shape {values.shape[1:]}, expected {self.shape[1:]}")
        with open(self.path, "r+b") as f:
            f.seek(self.offset + len(self) * self.row_bytes)
            f.write(values.tobytes())
        self.resize(len(self) + len(values))

    def resize(self, rows: int) -> None:
        """Keep the first ``rows`` rows (dropping what an interrupted append left) or add zero rows."""
        shape = (rows, *self.shape[1:])
        with open(self.path, "r+b") as f:
            _write_header(f, self.dtype, shape)
            if f.tell() != self.offset:
                raise WorkError(f"{self.path}: the header of shape {shape} does not fit in place")
            f.truncate(self.offset + rows * self.row_bytes)
        self.shape = shape

    def sync(self) -> None:
        """Make the rows written so far durable (fsync)."""
        fd = os.open(self.path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _write_header(f, dtype: np.dtype, shape: tuple[int, ...]) -> None:
    f.seek(0)
    np.lib.format.write_array_header_1_0(f, {"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False,
                                            "shape": shape})


class WorkFolder:
    """The work folder of one build, locked while open (``with``): its state and its arrays.

    ``fingerprints`` maps each stage of :data:`STAGES` to what its result depends on (options,
    source files); a stage whose fingerprint, or an earlier stage's, differs from the recorded one
    starts again, and so do all after it. ``restart`` starts every stage again.
    """

    def __init__(self, path: Path, fingerprints: dict[str, dict], restart: bool = False):
        self.path = Path(path)
        self.fingerprints = json.loads(json.dumps(fingerprints))  # as the state file gives them back
        self.restart = restart
        self.state: dict = {}
        self.notes: list[str] = []  # what was found and done, for the build's summary
        self._lock: TextIO | None = None   # both while the folder is open (the with statement)
        self._saver: ThreadPoolExecutor | None = None
        self._saves: list[Future] = []
        self.last_commit = time.monotonic()  # when commit() was last called

    def __enter__(self) -> WorkFolder:
        if self.path.is_dir() and any(self.path.iterdir()) and not (self.path / LOCK_FILE).is_file():
            raise WorkError(f"{self.path}: exists and is not a build's work folder (no {LOCK_FILE} file); "
                            "choose another --work-dir")
        self.path.mkdir(parents=True, exist_ok=True)
        lock = open(self.path / LOCK_FILE, "a")
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            lock.close()
            raise WorkError(f"{self.path}: another build is using this work folder") from None
        self._lock = lock
        self.state = self._load()
        self._saver = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mocapdb-work-state")
        return self

    def __exit__(self, *exc) -> None:
        try:
            self.wait()
        finally:
            lock, saver = self._opened()
            saver.shutdown()
            lock.close()

    def _opened(self) -> tuple[TextIO, ThreadPoolExecutor]:
        """The lock file and the state's saver of the open folder."""
        if self._lock is None or self._saver is None:
            raise RuntimeError(f"{self.path}: the work folder is not open (use it in a with statement)")
        return self._lock, self._saver

    def _load(self) -> dict:
        fresh = {"format": WORK_FORMAT, "fingerprints": self.fingerprints, "stages": {}}
        file = self.path / STATE_FILE
        if self.restart or not file.is_file():
            return fresh
        try:
            state = json.loads(file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            self.notes.append(f"unreadable {file} ({exc}): started again")
            return fresh
        if not (isinstance(state, dict) and state.get("format") == WORK_FORMAT
                and isinstance(state.get("fingerprints"), dict) and isinstance(state.get("stages"), dict)):
            return fresh
        for i, stage in enumerate(STAGES):
            if state["fingerprints"].get(stage) != self.fingerprints[stage]:
                kept = {s: state["stages"][s] for s in STAGES[:i] if s in state["stages"]}
                if stage in state["stages"]:
                    self.notes.append(f"the {stage} stage and those after it started again: its options or "
                                      "sources changed")
                return {**fresh, "stages": kept}
        return state

    def record(self, stage: str) -> dict:
        """The stage's record (its progress; ``done`` once complete), created empty."""
        return self.state["stages"].setdefault(stage, {})

    def commit(self, *arrays: WorkArray) -> None:
        """Save the state as it is now, atomically, once ``arrays`` are durable (fsync): the state
        never claims rows that are not on disk. Done on a background thread, in order, while the
        build goes on (the disk writes while the processors compute); a failed save is raised here
        next time or by :meth:`wait`."""
        self.last_commit = time.monotonic()
        for done in [s for s in self._saves if s.done()]:
            self._saves.remove(done)
            done.result()
        self._saves.append(self._opened()[1].submit(self._save, arrays, json.dumps(self.state, indent=1)))

    def _save(self, arrays: tuple[WorkArray, ...], state: str) -> None:
        for array in arrays:
            array.sync()
        write_atomic(self.path / STATE_FILE, state)

    def wait(self) -> None:
        """Wait for the saves under way (raising the first that failed)."""
        saves, self._saves = self._saves, []
        for save in saves:
            save.result()

    def array(self, name: str) -> WorkArray:
        """The folder's array ``name`` (``<name>.npy``)."""
        return WorkArray(self.path / f"{name}.npy")

    def new_array(self, name: str, dtype: np.dtype | type, row_shape: tuple[int, ...] = (),
                  rows: int = 0) -> WorkArray:
        """A new array ``name`` of ``rows`` zero rows (replacing one of that name)."""
        return WorkArray.create(self.path / f"{name}.npy", dtype, row_shape, rows)

    def save(self, name: str, values: np.ndarray) -> None:
        """A small array (centroids, representatives) saved whole, durably and atomically."""
        tmp = self.path / f".{name}.tmp.npy"
        with open(tmp, "wb") as f:
            np.save(f, values)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path / f"{name}.npy")

    def load(self, name: str) -> np.ndarray:
        """An array saved by :meth:`save`."""
        return np.load(self.path / f"{name}.npy")

    def size_bytes(self) -> int:
        """Bytes the folder's files take on disk (sparse files count what they hold); a file a save
        under way renames meanwhile (its temporary) is not counted."""
        total = 0
        for file in self.path.iterdir():
            try:
                status = file.stat()
            except FileNotFoundError:
                continue
            total += status.st_blocks * 512 if stat.S_ISREG(status.st_mode) else 0
        return total

    def remove(self) -> None:
        """Delete the folder, once no save is under way."""
        saves, self._saves = self._saves, []
        for save in saves:
            save.exception()
        shutil.rmtree(self.path, ignore_errors=True)
