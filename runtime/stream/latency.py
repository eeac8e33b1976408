"""A live stream's end-to-end latency: each frame's capture → the moment its output leaves the sink.

The session notes each frame's capture time as it takes the frame (:meth:`LatencyBook.captured`: a
camera's or a video file's frame when it was decoded, a keypoint message when it arrived; seconds of
``time.monotonic()``); the sink notes the moment the frame's output left it (:meth:`LatencyBook.sent`:
after the socket send, the file write, the TCP sender thread's ``sendall``). A frame's **latency** is
its send less its capture; its **lag**, the frames the session had taken after it by then (the online
take's hold: ``--lag-frames``), in frames and in milliseconds at the stream's frame rate. The
latency includes the lag and the time a frame waited in the input buffer. As the throughput counts
from the first frame processed, the figures leave out the **start-up** frames: those captured before
the first frame's output left the sink (they waited for the models' first runs and the first frame's
compiling; counted in ``startup_frames``, and in the line). Memory stays bounded:
capture times of at most :data:`MAX_PENDING` frames not yet sent, percentiles over at most the last
``2 × MAX_SAMPLES`` frames.
"""
from __future__ import annotations

import gc
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from mocapdb.core.kernel_cache import load_cached_kernels

__all__ = ["MAX_PENDING", "MAX_SAMPLES", "LatencyBook", "steady_stream"]

MAX_PENDING = 1024       # capture times kept for frames not yet sent (the oldest forgotten beyond)
MAX_SAMPLES = 100_000    # latency percentiles cover at most the last 2 × this many frames sent


class LatencyBook:
    """Capture and send times of a stream's frames (module docstring); :meth:`sent` may be called from
    any thread (a sink's sender thread). ``fps``: the stream's frame rate (the lag's milliseconds)."""

    def __init__(self, fps: float = 0.0) -> None:
        self.fps = fps
        self.latencies_s: list[float] = []   # capture → send per frame sent, seconds
        self.lags: list[int] = []            # frames taken after it when each frame was sent
        self._pending: dict[int, float] = {}   # frame index → capture time, frames not yet sent
        self._newest: int | None = None   # the frame taken last
        self._first_sent_s: float | None = None
        self.startup_frames = 0   # frames captured before the first send, left out of the figures
        self._lock = threading.Lock()

    def captured(self, index: int, capture_s: float) -> None:
        """Frame ``index`` was captured at ``capture_s`` (``time.monotonic()`` s) and is now taken."""
        with self._lock:
            self._pending[index] = capture_s
            self._newest = index
            if len(self._pending) > MAX_PENDING:
                del self._pending[min(self._pending)]

    def sent(self, index: int, sent_s: float | None = None) -> None:
        """Frame ``index``'s output left the sink at ``sent_s`` (default now); a frame sent again or
        never taken is not counted twice."""
        sent_s = time.monotonic() if sent_s is None else sent_s
        with self._lock:
            capture_s = self._pending.pop(index, None)
            for older in [i for i in self._pending if i < index]:   # taken, never sent (e.g. not finite)
                del self._pending[older]
            if capture_s is None or self._newest is None:
                return
            if self._first_sent_s is None:
                self._first_sent_s = sent_s
            if capture_s < self._first_sent_s:
                self.startup_frames += 1
                return
            self.latencies_s.append(sent_s - capture_s)
            self.lags.append(self._newest - index)
            if len(self.latencies_s) >= 2 * MAX_SAMPLES:
                del self.latencies_s[:MAX_SAMPLES], self.lags[:MAX_SAMPLES]

    def percentiles_ms(self) -> tuple[float, float]:
        """The latency's p50 and p99 in milliseconds (NaN before any frame was sent)."""
        with self._lock:
            ms = np.array(self.latencies_s) * 1000.0
        return (float(np.percentile(ms, 50)), float(np.percentile(ms, 99))) if len(ms) else (float("nan"),) * 2

    def lag(self) -> tuple[float, float]:
        """The stream's lag: the median frames taken after a frame before it was sent, and that in
        milliseconds at ``fps`` (NaN before any frame was sent; ms NaN without a frame rate)."""
        with self._lock:
            frames = float(np.median(self.lags)) if self.lags else float("nan")
        return frames, frames * 1000.0 / self.fps if self.fps > 0 else float("nan")

    def line(self) -> str:
        """``latency capture → send p50 A ms, p99 B ms (N frames, S start-up frames left out); lag L frames
        (M ms at F fps)``."""
        p50, p99 = self.percentiles_ms()
        frames, ms = self.lag()
        return (f"latency capture → send p50 {p50:.2f} ms, p99 {p99:.2f} ms ({len(self.latencies_s)} frames, "
                f"{self.startup_frames} start-up frames left out); lag {frames:g} frames ({ms:.1f} ms at "
                f"{self.fps:g} fps)")


@contextmanager
def steady_stream() -> Iterator[None]:
    """Around a live stream, once its session and detector are made: mocapdb's cached kernels loaded before
    the first frame (:func:`~mocapdb.core.kernel_cache.load_cached_kernels`: their first calls held up the
    first frames), and the objects of the start-up (the database, the models: about 50 ms for Python's
    oldest-generation collection to walk) set aside from the garbage collector while the stream runs
    (``gc.freeze``), so that a collection during the stream walks only what the stream made."""
    load_cached_kernels()
    gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()
