"""A screenshot of `mocapdb view` on a real multi-person video: the bundled Sports2D keypoints
reconstructed with the demo database, with the video when the shared data holds it.

    .venv/bin/python tools/view_screenshot.py            # writes docs/view_sports2d.png
    .venv/bin/python tools/view_screenshot.py --keypoints KP_HANDS --frame 50 --out docs/view_hands.png
                                                         # keypoints of `mocapdb detect --hands`

Headless Chromium from Debian's packages (`apt-get install chromium`), driven by Playwright.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from mocapdb.cli.main import main as mocapdb
from mocapdb.core.formats.take import read_take
from mocapdb.view.server import ViewServer
from mocapdb.view.take import open_take

ROOT = Path(__file__).resolve().parents[1]
KEYPOINTS = ROOT / "data" / "sample_keypoints" / "video_sports2d"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", default=str(ROOT / "demo" / "sample.db"), help="the motion database")
    parser.add_argument("--keypoints", default=str(KEYPOINTS), help="keypoint folder (its take.json: the video)")
    parser.add_argument("--frame", type=int, default=60, help="the frame shown")
    parser.add_argument("--out", default=str(ROOT / "docs" / "view_sports2d.png"), help="the PNG written")
    parser.add_argument("--size", default="1600x900", help="the browser window, WxH")
    args = parser.parse_args()
    chromium = shutil.which("chromium")
    if chromium is None:
        sys.exit("no chromium on PATH: apt-get install chromium")
    keypoints = Path(args.keypoints)
    take = read_take(keypoints)
    video = ROOT / take.source if take is not None and take.source else None
    video = video if video is not None and video.is_file() else None
    width, height = (int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / keypoints.name
        if mocapdb(["reconstruct", str(keypoints), "--db", args.db, "--out", str(out), "--format", "bvh,trc,csv",
                    "-q"]) != 0:
            return 1
        server = ViewServer(0, take=open_take(out, keypoints, video), folder=out)
        try:
            with sync_playwright() as p:
                browser = p.chromium.launch(executable_path=chromium)
                page = browser.new_page(viewport={"width": width, "height": height})
                start = time.perf_counter()
                page.goto(server.url)
                page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true")
                ready_s = time.perf_counter() - start
                page.evaluate(f"window.mocapdbViewer.seek({args.frame})")
                page.wait_for_function(f"window.mocapdbViewer.frame() === {args.frame}")
                page.screenshot(path=args.out)
                browser.close()
        finally:
            server.close()
    print(f"wrote {args.out} (frame {args.frame}, video {'shown' if video else 'not found'}; page ready in "
          f"{ready_s * 1000:.0f} ms)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
