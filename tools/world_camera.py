"""The world's camera against a calibration on any keypoint folders (e.g. BlazePose's from `mocapdb
detect`), each camera run alone: the table and summary `mocapdb eval --real-take` prints for the
take's own OpenPose keypoints (`mocapdb/evaluation/world_camera.py`).

    for c in 01 02 03 04; do
        .venv/bin/mocapdb detect ../shared/data/videos/pose2sim_balancing/cam$c.mp4 --out kp/cam$c; done
    .venv/bin/python tools/world_camera.py --db demo/sample.db \\
        --calibration ../shared/data/pose2sim_balancing/calibration.toml --fps 60 \\
        cam_01=kp/cam01 cam_02=kp/cam02 cam_03=kp/cam03 cam_04=kp/cam04
"""
from __future__ import annotations

import argparse
from pathlib import Path

from mocapdb.core.cameras import read_calibration_toml
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.evaluation.real_take import focal_px
from mocapdb.evaluation.world_camera import camera_checks, format_rows, score_camera, summary_lines, world_of_frames
from mocapdb.runtime.engine_config import EngineConfig


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", required=True, help="the motion database (Parquet folder)")
    parser.add_argument("--calibration", required=True, type=Path, help="a Pose2Sim calibration.toml (z up, metres)")
    parser.add_argument("--fps", type=float, required=True, help="the keypoints' frame rate (Hz)")
    parser.add_argument("cameras", nargs="+", metavar="NAME=FOLDER", help="a calibration camera and its keypoints")
    args = parser.parse_args()
    cams = read_calibration_toml(args.calibration)
    db = load_database(args.db)
    scores = {}
    for spec in args.cameras:
        name, _, folder = spec.partition("=")
        if name not in cams or not folder:
            parser.error(f"{spec}: expected NAME=FOLDER with NAME one of {', '.join(sorted(cams))}")
        cam = cams[name]
        config = EngineConfig(fps=args.fps, focal_px=focal_px(cam), image_size=(cam.size[0], cam.size[1]))
        frames = list(read_openpose_folder(Path(folder), fps=args.fps))
        scores[name] = score_camera(world_of_frames(db, frames, config), cam)
    print("\n".join(format_rows(scores) + [""] + summary_lines(scores) + camera_checks(scores)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
