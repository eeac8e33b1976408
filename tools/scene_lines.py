"""The scene's lines of a video, written into its keypoint folder as `mocapdb detect` writes them
(``scene.json``: `mocapdb/detect/scene.py`), for keypoint folders detected before detect wrote them.
The people's boxes come from the folder's keypoint files (``<stem>_<frame>_keypoints.json``).

    .venv/bin/python tools/scene_lines.py ../shared/data/videos/pose2sim_balancing/cam01.mp4 kp/cam01
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.formats.take import read_take
from mocapdb.detect.openpose_out import frame_file_name
from mocapdb.detect.scene import SceneSampler
from mocapdb.detect.video import VideoReader


def people(folder: Path, stem: str, index: int) -> np.ndarray:
    """The people ``[P, K, 3]`` of a frame's keypoint file (none when it is missing)."""
    path = folder / frame_file_name(stem, index)
    if not path.exists():
        return np.zeros((0, 1, 3))
    rows = [np.asarray(p["pose_keypoints_2d"], dtype=np.float64).reshape(-1, 3)
            for p in json.loads(path.read_text())["people"]]
    return np.stack(rows) if rows else np.zeros((0, 1, 3))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("video", type=Path)
    parser.add_argument("keypoints", type=Path, help="the video's keypoint folder (mocapdb detect's output)")
    args = parser.parse_args()
    take = read_take(args.keypoints)
    reader = VideoReader(str(args.video))
    sampler = SceneSampler(take.fps if take and take.fps else reader.fps)
    spent, sampled = 0.0, 0
    try:
        for frame in reader.frames():
            start = time.perf_counter()
            before = len(sampler.frames)
            sampler.see(frame.index, frame.image, people(args.keypoints, reader.name, frame.index))
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
