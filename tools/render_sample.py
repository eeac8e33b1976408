"""Render the bundled sample's pictures for the docs: docs/reconstruct_sample.png (contact sheet of
the camera-1 reconstruction) and docs/stereo_cameras.png (the two cameras and the motion).

    .venv/bin/python tools/render_sample.py [--work /tmp/render_sample] [--reuse]

Runs `mocapdb build data/sample_bvh`, `mocapdb reconstruct` of data/sample_keypoints/blazepose_cam01
(--focal 1681, as tools/quickstart.sh) and `mocapdb stereo` of cameras 1 and 4 into --work
(--reuse: keep outputs already there), then draws both pictures.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sample_keypoints"
FOCAL, SIZE = 1681.0, (1080, 1920)   # the take.json of blazepose_cam01


def _run(args: list[str]) -> None:
    print("$ mocapdb " + " ".join(args), flush=True)
    subprocess.run([sys.executable, "-m", "mocapdb", *args], check=True, cwd=ROOT)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--work", default="/tmp/render_sample", help="folder for the database and the runs")
    p.add_argument("--reuse", action="store_true", help="keep the database and results already in --work")
    p.add_argument("--frames", type=int, default=12, help="frames on the contact sheet (default 12)")
    args = p.parse_args()
    work = Path(args.work)
    db, recon, stereo = work / "sample.db", work / "recon", work / "stereo"
    if not (args.reuse and (db / "manifest.json").is_file()):
        _run(["build", str(ROOT / "data" / "sample_bvh"), "--out", str(db)])
    if not (args.reuse and (recon / "result.jsonl").is_file()):
        _run(["reconstruct", str(SAMPLE / "blazepose_cam01"), "--db", str(db), "--out", str(recon),
              "--focal", f"{FOCAL:g}"])
    if not (args.reuse and (stereo / "cameras.json").is_file()):
        _run(["stereo", str(SAMPLE / "pose2sim_cam01"), str(SAMPLE / "pose2sim_cam04"), "--calibration",
              str(SAMPLE / "calibration.toml"), "--cameras", "cam_01", "cam_04", "--fps", "60",
              "--camera-distance", "5.24", "--out", str(stereo)])

    from mocapdb.render.contact_sheet import contact_sheet
    from mocapdb.render.stereo_plot import render_stereo_plot

    sheet = contact_sheet(recon, SAMPLE / "blazepose_cam01", ROOT / "docs" / "reconstruct_sample.png", args.frames,
                          focal=FOCAL, image_size=SIZE, tile_height=480,
                          warn=lambda text: print(f"warning: {text}", file=sys.stderr))
    plot = render_stereo_plot(stereo, ROOT / "docs" / "stereo_cameras.png", panel=800)
    print(f"wrote {sheet.relative_to(ROOT)} and {plot.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
