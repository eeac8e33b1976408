"""Benchmark video → 3D: what each step costs, end to end, for each detector and detector path.

    python tools/bench_video.py VIDEO [--blazepose lite full heavy] [--model POSE.onnx] [--db demo/sample.db]
                                [--frames 400] [--hands] [--hands-every N ...] [--hand-model full lite]
                                [--face] [--face-every N ...]
                                [--max-people N] [--repeats R]
                                [--realtime] [--mediapipe PYTHON]

BlazePose (the default detector; the variants prepared by `mocapdb models fetch lite full heavy`)
runs its person detector on a tile scan and one landmark run per person. With ``--model``, a
YOLO-pose export is measured too. POSE.onnx should be an export with a dynamic input size
(``yolo export ... dynamic=True``): the
full-frame runs feed it 640 px, the crops ``--crop-size`` px. For each configuration:

* full: the model on every whole frame at 640 px (what `detect` and `live` did before the fast path);
* crops: one crop around the people of the frame before, the whole frame every 30 frames or when
  someone is lost (``--detector crops``, live's default);
* crops + flow: as crops, the model on every 2nd frame, optical flow between (``--model-every 2``);

it prints, over one thread (decode → detect → engine step → output line, as `live` does them):
each stage's mean and p99 in ms (detection split by the path each frame took) and the frames per
second end to end; the 2D keypoints' difference from the full-frame 640 px run (mean and p95 of
the distance per keypoint, in % of the person's box height; keypoints of confidence ≥ 0.5 in both);
then the real `mocapdb live --source VIDEO --model POSE.onnx` (decoding and detection in threads of
their own): its throughput, latency p50/p99 from a frame's capture to the sink's send (and p99 in
frame times of the video) and lag. The file is read as fast as detection goes (frames queue as they
would behind a camera too fast for the machine), so the latency includes waiting in the buffers;
``--realtime``: `live --realtime`, the file delivered at its frame rate as a camera would (the
latency a camera gives; late frames dropped). Other processes on the machine slow every figure
alike: compare the ratios within one run (the load average is printed). ``--repeats R``: every run R
times, interleaved (stages pooled, frames/s the median). ``--max-people N``: each BlazePose variant (and with
``--hands`` its hands variant) also with ``--max-people N``. ``--hands-every N ...``: the hands variants
run with `live --hands-every N` for each N given (default: live's default; in one thread too); ``--hand-model
full lite``: each of them with each hand landmark model given (`live --hand-model`; default full; named ``+ hands
lite/N`` for lite).
``--face``, ``--face-every N ...``: each BlazePose variant also with `live --face --face-every N`, alike.
``--mediapipe PYTHON``: MediaPipe Pose (complexity 1) on the same frames in that Python
(tools/bench_mediapipe.py; a venv with mediapipe 0.10.21), in the same sitting: its frames/s on frames
decoded first and with decoding, and each configuration's over MediaPipe's on decoded frames.
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.cli.main import parser  # noqa: E402
from mocapdb.cli.reconstruct import _session, resolve_take  # noqa: E402
from mocapdb.detect.camera_motion import LIVE_EVERY, BackgroundMotion  # noqa: E402
from mocapdb.detect.detectors import PIPELINE_MODEL_THREADS, open_detector  # noqa: E402
from mocapdb.detect.landmark_schedule import LIVE_FACE_EVERY, LIVE_HANDS_EVERY  # noqa: E402
from mocapdb.detect.model import Detections, box_iou  # noqa: E402
from mocapdb.detect.options import DEFAULT_CONF, DEFAULT_HAND_MODEL, DEFAULT_INPUT_SIZE, DEFAULT_IOU, HAND_MODELS  # noqa: E402
from mocapdb.detect.tracked import FULL_FRAME, FastPath  # noqa: E402
from mocapdb.detect.video import VideoReader  # noqa: E402
from mocapdb.runtime.stream.video_input import keypoint_frame  # noqa: E402

WARM_UP_FRAMES = 10     # left out of the timings: onnxruntime's first runs, the engine's first frames
MIN_CONFIDENCE = 0.5    # keypoints compared: confident in both runs
MIN_IOU = 0.3           # a person of the reference run is compared with the best-overlapping one found
CPU = "CPU"             # the process's CPU time per frame, all its threads (onnxruntime's too): what the
                        # machine's other load moves least (wall-clock stages wait for a core when it is busy)
STAGES = ("decode", "detect BlazePose", "detect full", "detect crop", "detect crop+full", "flow", "camera path",
          "engine step", "output")


def configurations(crop_px: int, variants: list[str], model: str | None, hands_every: list[int] | None = None,
                   max_people: int | None = None, face_every: list[int] | None = None,
                   hand_models: tuple[str, ...] = (DEFAULT_HAND_MODEL,)) -> dict[str, tuple[FastPath, list[str]]]:
    """Name → (the detector's paths, the same as `live` options); ``hands_every``: each BlazePose variant
    also with ``--hands --hands-every N`` for each N (``+ hands/N``), ``face_every`` with ``--face
    --face-every N`` (``+ face/N``); ``max_people``: also with ``--max-people`` (and with both); ``hand_models``:
    the hands variants with each ``--hand-model`` (``+ hands lite/N`` for one not the default)."""
    size = ["--crop-size", str(crop_px)]
    people = [("", [])] + ([(f" max {max_people}", ["--max-people", str(max_people)])] if max_people else [])
    hand_variants = [(f" + hands{'' if m == DEFAULT_HAND_MODEL else ' ' + m}/{n}",
                      ["--hands", "--hands-every", str(n), "--hand-model", m])
                     for m in hand_models for n in hands_every or []]
    hand_variants += [(f" + face/{n}", ["--face", "--face-every", str(n)]) for n in face_every or []]
    extra = [(limit + hand, [*limit_flags, *hand_flags]) for limit, limit_flags in people
             for hand, hand_flags in [("", []), *hand_variants]]
    blazepose = {f"BlazePose {v}{suffix}": (FULL_FRAME, ["--blazepose", v, *flag]) for v in variants
                 for suffix, flag in extra}
    if model is None:
        return blazepose
    flags = ["--model", model]
    return blazepose | {
            "full 640": (FULL_FRAME, ["--detector", "full", *flags]),
            "crops": (FastPath(crop_px=crop_px), ["--detector", "crops", *size, *flags]),
            "crops + flow/2": (FastPath(crop_px=crop_px, model_every=2),
                               ["--detector", "crops", *size, "--model-every", "2", *flags])}


def live_args(video: str, db: str, sink: str, flags: list[str]) -> argparse.Namespace:
    """`mocapdb live` options as its parser reads them, the take resolved from the video."""
    args = parser().parse_args(["live", "--source", video, "--db", db, "--sink", sink, *flags])
    resolve_take(args, args.source)
    return args


def one_thread(args: argparse.Namespace, fast: FastPath, frames: int) -> tuple[dict, list[Detections], float]:
    """Decode → detect → engine step → output line in one thread: milliseconds per stage (and the
    process's CPU time per frame, :data:`CPU`), the detections of every frame and the frames per second
    over the timed frames."""
    detector = open_detector(args.model, args.blazepose, conf=DEFAULT_CONF, iou=DEFAULT_IOU,
                             max_people=args.max_people, input_size=DEFAULT_INPUT_SIZE, fast=fast, hands=args.hands,
                             hands_every=args.hands_every, hand_model=args.hand_model, faces=args.face,
                             face_every=args.face_every, model_threads=PIPELINE_MODEL_THREADS)
    session = _session(args, args.sink, strict=False)
    engine_ms: list[float] = []
    step = session.engine.step

    def timed_step(*a, **k):
        started = time.perf_counter()
        try:
            return step(*a, **k)
        finally:
            engine_ms.append((time.perf_counter() - started) * 1000.0)

    session.engine.step = timed_step
    reader = VideoReader(args.source)
    motion = BackgroundMotion(history=False, every=LIVE_EVERY)   # the camera's path, as live measures it
    stages: dict[str, list[float]] = defaultdict(list)
    found_all: list[Detections] = []
    frame_iter = reader.frames()
    wall = 0.0
    for i in range(frames):
        t0, cpu0 = time.perf_counter(), time.process_time()
        frame = next(frame_iter, None)
        if frame is None:
            break
        t1 = time.perf_counter()
        found = detector(frame.image)
        t2 = time.perf_counter()
        motion.see(i, frame.image, found.keypoints)
        t_path = time.perf_counter()
        session.handle_frame(keypoint_frame(frame, found, detector.keypoint_layout), frame.capture_s)
        t3 = time.perf_counter()
        found_all.append(found)
        if i >= WARM_UP_FRAMES:
            last_path = getattr(detector, "last_path", "BlazePose")
            path = "flow" if last_path == "flow" else f"detect {last_path}"
            stages["decode"].append((t1 - t0) * 1000.0)
            stages[path].append((t2 - t1) * 1000.0)
            stages["camera path"].append((t_path - t2) * 1000.0)
            stages["engine step"].append(engine_ms[-1])
            stages["output"].append((t3 - t_path) * 1000.0 - engine_ms[-1])
            stages[CPU].append((time.process_time() - cpu0) * 1000.0)
            wall += t3 - t0
    session.finish()
    reader.close()
    return stages, found_all, len(stages["decode"]) / wall


def keypoint_difference(reference: list[Detections], found: list[Detections]) -> np.ndarray:
    """Per keypoint compared: its distance from the reference run's, % of the reference box height."""
    out = []
    for ref, got in zip(reference, found):
        if not len(ref.scores) or not len(got.scores):
            continue
        overlap = box_iou(ref.boxes, got.boxes)
        for r, g in enumerate(overlap.argmax(axis=1)):
            if overlap[r, g] < MIN_IOU:
                continue
            seen = (ref.keypoints[r, :, 2] >= MIN_CONFIDENCE) & (got.keypoints[g, :, 2] >= MIN_CONFIDENCE)
            height = ref.boxes[r, 3] - ref.boxes[r, 1]
            out.append(np.linalg.norm(ref.keypoints[r, seen, :2] - got.keypoints[g, seen, :2], axis=-1) / height)
    return np.concatenate(out) * 100.0 if out else np.zeros(0)


def live_run(video: str, db: str, flags: list[str], sink: str) -> dict[str, float]:
    """The real `mocapdb live --source VIDEO [flags]` (a subprocess): its summary's figures (latency in ms)."""
    command = [sys.executable, "-m", "mocapdb", "-q", "live", "--source", video, "--db", db, "--sink", sink, *flags]
    err = subprocess.run(command, capture_output=True, text=True, check=True, cwd=ROOT).stderr
    latency = re.search(r"latency capture → send p50 ([\d.]+) ms, p99 ([\d.]+) ms \(\d+ frames[^)]*\); "
                        r"lag ([\d.]+) frames \(([\d.]+) ms at [\d.]+ fps\); throughput ([\d.]+) frames/s", err)
    video_line = re.search(r"frames read (\d+), detected (\d+), dropped (\d+); detection ([\d.]+) frames/s", err)
    if latency is None or video_line is None:
        raise RuntimeError(f"unexpected summary from {' '.join(command)}:\n{err}")
    return {"p50": float(latency[1]), "p99": float(latency[2]), "lag": float(latency[3]), "lag_ms": float(latency[4]),
            "fps": float(latency[5]),
            "read": int(video_line[1]), "dropped": int(video_line[3]), "detect_fps": float(video_line[4])}


def mediapipe_run(python: str, video: str, frames: int, repeats: int) -> tuple[float, float, float]:
    """MediaPipe Pose's median frames/s (frames decoded first, decoding on the same thread) and CPU ms
    per decoded frame (all its threads) from tools/bench_mediapipe.py run by ``python``."""
    command = [python, str(ROOT / "tools" / "bench_mediapipe.py"), video, "--frames", str(frames),
               "--repeats", str(repeats)]
    out = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    found = re.search(r"mediapipe decoded ([\d.]+) frames/s, with decoding ([\d.]+) frames/s; CPU ([\d.]+) ms", out)
    if found is None:
        raise RuntimeError(f"unexpected output from {' '.join(command)}:\n{out}")
    return float(found[1]), float(found[2]), float(found[3])


def pooled(runs: list[tuple[dict, float]]) -> tuple[dict, float]:
    """Repeated one-thread runs as one: each stage's milliseconds pooled, the median frames/s."""
    stages: dict[str, list[float]] = defaultdict(list)
    for run_stages, _ in runs:
        for stage, ms in run_stages.items():
            stages[stage] += ms
    return stages, float(np.median([fps for _, fps in runs]))


def median_live(rows: list[dict[str, float]]) -> dict[str, float]:
    """Repeated `mocapdb live` runs as one: the median of each figure."""
    return {key: type(rows[0][key])(np.median([row[key] for row in rows])) for key in rows[0]}


def stage_table(results: dict[str, tuple[dict, float]]) -> list[str]:
    """One row per stage: mean / p99 ms of each configuration."""
    names = list(results)
    rows = [f"{'stage (ms: mean / p99)':24}" + "".join(f"{n:>22}" for n in names)]
    for stage in STAGES:
        cells = []
        for name in names:
            ms = np.array(results[name][0].get(stage, []))
            cells.append(f"{ms.mean():8.2f} / {np.percentile(ms, 99):6.2f} ({len(ms):3d})" if len(ms) else "-")
        rows.append(f"{stage:24}" + "".join(f"{c:>22}" for c in cells))
    rows.append(f"{'end to end, frames/s':24}" + "".join(f"{results[n][1]:>22.1f}" for n in names))
    rows.append(f"{'CPU ms/frame, all threads':24}" + "".join(f"{np.mean(results[n][0][CPU]):>22.2f}" for n in names))
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("video")
    ap.add_argument("--model", help="also a YOLO-pose ONNX export with a dynamic input size")
    ap.add_argument("--blazepose", nargs="*", default=["full"], metavar="VARIANT",
                    help="BlazePose variants measured (default full)")
    ap.add_argument("--db", default=str(ROOT / "demo" / "sample.db"))
    ap.add_argument("--frames", type=int, default=400, help="frames of the one-thread runs (default 400)")
    ap.add_argument("--crop-size", type=int, default=256, help="largest crop input side, pixels (default 256)")
    ap.add_argument("--hands", action="store_true", help="each BlazePose variant also with --hands (`live` frames/s "
                                                         "with hands over without)")
    ap.add_argument("--hands-every", type=int, nargs="+", metavar="N",
                    help=f"with --hands: the hands variants with `live --hands-every N` (default {LIVE_HANDS_EVERY})")
    ap.add_argument("--hand-model", nargs="+", choices=HAND_MODELS, default=[DEFAULT_HAND_MODEL], metavar="MODEL",
                    help=f"with --hands: the hands variants with each `live --hand-model` given (default "
                         f"{DEFAULT_HAND_MODEL})")
    ap.add_argument("--face", action="store_true", help="each BlazePose variant also with --face")
    ap.add_argument("--face-every", type=int, nargs="+", metavar="N",
                    help=f"with --face: the face variants with `live --face-every N` (default {LIVE_FACE_EVERY})")
    ap.add_argument("--realtime", action="store_true", help="`live --realtime`: the file at its frame rate")
    ap.add_argument("--max-people", type=int, metavar="N", help="each BlazePose variant also with --max-people N")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each configuration, interleaved (default 1)")
    ap.add_argument("--mediapipe", metavar="PYTHON",
                    help="also MediaPipe Pose in this Python (tools/bench_mediapipe.py)")
    args = ap.parse_args()
    print(f"load average before: {' '.join(f'{v:.2f}' for v in os.getloadavg())}; {os.cpu_count()} cores")
    hands_every = (args.hands_every or [LIVE_HANDS_EVERY]) if args.hands else None
    face_every = (args.face_every or [LIVE_FACE_EVERY]) if args.face else None
    configs = configurations(args.crop_size, args.blazepose, args.model, hands_every, args.max_people, face_every,
                             tuple(args.hand_model))
    realtime = ["--realtime"] if args.realtime else []
    runs: dict[str, list] = defaultdict(list)
    lives: dict[str, list] = defaultdict(list)
    detections = {}
    mediapipe = None
    with tempfile.TemporaryDirectory() as tmp:
        sink = str(Path(tmp) / "out.jsonl")
        for _ in range(args.repeats):
            for name, (fast, flags) in configs.items():
                stages, detections[name], fps = one_thread(live_args(args.video, args.db, sink, flags), fast,
                                                           args.frames)
                runs[name].append((stages, fps))
                lives[name].append(live_run(args.video, args.db, [*flags, *realtime], sink))
        if args.mediapipe:
            mediapipe = mediapipe_run(args.mediapipe, args.video, args.frames, args.repeats)
    results = {name: pooled(rows) for name, rows in runs.items()}
    live = {name: median_live(rows) for name, rows in lives.items()}
    reader = VideoReader(args.video)
    first, video_fps = next(reader.frames()).image, reader.fps or 30.0
    reader.close()
    print(f"video {args.video}: {first.shape[1]}x{first.shape[0]}, {args.frames} frames (the first "
          f"{WARM_UP_FRAMES} untimed); one thread; (n) frames per stage")
    print("\n".join(stage_table(results)))
    print(f"\n{'2D keypoints vs full 640':24}{'mean %':>10}{'p95 %':>10}{'max %':>10}{'compared':>10}")
    for name in (n for n in results if "full 640" in results and not n.startswith("BlazePose")):
        diff = keypoint_difference(detections["full 640"], detections[name])
        print(f"{name:24}{diff.mean():10.2f}{np.percentile(diff, 95):10.2f}{diff.max():10.2f}{len(diff):10d}")
    frame_ms = 1000.0 / video_fps
    print(f"\n{'mocapdb live' + (' --realtime' if args.realtime else ''):24}{'frames/s':>10}{'p50 ms':>10}"
          f"{'p99 ms':>10}{'p99 frames':>11}{'lag':>5}{'read':>8}{'dropped':>9}{'detect/s':>10}")
    for name, row in live.items():
        print(f"{name:24}{row['fps']:10.1f}{row['p50']:10.1f}{row['p99']:10.1f}{row['p99'] / frame_ms:11.2f}"
              f"{row['lag']:5g}{row['read']:8d}{row['dropped']:9d}{row['detect_fps']:10.1f}")
    print(f"(p99 frames: the p99 latency in frame times of the video, {frame_ms:.1f} ms at {video_fps:g} fps)")
    for name in (n for n in live if " + hands" in n):
        without = live[name.split(" + hands")[0]]["fps"]
        print(f"{name}: {live[name]['fps'] / without:.2f} x the frames/s without hands")
    if mediapipe is not None:
        print(f"\nMediaPipe Pose (complexity 1): {mediapipe[0]:.1f} frames/s on decoded frames, {mediapipe[1]:.1f} "
              f"with decoding, CPU {mediapipe[2]:.2f} ms a decoded frame; frames/s over MediaPipe's on decoded "
              "frames, and MediaPipe's CPU time a frame over the one thread's (decoding included):")
        for name in results:
            print(f"{name:24}one thread {results[name][1] / mediapipe[0]:.2f} x, mocapdb live "
                  f"{live[name]['fps'] / mediapipe[0]:.2f} x; CPU "
                  f"{mediapipe[2] / np.mean(results[name][0][CPU]):.2f} x")
    print(f"\nload average after: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
