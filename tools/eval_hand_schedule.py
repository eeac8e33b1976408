"""Hands at a lower rate (`live --hands-every N`) against every hand on every frame, on videos.

    python tools/eval_hand_schedule.py VIDEO [VIDEO ...] [--every 2 3] [--max-people 1] [--frames 300]

Per video, BlazePose full (``--max-people``) then the hand landmark model with every hand on every frame
(the reference: what `detect --hands` writes) and with each ``--every N``
(:mod:`mocapdb.detect.hand_schedule`), on the same decoded frames. Prints BlazePose's CPU time per frame
and per N the hands' (the process's, all threads: what the machine's other load moves least), hands run
and carried, and on the hand-frames both found, how far
the N run's hand lies from the reference (mean distance of the 21 points, % of the reference's wrist to
middle knuckle; mean and p95) and how far its fingers' curls do (degrees, the mean over the five fingers;
mean and p95); hand-frames found only by the reference or only by the N run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.fingers import curl_deg, flexion_deg  # noqa: E402
from mocapdb.detect.blazepose import BlazePose  # noqa: E402
from mocapdb.detect.hands import HandLandmarker, Hands  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path  # noqa: E402
from mocapdb.detect.video import VideoReader  # noqa: E402


def run_hands(images: list[np.ndarray], poses: list[np.ndarray], every: int) -> tuple[list[Hands], float, int, int]:
    """The hands of every frame with the model run every ``every`` frames: hands, CPU ms per frame, hands
    run, carried."""
    model = HandLandmarker(hand_landmark_path(), every)
    started = time.process_time()
    found = [model(image, pose) for image, pose in zip(images, poses)]
    return found, (time.process_time() - started) * 1000.0 / len(images), model.runs, model.schedule.carries


def differences(reference: list[Hands], got: list[Hands]) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Per hand-frame found by both: point distance (% of the wrist to middle knuckle) and mean curl
    difference (degrees); hand-frames found only by the reference, only by ``got``."""
    points, curls, only_ref, only_got = [], [], 0, 0
    for ref, hands in zip(reference, got):
        for person in range(min(len(ref.absent), len(hands.absent))):
            for side in range(2):
                in_ref, in_got = ref.absent[person][side] == "", hands.absent[person][side] == ""
                only_ref += in_ref and not in_got
                only_got += in_got and not in_ref
                if in_ref and in_got:
                    a, b = ref.points[person, side, :, :3], hands.points[person, side, :, :3]
                    length = np.linalg.norm(a[9, :2] - a[0, :2])
                    points.append(np.linalg.norm(a[:, :2] - b[:, :2], axis=1).mean() / length * 100.0)
                    curls.append(np.abs(curl_deg(flexion_deg(a)) - curl_deg(flexion_deg(b))).mean())
    return np.array(points), np.array(curls), only_ref, only_got


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("videos", nargs="+")
    ap.add_argument("--every", type=int, nargs="+", default=[2, 3], help="the rates compared (default 2 3)")
    ap.add_argument("--max-people", type=int, default=1, help="people BlazePose follows (default 1)")
    ap.add_argument("--frames", type=int, default=300, help="frames per video at most (default 300)")
    args = ap.parse_args()
    print(f"{'video':16}{'every':>6}{'hand CPU ms':>14}{'run':>6}{'carried':>8}{'compared':>9}"
          f"{'points % mean/p95':>19}{'curl deg mean/p95':>19}{'only ref':>9}{'only N':>7}")
    for video in args.videos:
        reader = VideoReader(video)
        images = [frame.image for _, frame in zip(range(args.frames), reader.frames())]
        reader.close()
        pose = BlazePose(*blazepose_paths("full"), max_people=args.max_people)
        started = time.process_time()
        poses = [pose(image).keypoints for image in images]
        print(f"{Path(video).stem:16}  BlazePose full: {(time.process_time() - started) * 1000.0 / len(images):.2f} "
              "CPU ms a frame")
        reference, ref_ms, ref_runs, _ = run_hands(images, poses, 1)
        print(f"{Path(video).stem:16}{1:6d}{ref_ms:14.2f}{ref_runs:6d}{0:8d}")
        for every in args.every:
            got, ms, runs, carried = run_hands(images, poses, every)
            points, curls, only_ref, only_got = differences(reference, got)
            print(f"{Path(video).stem:16}{every:6d}{ms:14.2f}{runs:6d}{carried:8d}{len(points):9d}"
                  f"{points.mean():10.1f} /{np.percentile(points, 95):6.1f}"
                  f"{np.nanmean(curls):10.1f} /{np.nanpercentile(curls, 95):6.1f}{only_ref:9d}{only_got:7d}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
