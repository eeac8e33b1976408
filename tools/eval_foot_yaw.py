"""The feet's yaw on the balancing take, each camera alone, against the 4 cameras' triangulation of BlazePose's
own heels, foot tips, hips and shoulders (issue 49, item 3; mocapdb/evaluation/foot_yaw.py).

    .venv/bin/python tools/eval_foot_yaw.py [--work /tmp/footeval] [--db demo/sample.db]

BlazePose and ``mocapdb reconstruct --rig humanoid`` run as for the head (tools/eval_head.py: its folders in
``--work`` are reused). Prints a Markdown table (docs/benchmarks.md).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from eval_head import CALIBRATION, CAMERAS, detected, reconstructed_bvh

from mocapdb.core.cameras import read_calibration_toml
from mocapdb.evaluation.foot_yaw import REFERENCE_POINTS, bvh_yaws, foot_yaws, format_table, score
from mocapdb.evaluation.head_turn import triangulated_points
from mocapdb.evaluation.real_take import focal_px


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/footeval"), help="detections and reconstructions")
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    args = parser.parse_args()
    cams = read_calibration_toml(CALIBRATION)
    folders = [detected(args.work, name) for name in CAMERAS]
    reference = foot_yaws(triangulated_points(folders, [cams[n] for n in CAMERAS], REFERENCE_POINTS))
    scores = {}
    for name, folder in zip(CAMERAS, folders):
        yaws = bvh_yaws(reconstructed_bvh(folder, args.work / f"out_{name}", args.db, focal_px(cams[name])))[1:]
        estimate = np.full_like(reference, np.nan)                 # BVH frame k is input frame k - 1
        estimate[:len(yaws)] = yaws[:len(reference)]
        scores[name] = score(estimate, reference)
    print(format_table(scores))


if __name__ == "__main__":
    main()
