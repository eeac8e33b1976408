"""Benchmark the runtime: throughput, clustered vs exact search, live latency with 4 people, start-up.

    python tools/bench_runtime.py --db eval.db [--heldout ../shared/data/cmu_bvh/007_*.bvh] [--no-exact]

* throughput: person-frames/s of ``Engine.step`` (parsed keypoints to smoothed skeleton, one
  thread) with the 2D refinement (default; also without the own-body estimate, and keeping the
  per-frame fits for the whole take) and without (``--no-refine``: the method as published), and
  exact search without refinement, on held-out clips rendered from off-grid yaws; and the
  whole-take fit's person-frames/s over the tracks recorded;
* search: recall@1 of the clustered search against exact search and the time of each;
* live: 4 people per frame streamed at 30 fps over TCP on loopback into the live loop;
  latency p50/p99 from a message's arrival to the sink's send of its output line;
* track files in live: one person for 3,000 frames in 2,000-frame parts (a part's whole-take fit
  written when it completes): the slowest frame of the loop with the files written in it and on
  live's writer thread;
* start-up: from launching ``mocapdb live --source -`` to its first output frame.
"""
from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.core.formats.keypoints import KeypointFrame  # noqa: E402
from mocapdb.evaluation.heldout import Scenario, load_heldout, render, view_of  # noqa: E402
from mocapdb.evaluation.reconstruction import search_benchmark  # noqa: E402
from mocapdb.runtime.engine import Engine  # noqa: E402
from mocapdb.runtime.engine_config import EngineConfig  # noqa: E402
from mocapdb.runtime.stream.session import FrameParser, Session, run_live  # noqa: E402
from mocapdb.runtime.stream.session_options import SessionOptions  # noqa: E402
from mocapdb.runtime.stream.session_summary import SessionSummary  # noqa: E402
from mocapdb.runtime.stream.transport import StreamStats, open_sink, open_source  # noqa: E402
from mocapdb.runtime.take_params import TakeParams  # noqa: E402
from mocapdb.runtime.world.fuse import fit_world  # noqa: E402

DEFAULT_HELDOUT = sorted((ROOT.parent / "shared" / "data" / "cmu_bvh").glob("007_*.bvh"))
COCO17_OF_UNIVERSAL = {0: 0, 2: 6, 3: 8, 4: 10, 5: 5, 6: 7, 7: 9, 8: 12, 9: 14, 10: 16, 11: 11, 12: 13, 13: 15}


def rendered_sequences(truths, yaws=(6.0, 96.0, 186.0, 276.0), noise_px: float = 5.0) -> list[list[KeypointFrame]]:
    rng = np.random.default_rng(0)
    scenario = Scenario("bench", noise_px=noise_px)
    return [render(view_of(t, yaw, 1.5, 5.0), scenario, 1000.0, (1920, 1080), rng) for t in truths for yaw in yaws]


def throughput(db, sequences, **options) -> tuple[float, list]:
    """Person-frames/s of ``Engine.step`` under ``EngineConfig(**options)`` and the tracks recorded."""
    config = EngineConfig(fps=24.0, **options)
    engine = Engine(db, config)
    for frame in sequences[0][:5]:
        engine.step(frame)  # compile / warm up
    engine.finish()
    n, seconds, recordings = 0, 0.0, []
    for frames in sequences:
        engine = Engine(db, config)
        start = time.perf_counter()
        for frame in frames:
            n += len(engine.step(frame))
        seconds += time.perf_counter() - start
        recordings += engine.finish()
    return n / seconds, recordings


def whole_take_speed(recordings) -> float:
    """Person-frames/s of the whole-take fit with the take's world (``runtime.world.fuse.fit_world``: each
    track's ``fit_take``, then one world for all of them) over recorded tracks, taken as one take."""
    fit_world(recordings[:1], 24.0)  # warm up
    start = time.perf_counter()
    fit_world(recordings, 24.0)
    return sum(len(r.quaternions) for r in recordings) / (time.perf_counter() - start)


def _coco_line(index: int, people_px: list[np.ndarray]) -> str:
    people = []
    for px in people_px:
        kp = np.zeros((17, 3))
        for u, c in COCO17_OF_UNIVERSAL.items():
            kp[c] = [px[u, 0], px[u, 1], 0.9]
        people.append({"keypoints": np.round(kp, 2).tolist()})
    return json.dumps({"frame": index, "layout": "coco17", "people": people})


def live_latency(db, sequences, n_people: int = 4, fps: float = 30.0, n_frames: int = 300) -> dict:
    """``n_people`` side by side per frame, sent at ``fps`` over TCP into the live loop."""
    lines = []
    for i in range(n_frames):  # each person's sequence repeats when it runs out
        people = [sequences[p][i % len(sequences[p])].people[0].points_px + [(p - 1.5) * 420.0, 0.0]
                  for p in range(n_people)]
        lines.append(_coco_line(i, people))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    summary = SessionSummary(stream=StreamStats())
    session = Session(Engine(db, EngineConfig(fps=fps)), open_sink("/dev/null", summary.stream), FrameParser(), summary)
    source = open_source(f"tcp://127.0.0.1:{port}", stats=summary.stream)
    stop = threading.Event()
    loop = threading.Thread(target=run_live, args=(session, source, stop))
    loop.start()
    with socket.create_connection(("127.0.0.1", port), timeout=5) as client:
        start = time.perf_counter()
        for i, line in enumerate(lines):
            client.sendall((line + "\n").encode())
            time.sleep(max(0.0, start + (i + 1) / fps - time.perf_counter()))
    deadline = time.monotonic() + 10
    while summary.frames + summary.stream.dropped_stale < n_frames and time.monotonic() < deadline:
        time.sleep(0.01)
    stop.set()
    loop.join()
    session.finish(None)
    lat = np.array(summary.latency.latencies_s[10:]) * 1000  # after warm-up
    return {"people": n_people, "frames_sent": n_frames, "frames_processed": summary.frames,
            "dropped_stale": summary.stream.dropped_stale, "tracks": summary.tracks,
            "latency_ms_p50": round(float(np.percentile(lat, 50)), 2),
            "latency_ms_p99": round(float(np.percentile(lat, 99)), 2)}


def part_writing_stall(db, frames: list[KeypointFrame], n_frames: int = 3000, part_frames: int = 2000) -> dict:
    """The live loop's slowest and p99 frame (ms) while one person's 2,000-frame part is fitted and
    written, in the loop and on the writer thread (``SessionOptions.write_in_background``); the
    person walks ``frames`` back and forth (no jump, so one track)."""
    period = 2 * len(frames) - 2
    walk = [frames[i % period if i % period < len(frames) else period - i % period] for i in range(n_frames)]
    report = {}
    for label, background in (("in_loop", False), ("writer_thread", True)):
        with tempfile.TemporaryDirectory() as folder:
            summary = SessionSummary(stream=StreamStats())
            options = SessionOptions(bvh_dir=Path(folder), bvh_part_min=part_frames / 24.0 / 60.0, take=TakeParams(),
                                     checkpoint_s=1e9, strict=False, write_in_background=background)
            session = Session(Engine(db, EngineConfig(fps=24.0, keep_take=True)),
                              open_sink(str(Path(folder) / "out.jsonl"), summary.stream), FrameParser(), summary,
                              options)
            took = []
            for i, frame in enumerate(walk):
                start = time.perf_counter()
                session.handle_frame(KeypointFrame(i, i / 24.0, frame.people), time.monotonic())
                took.append(time.perf_counter() - start)
            session.finish()
        took_ms = np.array(took[10:]) * 1000
        report[label] = {"max_ms": round(float(took_ms.max()), 1),
                         "p99_ms": round(float(np.percentile(took_ms, 99)), 2)}
    return report


def startup(db_path: Path, line: str) -> float:
    """Seconds from launching `mocapdb live --source -` to its first output frame."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "mocapdb", "live", "--source", "-", "--db", str(db_path)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=ROOT)
    proc.stdin.write(line + "\n")
    proc.stdin.flush()
    elapsed = float("nan")
    for out in proc.stdout:
        if '"frame"' in out and '"format"' not in out:
            elapsed = time.perf_counter() - start
            break
    proc.stdin.close()
    proc.wait(timeout=30)
    return elapsed


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--db", type=Path, required=True, help="database built without the held-out clips")
    ap.add_argument("--heldout", type=Path, nargs="+", default=DEFAULT_HELDOUT, help="held-out BVH files")
    ap.add_argument("--no-exact", action="store_true",
                    help="leave out exact search (its throughput and the recall check): on a database of tens of "
                         "millions of projections it takes a quarter of a second per query; tools/bench_search.py "
                         "measures recall on a sample")
    args = ap.parse_args()
    db = load_database(args.db, projections=False)  # as `live` loads it: the poses from the search index
    truths = load_heldout(args.heldout, 24.0)
    sequences = rendered_sequences(truths)
    report = {"database_projections": db.n_projections}
    runs = {"refined": dict(), "refined, universal body (--universal-body)": dict(own_body=False),
            "refined, keeping the per-frame fits (reconstruct)": dict(keep_take=True),
            "published (--no-refine)": dict(refine=False),
            **({} if args.no_exact else {"published, exact search": dict(refine=False, search="exact")})}
    measured = {name: throughput(db, sequences, **options) for name, options in runs.items()}
    report["throughput_person_frames_per_s"] = {name: round(rate, 1) for name, (rate, _) in measured.items()}
    report["whole_take_fit_person_frames_per_s"] = round(
        whole_take_speed(measured["refined, keeping the per-frame fits (reconstruct)"][1]), 1)
    queries = [f.people[0] for seq in sequences for f in seq[::3]]
    if not args.no_exact:
        report["search"] = search_benchmark(Engine(db), queries, 0.3)
    report["live_4_people_30fps"] = live_latency(db, sequences)
    report["live_track_files_2000_frame_part"] = part_writing_stall(db, max(sequences, key=len))
    first_line = _coco_line(0, [sequences[0][0].people[0].points_px])
    report["startup_to_first_frame_s"] = round(startup(args.db, first_line), 2)
    print(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
