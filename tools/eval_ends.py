"""The head, hands and feet against synthetic truth (issue 49, item 6; mocapdb/evaluation/ends.py): held-out
clips on the accuracy gate's three bodies, their face, hand and foot points attached to the clips' own head,
hands and feet, seen from 6 yaws, exact and with noise; the median geodesic error (degrees) of each end
bone's global rotation in the humanoid BVH (whole take) and in the stream at lag 0 (``--lag``), and not turned.

    .venv/bin/python tools/eval_ends.py [--db demo/sample.db] [--bvh data/gate/cmu_bvh/007_01.bvh ...]
        [--hand-points 21] [--face-mesh]

The default clips are the gate's (data/gate/cmu_bvh: 007_01, 007_12, 002_05, none in demo/sample.db).
Prints a Markdown table (docs/benchmarks.md, "Head, hands and feet against synthetic truth").
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from mocapdb.core.formats.database_reader import load_database
from mocapdb.evaluation.ends import ENDS_YAWS_DEG, evaluate_ends, format_ends, gate_clip_files
from mocapdb.evaluation.gate import MAX_FRAMES


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--bvh", type=Path, nargs="+", default=gate_clip_files(Path("data/gate/cmu_bvh")),
                        help="held-out clips (Character Creator rigs, none of them in the database)")
    parser.add_argument("--yaws", type=float, nargs="+", default=list(ENDS_YAWS_DEG))
    parser.add_argument("--max-frames", type=int, default=MAX_FRAMES)
    parser.add_argument("--lag", type=int, default=0, help="the stream's lag (frames)")
    parser.add_argument("--hand-points", type=int, choices=(3, 21), default=3,
                        help="the hands as BlazePose's 3 points, or with the hand landmark model's 21 (detect --hands)"
                             " and the fingers' bends scored")
    parser.add_argument("--face-mesh", action="store_true",
                        help="also render the face mesh (a real face's rigid head vertices, detect --face): the head "
                             "from the mesh where the face looks within 60 deg of the camera")
    args = parser.parse_args()
    t0 = time.perf_counter()
    results = evaluate_ends(load_database(args.db), args.bvh, yaws_deg=tuple(args.yaws), max_frames=args.max_frames,
                            lag_frames=args.lag, hand_points=args.hand_points, face_mesh=args.face_mesh)
    print(format_ends(results))
    print(f"\n{len(args.bvh)} clips x 3 bodies x {len(args.yaws)} yaws per input; {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
