"""A pose detector's 2D quality without 2D ground truth (issue 28, item 5): each detector's keypoints of
every camera of a calibrated take triangulated and re-projected (residual per joint, px and % of the body
height), and, with a database, the planted-foot slide and acceleration of `mocapdb reconstruct` on camera
1 alone (what is measured and how: :mod:`mocapdb.evaluation.detector_quality`).

    python tools/detector_quality.py --calibration FILE --detector NAME DIR DIR DIR DIR [--detector ...]
                                     [--cameras NAME ...] [--db DB] [--json OUT.json] [--figure OUT.png]

The folders are `mocapdb detect`'s output (OpenPose JSON, any layout: COCO-18, BlazePose 33, ...), one per
camera in the order of --cameras (default: the calibration's cameras, sorted), camera 1 first.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.cameras import read_calibration  # noqa: E402
from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD  # noqa: E402
from mocapdb.core.formats.take import read_take  # noqa: E402
from mocapdb.evaluation.detector_quality import BODY_JOINTS, evaluate, format_table  # noqa: E402


def bar_chart(report: dict, path: Path) -> None:
    """Median residual (% of the body height) per body joint and detector, as a PNG."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(report["detectors"])
    x = np.arange(len(BODY_JOINTS))
    width = 0.8 / len(names)
    fig, ax = plt.subplots(figsize=(10, 3.6), dpi=110)
    for k, name in enumerate(names):
        joints = report["detectors"][name]["joints"]
        ax.bar(x + k * width, [joints[j]["median_pct"] or 0.0 for j in BODY_JOINTS], width, label=name)
    ax.set_xticks(x + 0.4 - width / 2, BODY_JOINTS, rotation=30)
    ax.set_ylabel("median residual, % of body height")
    ax.set_title("4-camera re-projection residual per joint (pose2sim balancing)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calibration", type=Path, required=True, metavar="FILE",
                        help="the take's calibration (Pose2Sim TOML or Qualisys .qca.txt)")
    parser.add_argument("--detector", nargs="+", action="append", required=True, metavar="NAME DIR",
                        help="a detector's name, then its keypoint folder of each camera (camera 1 first)")
    parser.add_argument("--cameras", nargs="+", metavar="NAME", help="the calibration's camera of each folder")
    parser.add_argument("--fps", type=float, help="frame rate (Hz); default: camera 1's take.json")
    parser.add_argument("--confidence", type=float, default=CONFIDENCE_THRESHOLD,
                        help="a view takes part in a joint's triangulation above this confidence")
    parser.add_argument("--db", type=Path, help="a database: also reconstruct camera 1 and measure its motion")
    parser.add_argument("--work", type=Path, help="where the reconstructions go (default: a temporary folder)")
    parser.add_argument("--json", type=Path, metavar="FILE", help="write the figures here")
    parser.add_argument("--figure", type=Path, metavar="FILE", help="a bar chart (PNG) of the body joints")
    args = parser.parse_args(argv)
    cams = read_calibration(args.calibration)
    names = args.cameras or sorted(cams)
    if unknown := [n for n in names if n not in cams]:
        parser.error(f"{args.calibration} has no camera {', '.join(unknown)} ({', '.join(cams)})")
    detectors = {d[0]: [Path(f) for f in d[1:]] for d in args.detector}
    if wrong := [n for n, folders in detectors.items() if len(folders) != len(names)]:
        parser.error(f"--detector {', '.join(wrong)}: give one folder per camera ({len(names)}: {', '.join(names)})")
    take = read_take(next(iter(detectors.values()))[0])
    fps = args.fps or (take.fps if take else None)
    if not fps:
        parser.error("camera 1's folder has no take.json giving the frame rate: give --fps")
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        report = evaluate(detectors, [cams[n] for n in names], fps, args.confidence, args.db, args.work or Path(tmp))
    report["seconds"] = time.perf_counter() - started
    print(format_table(report))
    if args.json:
        args.json.write_text(json.dumps(report, indent=1) + "\n")
    if args.figure:
        bar_chart(report, args.figure)
    print(f"\n({report['seconds']:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
