"""The scene's lines of a video, written into its keypoint folder as `mocapdb detect` writes them
(``scene.json``: `mocapdb/detect/scene.py`), for keypoint folders detected before detect wrote them.
The people's boxes come from the folder's keypoint files (any folder `reconstruct` reads: frame
numbers in the files, else their order, are taken as the video's frame numbers).

    .venv/bin/python tools/scene_lines.py ../shared/data/videos/pose2sim_balancing/cam01.mp4 kp/cam01
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.formats.openpose import read_openpose_folder  # noqa: E402
from mocapdb.core.formats.take import read_take
from mocapdb.detect.scene import SceneSampler
from mocapdb.detect.video import VideoReader


def people_by_frame(folder: Path) -> dict[int, np.ndarray]:
    """Each frame's people ``[P, 14, 3]`` (x px, y px, confidence) by frame number, as
    ``reconstruct`` reads the folder (its files in frame order, numbered by their own ``frame``)."""
    return {frame.index: np.array([np.column_stack([np.nan_to_num(p.points_px), p.confidence]) for p in frame.people]
                                   ).reshape(-1, 14, 3) for frame in read_openpose_folder(folder)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("keypoints", type=Path, help="the video's keypoint folder (mocapdb detect's output)")
    args = parser.parse_args()
    take = read_take(args.keypoints)
    seen = people_by_frame(args.keypoints)
    reader = VideoReader(str(args.video))
    sampler = SceneSampler(take.fps if take and take.fps else reader.fps)
    spent, sampled = 0.0, 0
    try:
        for frame in reader.frames():
            start = time.perf_counter()
            before = len(sampler.frames)
            sampler.see(frame.index, frame.image, seen.get(frame.index, np.zeros((0, 14, 3))))
            if len(sampler.frames) != before:
                spent, sampled = spent + time.perf_counter() - start, sampled + 1
    finally:
        reader.close()
    print("\n".join(sampler.finish(args.keypoints)))
    print(f"{1000 * spent / max(sampled, 1):.1f} ms a sampled frame, {1000 * spent / max(reader.frames_read, 1):.2f} "
          f"ms a frame of the video ({reader.frames_read} frames)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
