"""`mocapdb stereo` on all 6 camera pairs of the Pose2Sim take, through the real pipeline: frames where both
views see the person, frames reconstructed, null joints, ellipsoid rounds, rotation error and MPJPE against
the 4-camera triangulation (what is scored and how: :mod:`mocapdb.evaluation.stereo_pairs`).

    python tools/eval_stereo_pairs.py [TAKE_FOLDER]     (default ../shared/data/pose2sim_balancing)
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.evaluation.stereo_pairs import all_pairs, format_table  # noqa: E402

TAKE = ROOT.parent / "shared" / "data" / "pose2sim_balancing"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("take", nargs="?", type=Path, default=TAKE,
                        help="a Pose2Sim take: calibration.toml, triangulated_4cam.trc, openpose_body25b/camNN_json")
    args = parser.parse_args(argv)
    logging.getLogger("mocapdb").setLevel(logging.ERROR)  # the table's "converged" column says what the warning would
    started = time.perf_counter()
    print(format_table(all_pairs(args.take)))
    print(f"\n({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
