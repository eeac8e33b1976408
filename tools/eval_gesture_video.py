"""Hand gestures through the video paths (issue 49, item 6): the photos of ``data/sample_hands`` that show a
whole person (pointing, a thumb down, a flat hand; MediaPipe's test photos), each held ``--seconds`` in one
video and slowly zoomed in (so each is a moving picture for the detector's tracking and the hands' schedule),
through ``mocapdb detect --hands`` + ``reconstruct`` (the track files: the README's video path) and through
``mocapdb live --source VIDEO --hands`` (its BVH files; the hands every 2nd frame, carried between). Scored per
photo: the share of its frames, after its first :data:`EASE_S` (a hand found eases in from rest), whose hand in
the humanoid BVH (forward kinematics: :func:`bvh_gestures`) shows the photo's gesture
(:func:`mocapdb.evaluation.gestures.classify`), for the hand that shows it in the still photo.

    .venv/bin/python tools/eval_gesture_video.py [--seconds 1.5] [--work DIR] [--hand-model full|lite]

``--hand-model``: the hand landmark model `detect` and `live` run (the hands showing each gesture in the
still photos are always the full model's, so both models are scored on the same hands).

Prints a Markdown table (docs/benchmarks.md, "Gestures on a video"). Needs ``mocapdb models fetch hands``.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fingers import add_hand_model_option, expected_gesture, photos  # noqa: E402

from mocapdb.cli.main import main as mocapdb  # noqa: E402
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh  # noqa: E402
from mocapdb.core.hand_rig import FINGER_NAMES, SIDE_NAMES  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, hand_landmark_path  # noqa: E402
from mocapdb.evaluation.gestures import classify, photo_hands  # noqa: E402
from mocapdb.evaluation.hand_bvh import IMAGE_FROM_VIEW  # noqa: E402

FRAME_PX = 640      # the video's frames: each photo letterboxed into this square
FPS = 30.0
ZOOM = 0.15         # each photo zoomed in by this share over its seconds, about the frame's centre
EASE_S = 0.5        # a photo's first half second is not scored: its person is new, their hands ease in


def letterboxed(image: np.ndarray) -> np.ndarray:
    """``image`` scaled to fit a :data:`FRAME_PX` square, centred on black."""
    scale = FRAME_PX / max(image.shape[:2])
    resized = cv2.resize(image, (round(image.shape[1] * scale), round(image.shape[0] * scale)))
    frame = np.zeros((FRAME_PX, FRAME_PX, 3), np.uint8)
    top, left = (FRAME_PX - resized.shape[0]) // 2, (FRAME_PX - resized.shape[1]) // 2
    frame[top:top + resized.shape[0], left:left + resized.shape[1]] = resized
    return frame


def gesture_video(paths: list[Path], video: Path, frames_each: int) -> None:
    """Each photo of ``paths`` for ``frames_each`` frames, zoomed in by :data:`ZOOM` over them, as an mp4."""
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"mp4v"), FPS, (FRAME_PX, FRAME_PX))
    centre = (FRAME_PX / 2.0, FRAME_PX / 2.0)
    for path in paths:
        image = letterboxed(cv2.imread(str(path)))
        for k in range(frames_each):
            zoom = cv2.getRotationMatrix2D(centre, 0.0, 1.0 + ZOOM * k / frames_each)
            writer.write(cv2.warpAffine(image, zoom, (FRAME_PX, FRAME_PX)))
    writer.release()


def still_sides(path: Path, gesture: str) -> set[str]:
    """The sides ("Right", "Left") whose hand shows ``gesture`` in the still photo (the pose's hand crops)."""
    found = photo_hands(letterboxed(cv2.imread(str(path))), blazepose_paths("full"), hand_landmark_path("full"))
    return {{"right": "Right", "left": "Left"}[label.rsplit("_", 1)[-1]]
            for label, points, _ in found if label.startswith("person") and classify(points) == gesture}


def bvh_gestures(bvh_path: Path) -> dict[str, list[str]]:
    """Per side, each frame's gesture of the hand a humanoid BVH (in the camera's view frame) holds: its 21
    points by forward kinematics, turned into the image's convention (y down, z away)."""
    bvh = read_bvh(bvh_path)
    gestures = {}
    for side in SIDE_NAMES:
        names = [f"{side}Hand"] + [f"{side}Hand{f}{k}" for f in FINGER_NAMES for k in ("1", "2", "3", "3_End")]
        if not set(names) <= set(bvh.names):
            raise SystemExit(f"{bvh_path}: no finger bones (a humanoid BVH from keypoints with hands expected)")
        positions = forward_kinematics(bvh, [bvh.index(name) for name in names])[0]
        gestures[side] = [classify(points * IMAGE_FROM_VIEW) for points in positions]
    return gestures


def segment_track(result: Path, frames: range) -> int | None:
    """The track the stream (``result.jsonl``) shows most over ``frames``."""
    seen: Counter[int] = Counter()
    for line in (result / "result.jsonl").read_text().splitlines()[1:]:
        frame = json.loads(line)
        if frame["frame"] in frames:
            seen.update(person["track"] for person in frame["people"])
    return seen.most_common(1)[0][0] if seen else None


def scored(out: Path, frames: range, sides: set[str], gesture: str) -> float:
    """The share of ``frames`` (after the ease) in which a hand of ``sides`` shows ``gesture`` in the segment's
    track file (0 when no track or hand); ``out``: the run's folder (``result.jsonl`` and the track files)."""
    track = segment_track(out, frames)
    if track is None or not sides:
        return 0.0
    gestures = bvh_gestures(out / f"track_{track}.bvh")
    kept = frames[round(EASE_S * FPS):]
    return float(np.mean([any(gestures[side][k] == gesture for side in sides if k < len(gestures[side]))
                          for k in kept]))


def run(args: list[str]) -> None:
    if mocapdb(args) != 0:
        raise SystemExit(f"mocapdb {args[0]} failed")


def evaluate(db: Path, work: Path, seconds: float, hand_model: str) -> list[tuple[str, str, str, float, float]]:
    """Per photo: name, gesture, the sides showing it, the share in the track files and in live's BVH (the
    ``hand_model`` landmark model in both)."""
    named = [(path, gesture) for path in photos([]) for gesture in [expected_gesture(path)] if gesture]
    chosen = [(path, gesture, sides) for path, gesture in named for sides in [still_sides(path, gesture)] if sides]
    frames_each = round(seconds * FPS)
    video = work / "gestures.mp4"
    gesture_video([path for path, _, _ in chosen], video, frames_each)
    model = ["--hands", "--hand-model", hand_model]
    run(["detect", str(video), *model, "--out", str(work / "keypoints"), "-q"])
    run(["reconstruct", str(work / "keypoints"), "--db", str(db), "--out", str(work / "files"), "--view-frame", "-q"])
    (work / "live").mkdir(exist_ok=True)
    run(["live", "--source", str(video), *model, "--db", str(db), "--bvh-dir", str(work / "live"),
         "--view-frame", "--sink", str(work / "live" / "result.jsonl"), "-q"])
    rows = []
    for i, (path, gesture, sides) in enumerate(chosen):
        frames = range(i * frames_each, (i + 1) * frames_each)
        rows.append((path.name, gesture, "+".join(sorted(sides)),
                     scored(work / "files", frames, sides, gesture), scored(work / "live", frames, sides, gesture)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--seconds", type=float, default=1.5, help="each photo's time in the video")
    parser.add_argument("--work", type=Path, default=None, help="keep the video and results here")
    add_hand_model_option(parser)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        rows = evaluate(args.db, work, args.seconds, args.hand_model)
    print("| photo | gesture | hand | frames showing it: track file | `live` BVH |\n|---|---|---|---|---|")
    for name, gesture, sides, files, live in rows:
        print(f"| {name} | {gesture} | {sides} | {files:.0%} | {live:.0%} |")
    print(f"| all | | | {np.mean([r[3] for r in rows]):.0%} | {np.mean([r[4] for r in rows]):.0%} |")


if __name__ == "__main__":
    main()
