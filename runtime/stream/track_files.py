"""A session's track files (:class:`TrackFiles`): which tracks get files (not static, long enough,
within ``--max-bvh-files``), parts and checkpoints, the whole-take fit and the shared floor with
``world.json``, removal, and, in ``live``, a writer thread of their own whose errors the session's
thread raises."""
from __future__ import annotations

import json
import logging
import queue
import threading
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from mocapdb.core.exports import write_track_files
from mocapdb.core.files import write_atomic
from mocapdb.core.outputs import TrackRecording
from mocapdb.runtime.stream.session_options import SessionOptions
from mocapdb.runtime.stream.session_summary import SessionSummary
from mocapdb.runtime.take import fit_take
from mocapdb.runtime.world.camera_path import camera_path_line, camera_path_record
from mocapdb.runtime.world.fuse import fit_take_world
from mocapdb.runtime.world.subject import chosen, main_track
from mocapdb.runtime.world.summary import track_facts, world_line, world_record

LOG = logging.getLogger(__name__)

# A writer thread's job: an operation and its arguments; None ends the thread
WriteJob = tuple[Callable[..., object], tuple[object, ...]]


def track_stem(track: int, part: int | None) -> str:
    """``track_<id>``, or ``track_<id>_part<k>`` for part k (from 1) of a split track: the name of
    its files without the format's suffix."""
    return f"track_{track}" if part is None else f"track_{track}_part{part}"


class TrackFiles:
    """The session's BVH files within its limits (:class:`SessionOptions`). Without a folder yet,
    recordings wait for :meth:`flush` (at most ``max_bvh_files`` of them).

    With ``write_in_background`` (live), every file operation (a whole-take fit and its files, a
    removal) runs in order on one writer thread, so a long track's fit (~2 s for a 10-minute part)
    does not hold up the stream; the first error it meets is raised by the next operation or by
    :meth:`drain`."""

    def __init__(self, options: SessionOptions, fps: float, summary: SessionSummary):
        self.options, self.fps, self.summary = options, fps, summary
        self.part_frames = max(round(options.bvh_part_min * 60.0 * fps), 1)
        self._names: set[str] = set()  # written or waiting
        self._paths: set[Path] = set()  # written
        self._waiting: list[tuple[TrackRecording, str]] = []
        self._held: list[tuple[TrackRecording, str]] = []  # final files held for the shared floor
        self._still: list[TrackRecording] = []  # static tracks: no files, but evidence of the shared floor
        self._jobs: queue.Queue[WriteJob | None] | None = None
        self._writer: threading.Thread | None = None
        self._error: BaseException | None = None

    def ended(self, rec: TrackRecording) -> None:
        """A track ended: its file (or last part), unless static or too short."""
        name = track_stem(rec.track, rec.part + 1 if rec.part else None)
        if rec.static:
            self.summary.add_static(rec.track)
        if rec.static and not self.options.keep_static:
            self._remove(name)  # a checkpoint written while it was open
            if self._sharing_floor(rec):
                self._still.append(rec)
        elif not rec.part and self._short(rec):
            self.summary.limits.short_tracks += 1
        else:
            self._write(rec, name, final=True)

    def cut(self, rec: TrackRecording) -> None:
        """A full part of an open track (``Engine.cut_recordings``); part 1 replaces its checkpoint."""
        if not rec.part:
            self._remove(track_stem(rec.track, None))
        if self.options.keep_static or not rec.static:
            self._write(rec, track_stem(rec.track, rec.part + 1), final=True)

    def checkpoint(self, recordings: list[TrackRecording]) -> None:
        """The open tracks' files so far (long enough, not static, within the file limit)."""
        for rec in recordings:
            if (rec.part or not self._short(rec)) and not rec.static:
                self._write(rec, track_stem(rec.track, rec.part + 1 if rec.part else None), final=False)

    def _short(self, rec: TrackRecording) -> bool:
        return rec.duration_s(self.fps) < self.options.min_track_s - 1e-9

    def flush(self) -> None:
        """Write the recordings that waited for a folder, then those held for the shared floor (all
        on one floor)."""
        self.drain()
        waiting, self._waiting = self._waiting, []
        for rec, name in waiting:
            self._save(rec, name)
        held, self._held = self._held, []
        still, self._still = self._still, []
        if held:
            self._write_world(held, still)

    def _write_world(self, held: list[tuple[TrackRecording, str]], still: list[TrackRecording]) -> None:
        """The held recordings and the static ones as one take: fragments of one person joined, one
        world, its subject (a moving track); the files of the tracks ``--people`` asks for (static ones
        get none), the summary's lines and ``world.json``."""
        if self.options.take is None:
            raise RuntimeError("recordings held for the shared floor without a whole-take fit (options.take)")
        names = {rec.track: name for rec, name in held}
        recordings, fitted, world, joined = fit_take_world([rec for rec, _ in held] + still, self.fps,
                                                           self.options.take, self.options.camera_height_m,
                                                           self.options.subject_heights_m, self.options.scene)
        filed = [rec for rec in recordings if rec.track in names]   # with their input keypoints
        main = main_track(filed, 2.0 * filed[0].camera_px[1] if filed[0].camera_px else 1.0)
        written = {rec.track for rec in chosen(filed, self.options.people, main)}
        facts = [track_facts(rec, world, self.fps) for rec in fitted]
        self.summary.world_lines = [world_line(world)] + [
            f.line(f.track == main, f.track in written, "--people" if f.track in names else "static")
            for f in facts]
        self.summary.world_lines += [f"track {track} joined into track {into} (one person lost and found again)"
                                     for track, into in joined.items()]
        path = self.options.camera_path
        if path is not None:
            self.summary.world_lines.append(camera_path_line(path))
        for rec in fitted:
            if rec.track in written:
                self._write_files(rec, names.pop(rec.track))
        for name in names.values():
            self._names.discard(name)
        if self.options.bvh_dir is not None:
            record = world_record(world, facts, main, written, joined, self.options.export.floor)
            if path is not None:
                record["camera_path"] = camera_path_record(path, world, self.options.export.floor)
            write_atomic(Path(self.options.bvh_dir) / "world.json", json.dumps(record, indent=1) + "\n")

    def _write(self, rec: TrackRecording, name: str, final: bool) -> None:
        limit = self.options.max_bvh_files
        if name not in self._names and limit and len(self._names) >= limit:
            if final:
                self._refuse()
        elif final and self._sharing_floor(rec):
            self._names.add(name)
            self._held.append((rec, name))
        elif self.options.bvh_dir is None:
            self._names.add(name)
            self._waiting.append((rec, name))
        else:
            self._names.add(name)
            queued = self.options.write_in_background and not final  # an open track records on meanwhile
            self._run(self._save, rec.snapshot() if queued else rec, name, final)

    def _sharing_floor(self, rec: TrackRecording) -> bool:
        return self.options.shared_floor and self.options.take is not None and len(rec.column("keypoints")) > 0

    def _save(self, rec: TrackRecording, name: str, final: bool = True) -> None:
        """``rec``'s files: the whole take when kept. A checkpoint (not ``final``: the live loop waits
        for it) leaves out the whole take's re-fit to the image, its costliest step."""
        if self.options.take is not None and len(rec.column("keypoints")):
            params = self.options.take if final else replace(self.options.take, refit_prior=0.0)
            rec, _ = fit_take(rec, self.fps, params)
        self._write_files(rec, name)

    def _write_files(self, rec: TrackRecording, name: str) -> None:
        if self.options.bvh_dir is None:
            raise RuntimeError(f"no folder (options.bvh_dir) to write {name}'s files in")
        paths = write_track_files(rec, self.options.bvh_dir, name, self.fps, self.options.export)
        self._names.add(name)
        for path in paths:
            if path not in self._paths:
                self._paths.add(path)
                self.summary.bvh_files.append(path)

    def _run(self, operation: Callable[..., object], *args: object) -> None:
        """``operation(*args)`` now, or queued for the writer thread (``write_in_background``)."""
        if not self.options.write_in_background:
            operation(*args)
            return
        self._raise_error()
        if self._writer is None:
            self._jobs = queue.Queue()
            self._writer = threading.Thread(target=self._write_jobs, args=(self._jobs,), name="mocapdb-track-files",
                                            daemon=True)
            self._writer.start()
        self._writer_jobs().put((operation, args))

    def _writer_jobs(self) -> queue.Queue[WriteJob | None]:
        """The writer thread's queue (made with the thread)."""
        if self._jobs is None:
            raise RuntimeError("the writer thread runs without its queue")
        return self._jobs

    def _write_jobs(self, jobs: queue.Queue[WriteJob | None]) -> None:
        """The writer thread: queued operations in order until ``None``; after an error, the rest are
        skipped (the error is raised in the session's thread)."""
        while (job := jobs.get()) is not None:
            if self._error is None:
                try:
                    job[0](*job[1])
                except BaseException as exc:  # raised again by the session's thread
                    self._error = exc

    def drain(self) -> None:
        """Wait for the writer thread's queued operations; raise the first error it met."""
        if self._writer is not None:
            self._writer_jobs().put(None)
            self._writer.join()
            self._writer = None
        self._raise_error()

    def _raise_error(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def _remove(self, name: str) -> None:
        self._run(self._remove_now, name)

    def _remove_now(self, name: str) -> None:
        if self.options.bvh_dir is None:
            return
        for suffix in self.options.export.formats:
            path = self.options.bvh_dir / f"{name}.{suffix}"
            if path in self._paths:
                path.unlink(missing_ok=True)
                self._paths.discard(path)
                self.summary.bvh_files.remove(path)
        self._names.discard(name)

    def _refuse(self) -> None:
        self.summary.limits.over_max_files += 1
        if self.summary.limits.over_max_files == 1:
            LOG.warning("--max-bvh-files %d reached: further tracks get no file (their frames stay in the stream)",
                        self.options.max_bvh_files)
