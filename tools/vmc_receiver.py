"""A small receiver for what `mocapdb live --sink vmc://…` or `--sink vrchat://…` sends: listens for OSC on
UDP (python-osc's server) and prints once a second the datagrams (bundles or single messages), the
messages, the bones (VMC) or trackers (VRChat) per frame, the largest datagram, the frame rate, VMC's
OK values and the hips' position.

    .venv/bin/python tools/vmc_receiver.py --port 39539            # VMC (Ctrl-C to stop)
    .venv/bin/python tools/vmc_receiver.py --port 9000 --seconds 20  # VRChat trackers, 20 s
    .venv/bin/python tools/vmc_receiver.py --port 0 --times arrivals.txt   # any free port; each frame's arrival

``--times FILE``: one line per VMC frame, ``ARRIVAL_S T_S``: the moment (``time.monotonic()`` seconds, the
clock of `mocapdb live`'s capture times on the same machine) the datagram holding its ``/VMC/Ext/T`` arrived,
and that ``T`` (the frame's stream time, seconds): a frame's end-to-end latency seen by a receiver.

A frame ends with its `/VMC/Ext/T` (VMC) or `/tracking/trackers/head/rotation` (VRChat). The hips: VMC's
root position plus the Hips bone's local position turned by the root's rotation; VRChat's tracker 1.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import TextIO

import numpy as np
from pythonosc.dispatcher import Dispatcher
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_server import BlockingOSCUDPServer

from mocapdb.core.geometry import quat_to_matrix


@dataclass
class Second:
    """What arrived in one reporting interval."""

    bundles: int = 0
    singles: int = 0          # datagrams holding one message, not a bundle
    messages: int = 0
    max_bytes: int = 0
    frames: int = 0
    parts_per_frame: set[int] = field(default_factory=set)   # bones (VMC) or trackers (VRChat)
    ok: set[int] = field(default_factory=set)


class Tally:
    """The receiver's counts and the last hips position; with ``times`` (an open text file) each VMC
    frame's arrival and stream time."""

    def __init__(self, times: TextIO | None = None) -> None:
        self.second, self.total_frames = Second(), 0
        self.parts, self.root, self.hips_local = 0, None, None
        self.hips: np.ndarray | None = None
        self.times, self.arrival_s = times, 0.0

    def datagram(self, data: bytes) -> None:
        """Counts one datagram (before python-osc dispatches its messages) and notes when it arrived."""
        self.arrival_s = time.monotonic()
        s = self.second
        s.max_bytes = max(s.max_bytes, len(data))
        if OscBundle.dgram_is_bundle(data):
            s.bundles += 1
        else:
            s.singles += 1

    def message(self, address: str, *args) -> None:
        """Counts one message; a frame's last message closes it."""
        self.second.messages += 1
        if address == "/VMC/Ext/Bone/Pos":
            self.parts += 1
            if args[0] == "Hips":
                self.hips_local = np.array(args[1:4])
        elif address.startswith("/tracking/trackers/") and address.endswith("/position"):
            self.parts += 1
            if address == "/tracking/trackers/1/position":
                self.hips = np.array(args)
        elif address == "/VMC/Ext/Root/Pos":
            self.root = (np.array(args[1:4]), np.array([args[7], *args[4:7]]))   # position, (w, x, y, z)
        elif address == "/VMC/Ext/OK":
            self.second.ok.add(int(args[0]))
        elif address in ("/VMC/Ext/T", "/tracking/trackers/head/rotation"):
            if self.times is not None and address == "/VMC/Ext/T":
                self.times.write(f"{self.arrival_s:.6f} {args[0]:.6f}\n")
            self._frame()

    def _frame(self) -> None:
        if self.root is not None and self.hips_local is not None:
            position, quat = self.root
            self.hips = position + quat_to_matrix(quat) @ self.hips_local
        self.second.frames += 1
        self.total_frames += 1
        self.second.parts_per_frame.add(self.parts)
        self.parts, self.root, self.hips_local = 0, None, None

    def report(self, elapsed_s: float, interval_s: float) -> str:
        """One line on the interval just ended; starts the next."""
        s, self.second = self.second, Second()
        hips = "-" if self.hips is None else "(" + ", ".join(f"{v:+.3f}" for v in self.hips) + ") m"
        parts = "/".join(str(b) for b in sorted(s.parts_per_frame)) or "-"
        ok = "/".join(str(v) for v in sorted(s.ok)) or "-"
        return (f"t={elapsed_s:5.1f}s bundles {s.bundles} single messages {s.singles} messages {s.messages} "
                f"bones or trackers/frame {parts} max datagram {s.max_bytes} B frames/s {s.frames / interval_s:.1f} "
                f"OK {ok} hips {hips}")


class CountingServer(BlockingOSCUDPServer):
    """python-osc's UDP server, counting each datagram before it is dispatched."""

    def __init__(self, address: tuple[str, int], dispatcher: Dispatcher, tally: Tally) -> None:
        super().__init__(address, dispatcher)
        self.tally = tally

    def verify_request(self, request, client_address) -> bool:
        self.tally.datagram(request[0])
        return True


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default %(default)s)")
    parser.add_argument("--port", type=int, default=39539,
                        help="UDP port (default %(default)s: VMC; VRChat 9000; 0: any free one, printed)")
    parser.add_argument("--seconds", type=float, help="stop after this many seconds (default: Ctrl-C)")
    parser.add_argument("--times", metavar="FILE", help="write each VMC frame's arrival time and T (module notes)")
    args = parser.parse_args()
    times = None if args.times is None else open(args.times, "w", encoding="utf-8", buffering=1)
    tally, dispatcher = Tally(times), Dispatcher()
    dispatcher.set_default_handler(tally.message)
    server = CountingServer((args.host, args.port), dispatcher, tally)
    server.timeout = 0.05
    quat_to_matrix(np.array([1.0, 0.0, 0.0, 0.0]))   # its numba kernel loaded now, not while the first frames wait
    print(f"listening on {args.host}:{server.server_address[1]}", flush=True)
    start = last = time.monotonic()
    try:
        while args.seconds is None or time.monotonic() - start < args.seconds:
            server.handle_request()
            if (now := time.monotonic()) - last >= 1.0:
                print(tally.report(now - start, now - last), flush=True)
                last = now
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
        if times is not None:
            times.close()
    print(f"frames received {tally.total_frames}", flush=True)


if __name__ == "__main__":
    main()
