"""Accuracy and speed of `mocapdb stereo` (ElliPose), printed as Markdown tables with pass/fail lines.

What is rendered, scored and how (synthetic Tables 1 and 2 on the held-out CMU walks, the real
Pose2Sim camera pairs): :mod:`mocapdb.evaluation.stereo`.

    python tools/eval_stereo.py [--quick]
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.evaluation.stereo import (  # noqa: E402
    FPS,
    PAIRS,
    TARGET_CUT,
    TARGET_SPEED_S,
    check_line,
    load_held_out,
    real_pairs,
    speed,
    table1,
    table2,
)

SHARED = ROOT.parent / "shared" / "data"
HELD_OUT = SHARED / "cmu_bvh"
POSE2SIM = SHARED / "pose2sim_balancing"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true",
                        help="3 held-out clips, the ablation on the front pair only")
    args = parser.parse_args(argv)
    logging.getLogger("mocapdb").setLevel(logging.ERROR)  # each run's unconverged ellipsoid: the tables show ε
    t0 = time.perf_counter()
    clips = load_held_out(HELD_OUT, args.quick)
    print(f"held-out clips: {len(clips)} ({sum(len(p) for _, p in clips)} frames at {FPS:g} fps)\n")
    text, rows = table1(clips, list(PAIRS))
    print("Table 1 (synthetic, mm; PCK in %)\n\n" + text + "\n")
    kinds = ["front"] if args.quick else ["front", "side"]
    print("Table 2 (synthetic ablation, MPJPE mm)\n\n" + table2(clips, kinds) + "\n")
    checks = [check_line(f"front pair: MPJPE cut {100 * rows['front']['cut']:.0f} % ≥ {100 * TARGET_CUT:.0f} %",
                         rows["front"]["cut"] >= TARGET_CUT)]
    if POSE2SIM.is_dir():
        text, real_checks = real_pairs(POSE2SIM)
        print("Real (Pose2Sim, 100 frames at 60 fps, against the 4-camera triangulation)\n\n" + text + "\n")
        checks += real_checks
    seconds, n = speed(clips)
    checks.append(check_line(f"speed: {n} frames in {seconds:.2f} s < {TARGET_SPEED_S:g} s", seconds < TARGET_SPEED_S))
    print("\n".join(checks))
    print(f"\n(total {time.perf_counter() - t0:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
