"""`mocapdb view`: a take in the browser (a page served on 127.0.0.1); `live --view` uses the same page."""
from __future__ import annotations

import argparse
import sys

from mocapdb.cli import paths as P
from mocapdb.core import domains as D


def add_view_parser(sub: argparse._SubParsersAction) -> None:
    """Add the ``view`` subcommand (``run`` returns the exit code)."""
    p = sub.add_parser(
        "view", help="look at a result in the browser: video, skeletons, a 3D view you can turn, a timeline",
        description="Serve a page on 127.0.0.1 showing the output of `mocapdb reconstruct` (its track files as "
                    "`mocapdb render` draws them, else the per-frame stream) or `mocapdb stereo`: the video with "
                    "the skeletons re-projected over it and the input keypoints, a 3D view (drag to turn, wheel "
                    "to zoom) with the floor, the camera and every person labelled with their size, a timeline "
                    "(play at the take's rate, step, scrub), the summary and links to the files. Opens it in "
                    "the browser; Ctrl-C stops the server. Nothing is fetched from the internet.")
    p.add_argument("result", type=P.INPUT_ANY,
                   help="the --out folder of `mocapdb reconstruct` or `mocapdb stereo` (or its result.jsonl)")
    p.add_argument("--video", type=P.INPUT_FILE, help="the input video, shown under the skeletons (OpenCV reads it)")
    p.add_argument("--keypoints", metavar="INPUT", type=P.INPUT_ANY,
                   help="the 2D input given to reconstruct (OpenPose folder, .jsonl, MMPose .json, .npy/.npz)")
    add_page_options(p, "--port")
    p.set_defaults(run=run_view)


def add_page_options(p: argparse.ArgumentParser, port_option: str) -> None:
    """The page's port option (``view --port N``, ``live --view [N]``) and ``--no-browser``."""
    if port_option == "--port":
        p.add_argument("--port", type=D.VIEW_PORT, default=D.VIEW_PORT.default,
                       help="the port on 127.0.0.1 (default: any free port, printed)")
    else:
        p.add_argument(port_option, type=D.VIEW_PORT, nargs="?", const=D.VIEW_PORT.default, metavar="PORT",
                       help="also show the stream in the browser: a page on 127.0.0.1:PORT (default: any free port, "
                            "printed) fed as frames come, with the frame rate and latency; a page that falls "
                            "behind loses frames (counted), never slows the engine")
    p.add_argument("--no-browser", action="store_true", help="serve the page without opening a browser")


def open_page(url: str, args: argparse.Namespace, command: str) -> None:
    """Say where the page is (stderr) and open it in the browser unless ``--no-browser``."""
    print(f"mocapdb {command}: the page is at {url}", file=sys.stderr, flush=True)
    if not args.no_browser:
        import webbrowser

        webbrowser.open(url)


def run_view(args: argparse.Namespace) -> int:
    """Serve the page until Ctrl-C (SIGINT) or SIGTERM."""
    import threading
    from pathlib import Path

    from mocapdb.cli.signals import install_stop_handlers
    from mocapdb.view.server import ViewServer
    from mocapdb.view.take import open_take

    take = open_take(args.result, args.keypoints, args.video,
                     warn=lambda text: print(f"mocapdb view: warning: {text}", file=sys.stderr))
    result = Path(args.result)
    try:
        server = ViewServer(args.port, take=take, folder=result if result.is_dir() else result.parent)
    except OSError:
        take.close()
        raise
    stop = threading.Event()
    with install_stop_handlers(stop):
        try:
            open_page(server.url, args, "view")
            print(f"{take.meta['summary'][0]}; Ctrl-C stops the server", file=sys.stderr, flush=True)
            while not stop.wait(0.5):
                pass
        finally:
            server.close()
            take.close()
    return 0
