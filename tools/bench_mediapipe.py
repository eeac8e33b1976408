"""MediaPipe Pose's frames per second on a video, the reference of `live`'s speed (issue 50, item 4).

    /tmp/mpvenv/bin/python tools/bench_mediapipe.py VIDEO [--frames 400] [--complexity 1] [--repeats 3]

Runs in a Python that has ``mediapipe`` (the pinned 0.10.21 wheel) and OpenCV, not mocapdb's
environment: ``python3 -m venv /tmp/mpvenv && /tmp/mpvenv/bin/pip install mediapipe==0.10.21
opencv-python-headless``. MediaPipe's legacy Pose solution (one person, tracking between frames, the
given model complexity) on the video's first ``--frames`` frames, twice per repeat: the frames decoded
first (``decoded``: BGR → RGB and the graph only), and decoding on the same thread (``with decoding``).
Prints one line per repeat and the medians: ``mediapipe decoded F frames/s, with decoding G frames/s;
CPU H ms a decoded frame`` (the process's CPU time, all threads, mean over the repeats; tools/bench_video.py
--mediapipe PYTHON reads that line).
"""
from __future__ import annotations

import argparse
import statistics
import time

import cv2
import mediapipe as mp

WARM_UP_FRAMES = 10   # left out of the timings, as in tools/bench_video.py


def decoded_frames(video: str, frames: int) -> list:
    """The first ``frames`` frames of ``video`` (BGR)."""
    capture, images = cv2.VideoCapture(video), []
    while len(images) < frames:
        ok, image = capture.read()
        if not ok:
            break
        images.append(image)
    capture.release()
    return images


def frames_per_second(images, complexity: int) -> tuple[float, float]:
    """MediaPipe Pose over ``images`` (any iterable of BGR frames): frames per second after the warm-up,
    and the process's CPU time per frame (ms, all its threads)."""
    with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=complexity) as pose:
        timed, started, cpu = 0, 0.0, 0.0
        for i, image in enumerate(images):
            if i == WARM_UP_FRAMES:
                started, cpu = time.perf_counter(), time.process_time()
            pose.process(cv2.cvtColor(image, cv2.COLOR_BGR2RGB))
            timed += i >= WARM_UP_FRAMES
        return timed / (time.perf_counter() - started), (time.process_time() - cpu) * 1000.0 / timed


def read_as_decoded(video: str, frames: int):
    """The first ``frames`` frames of ``video``, each decoded when asked for."""
    capture = cv2.VideoCapture(video)
    for _ in range(frames):
        ok, image = capture.read()
        if not ok:
            break
        yield image
    capture.release()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("video")
    ap.add_argument("--frames", type=int, default=400, help="frames per run (default 400)")
    ap.add_argument("--complexity", type=int, default=1, choices=(0, 1, 2), help="model complexity (default 1)")
    ap.add_argument("--repeats", type=int, default=3, help="runs of each kind (default 3)")
    args = ap.parse_args()
    images = decoded_frames(args.video, args.frames)
    decoded, with_decoding, cpu = [], [], []
    for repeat in range(args.repeats):
        fps, cpu_ms = frames_per_second(images, args.complexity)
        decoded.append(fps)
        cpu.append(cpu_ms)
        with_decoding.append(frames_per_second(read_as_decoded(args.video, args.frames), args.complexity)[0])
        print(f"repeat {repeat + 1}: decoded {decoded[-1]:.1f} ({cpu_ms:.2f} ms CPU a frame), with decoding "
              f"{with_decoding[-1]:.1f} frames/s ({len(images)} frames, complexity {args.complexity}, mediapipe "
              f"{mp.__version__})")
    print(f"mediapipe decoded {statistics.median(decoded):.1f} frames/s, with decoding "
          f"{statistics.median(with_decoding):.1f} frames/s; CPU {statistics.mean(cpu):.2f} ms a decoded frame")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
