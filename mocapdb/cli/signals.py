"""Stopping long-running work cleanly on SIGINT / SIGTERM (``live``, ``detect``)."""
from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

STOPPING_NOTE = b"mocapdb: already stopping: finishing the output files; further signals are ignored\n"


@contextmanager
def install_stop_handlers(stop_event: threading.Event, force_quit: bool = True) -> Iterator[threading.Event]:
    """Within the block, SIGINT and SIGTERM set ``stop_event`` so the live loop can finish cleanly.
    Once it is set, with ``force_quit`` a further SIGINT raises KeyboardInterrupt (force quit);
    without, every further signal is ignored (one note on stderr), so work done inside the block
    (writing the BVH files) is never cut short. The previous handlers are restored on exit. Main
    thread only."""
    if threading.current_thread() is not threading.main_thread():
        raise RuntimeError("signal handlers can only be installed from the main thread")
    noted = False

    def handler(signum: int, _frame: object) -> None:
        nonlocal noted
        if not stop_event.is_set():
            stop_event.set()
        elif force_quit and signum == signal.SIGINT:
            raise KeyboardInterrupt
        elif not force_quit and not noted:
            noted = True
            os.write(2, STOPPING_NOTE)   # not print(): the handler may interrupt a write to sys.stderr

    previous: dict[signal.Signals, Callable[..., Any] | int] = {}
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            old = signal.signal(sig, handler)
            previous[sig] = signal.SIG_DFL if old is None else old
        yield stop_event
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
