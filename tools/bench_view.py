"""How fast `mocapdb view` plays a minute of a three-person take in headless Chromium: the bundled
Sports2D keypoints (three people, 230 frames at 30 fps) played back and forth to a minute, the
take reconstructed with the demo database, the page played for a few seconds; prints the page's
load time and its own play rate, without and (when the shared video is there) with the video.

    .venv/bin/python tools/bench_view.py            # needs chromium on PATH (apt-get install chromium)
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from mocapdb.cli.main import main as mocapdb
from mocapdb.view.server import ViewServer
from mocapdb.view.take import open_take

ROOT = Path(__file__).resolve().parents[1]
KEYPOINTS = ROOT / "data" / "sample_keypoints" / "video_sports2d"
VIDEO = ROOT / "../shared/data/videos/sports2d_demo/demo.mp4"


def minute_of_keypoints(folder: Path, seconds: float = 60.0, fps: float = 30.0) -> None:
    """``folder``: the Sports2D frames forwards, then backwards, … until ``seconds`` of frames (a
    person walks back the way they came: no jump between rounds), numbered anew; its take.json."""
    frames = sorted(KEYPOINTS.glob("*_keypoints.json"))
    order = frames + frames[-2:0:-1]
    folder.mkdir(parents=True)
    for i in range(int(seconds * fps)):
        (folder / f"minute_{i:012d}_keypoints.json").write_bytes(order[i % len(order)].read_bytes())
    take = json.loads((KEYPOINTS / "take.json").read_text()) | {"frames": int(seconds * fps), "source": None}
    (folder / "take.json").write_text(json.dumps(take))


def play(url: str, chromium: str, seconds: float) -> tuple[float, float]:
    """The page's load time (s) and its own play rate (frames/s) over ``seconds`` of playing."""
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=["--enable-unsafe-swiftshader"])
        page = browser.new_page(viewport={"width": 1400, "height": 800})
        start = time.perf_counter()
        page.goto(url)
        page.wait_for_function("window.mocapdbViewer && window.mocapdbViewer.ready === true", timeout=60_000)
        load_s = time.perf_counter() - start
        page.click("#play")
        time.sleep(seconds)
        stats = page.evaluate("window.mocapdbViewer.stats()")
        browser.close()
    return load_s, float(stats["playFps"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", default=str(ROOT / "demo" / "sample.db"), help="the motion database")
    parser.add_argument("--seconds", type=float, default=5.0, help="how long the page plays (s)")
    args = parser.parse_args()
    chromium = shutil.which("chromium")
    if chromium is None:
        sys.exit("no chromium on PATH: apt-get install chromium")
    with tempfile.TemporaryDirectory() as tmp:
        keypoints, out = Path(tmp) / "kp", Path(tmp) / "take"
        minute_of_keypoints(keypoints)
        if mocapdb(["reconstruct", str(keypoints), "--db", args.db, "--out", str(out), "--format", "csv,bvh", "-q"]):
            return 1
        videos = [None] + ([VIDEO] if VIDEO.is_file() else [])
        for video in videos:
            server = ViewServer(0, take=open_take(out, keypoints, video), folder=out)
            try:
                load_s, fps = play(server.url, chromium, args.seconds)
            finally:
                server.close()
            print(f"1 min, 3 people, {'with the video' if video else 'no video'}: page ready in {load_s:.2f} s, "
                  f"played at {fps:.1f} frames/s (the take: 30)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
