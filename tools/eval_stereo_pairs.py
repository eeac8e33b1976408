"""`mocapdb stereo` on every camera pair of a calibrated take, through the real pipeline: frames where both
views see the person, frames reconstructed, null joints, ellipsoid rounds, rotation error and MPJPE against
a reference person (what is scored and how: :mod:`mocapdb.evaluation.stereo_pairs`).

    python tools/eval_stereo_pairs.py [TAKE_FOLDER]     (default ../shared/data/pose2sim_balancing)
    python tools/eval_stereo_pairs.py --views DIR DIR [DIR ...] --calibration FILE --cameras NAME NAME [...]
                                      [--fps FPS]

A Pose2Sim take is scored against its 4-camera TRC; keypoint folders (one per camera, e.g. `mocapdb detect`'s
output of each video) against the person the most views agree on, triangulated with the calibration.
"""
from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.take import read_take  # noqa: E402
from mocapdb.evaluation.stereo_pairs import all_pairs, calibrated_pairs, format_table  # noqa: E402

TAKE = ROOT.parent / "shared" / "data" / "pose2sim_balancing"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("take", nargs="?", type=Path, default=TAKE,
                        help="a Pose2Sim take: calibration.toml, triangulated_4cam.trc, openpose_body25b/camNN_json")
    parser.add_argument("--views", nargs="+", type=Path, metavar="DIR",
                        help="keypoint folders, one per camera (instead of a take)")
    parser.add_argument("--calibration", type=Path, metavar="FILE", help="the cameras of --views (TOML or .qca.txt)")
    parser.add_argument("--cameras", nargs="+", metavar="NAME", help="the calibration's camera of each of --views")
    parser.add_argument("--fps", type=float, help="frame rate (Hz); default: the first view's take.json")
    args = parser.parse_args(argv)
    logging.getLogger("mocapdb").setLevel(logging.ERROR)  # the table's "converged" column says what the warning would
    started = time.perf_counter()
    if args.views:
        if not args.calibration or not args.cameras or len(args.cameras) != len(args.views) or len(args.views) < 2:
            parser.error("--views needs two folders or more, --calibration and one --cameras name per folder")
        take = read_take(args.views[0])
        fps = args.fps or (take.fps if take else None)
        if not fps:
            parser.error(f"{args.views[0]} has no take.json giving the frame rate: give --fps")
        print(f"reference: the person the most views agree on, triangulated from them with {args.calibration}\n")
        try:
            rows = calibrated_pairs(args.views, args.calibration, args.cameras, fps)
        except KeyError as exc:
            parser.error(f"{args.calibration} has no camera {exc}")
    else:
        print(f"reference: {args.take / 'triangulated_4cam.trc'}\n")
        rows = all_pairs(args.take)
    print(format_table(rows))
    print(f"\n({time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
