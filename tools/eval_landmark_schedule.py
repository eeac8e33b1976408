"""Hands or faces at a lower rate (`live --hands-every N`, `--face-every N`) against every one on every frame.

    python tools/eval_landmark_schedule.py VIDEO [VIDEO ...] [--every 2 3] [--max-people 1] [--frames 300]
                                           [--hand-model full|lite]
    python tools/eval_landmark_schedule.py --face PHOTO_OR_VIDEO [...] [--every 2 3]

Per video, BlazePose full (``--max-people``) then the hand landmark model (``--face``: the face landmark
model) with every one on every frame (the reference: what `detect --hands` / `--face` writes; the full hand
model) and with each ``--every N`` (:mod:`mocapdb.detect.landmark_schedule`; ``--hand-model lite``: the lite
hand model in these runs, ``--every 1`` for it on every frame), on the same decoded frames. A photo (.jpg,
.png) is made into a video of ``--frames`` frames by known similarities (:func:`photo_frames`: a turn of
±10° and a scale of ±8 % over 2 s, a shift of ±40 px over 1.5 s, at 30 fps). Prints BlazePose's CPU time
per frame and per N the landmark model's (the process's, all threads), crops run and carried, and on the
parts both found, how far the N run's points lie from the reference (mean distance, % of the reference's
wrist to middle knuckle, or of its eyes' outer corners for a face; mean and p95); for hands how far
their fingers' curls do (degrees, the mean over the five fingers; mean and p95); parts found only by the
reference or only by the N run. For a photo's faces also each run's distance from the truth: the
reference's mesh on frame 0 moved by the known similarity to each frame (``truth %``, mean and p95).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from eval_fingers import add_hand_model_option  # noqa: E402

from mocapdb.core.fingers import curl_deg, flexion_deg  # noqa: E402
from mocapdb.detect.blazepose import BlazePose  # noqa: E402
from mocapdb.detect.face import FaceLandmarker  # noqa: E402
from mocapdb.detect.hands import HandLandmarker  # noqa: E402
from mocapdb.detect.model_store import blazepose_paths, extra_model_path, hand_landmark_path  # noqa: E402
from mocapdb.detect.options import DEFAULT_HAND_MODEL  # noqa: E402
from mocapdb.detect.video import VideoReader  # noqa: E402

PHOTO_FPS = 30.0   # a photo's video: frames per second


def photo_frames(path: str, frames: int) -> tuple[list[np.ndarray], np.ndarray]:
    """``frames`` images of the photo at ``path`` moved by known similarities about its centre: turned by
    10° sin(2π t / 2 s), scaled by 1 + 0.08 sin(2π t / 2 s + 1), shifted 40 px sin(2π t / 1.5 s) across
    and 20 px cos(…) down, t = frame / :data:`PHOTO_FPS`; and the similarities ``[frames, 2, 3]`` (px)."""
    image = cv2.imread(path)
    height, width = image.shape[:2]
    t = np.arange(frames) / PHOTO_FPS
    turn, scale = 10.0 * np.sin(2 * np.pi * t / 2.0), 1.0 + 0.08 * np.sin(2 * np.pi * t / 2.0 + 1.0)
    shift = np.column_stack([40.0 * np.sin(2 * np.pi * t / 1.5), 20.0 * np.cos(2 * np.pi * t / 1.5)])
    matrices = np.array([cv2.getRotationMatrix2D((width / 2.0, height / 2.0), float(deg), float(s))
                         for deg, s in zip(turn, scale)])
    matrices[:, :, 2] += shift
    out = [cv2.warpAffine(image, matrix, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
           for matrix in matrices]
    return out, matrices


def truth_error(reference: list, got: list, matrices: np.ndarray) -> np.ndarray:
    """Per frame where both the first reference face and ``got``'s are found: the mean distance (% of the
    eyes' outer corners) of ``got``'s first face from the reference's frame-0 mesh moved by the known
    similarities ``matrices [F, 2, 3]`` onto that frame."""
    first = reference[0].points[0, :, :2]
    to_first = np.linalg.inv(np.vstack([matrices[0], [0.0, 0.0, 1.0]]))[:2]
    flat = first @ to_first[:, :2].T + to_first[:, 2]          # the photo's own mesh
    truth = np.einsum("fij,nj->fni", matrices[:, :, :2], flat) + matrices[:, None, :, 2]
    eyes = np.linalg.norm(truth[:, 33] - truth[:, 263], axis=-1)
    seen = np.array([found.absent[0] == "" for found in got]) & (reference[0].absent[0] == "")
    mesh = np.array([found.points[0, :, :2] for found in got])
    return (np.linalg.norm(mesh - truth, axis=-1).mean(axis=1) / eyes * 100.0)[seen]


def run_model(images: list[np.ndarray], poses: list[np.ndarray], every: int, face: bool,
              hand_model: str = DEFAULT_HAND_MODEL) -> tuple[list, float, int, int]:
    """The hands (the ``hand_model`` landmark model; ``face``: faces) of every frame with the model run every
    ``every`` frames: results, CPU ms per frame, crops run, carried."""
    model = (FaceLandmarker(extra_model_path("face"), every) if face
             else HandLandmarker(hand_landmark_path(hand_model), every))
    started = time.process_time()
    found = [model(image, pose) for image, pose in zip(images, poses)]
    return found, (time.process_time() - started) * 1000.0 / len(images), model.runs, model.schedule.carries


def differences(reference: list, got: list, face: bool) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Per part found by both: mean point distance (% of the hand's wrist to middle knuckle, or the face's
    eyes' outer corners, 33 ↔ 263) and, for hands, the mean curl difference (degrees; none for faces);
    parts found only by the reference, only by ``got``."""
    points, curls, only_ref, only_got = [], [], 0, 0
    ends = (33, 263) if face else (0, 9)
    for ref, found in zip(reference, got):
        ref_absent = [(a,) for a in ref.absent] if face else ref.absent
        got_absent = [(a,) for a in found.absent] if face else found.absent
        for person in range(min(len(ref_absent), len(got_absent))):
            for part in range(len(ref_absent[person])):
                in_ref, in_got = ref_absent[person][part] == "", got_absent[person][part] == ""
                only_ref += in_ref and not in_got
                only_got += in_got and not in_ref
                if in_ref and in_got:
                    at = (person,) if face else (person, part)
                    a, b = ref.points[at][:, :3], found.points[at][:, :3]
                    length = np.linalg.norm(a[ends[1], :2] - a[ends[0], :2])
                    points.append(np.linalg.norm(a[:, :2] - b[:, :2], axis=1).mean() / length * 100.0)
                    if not face:
                        curls.append(np.abs(curl_deg(flexion_deg(a)) - curl_deg(flexion_deg(b))).mean())
    return np.array(points), np.array(curls) if curls else np.full(1, np.nan), only_ref, only_got


def read_frames(path: str, frames: int) -> tuple[list[np.ndarray], np.ndarray | None]:
    """A video's first ``frames`` images (no similarities), or a photo's (.jpg, .png) :func:`photo_frames`."""
    if Path(path).suffix.lower() in (".jpg", ".jpeg", ".png"):
        return photo_frames(path, frames)
    reader = VideoReader(path)
    images = [frame.image for _, frame in zip(range(frames), reader.frames())]
    reader.close()
    return images, None


def _spread(values: np.ndarray) -> str:
    """``mean / p95`` of ``values`` (blank without any)."""
    return f"{np.mean(values):10.1f} /{np.percentile(values, 95):6.1f}" if np.isfinite(values).any() else f"{'':18}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("videos", nargs="+", help="videos, or photos made into videos by known similarities")
    ap.add_argument("--face", action="store_true", help="the face mesh instead of the hands")
    ap.add_argument("--every", type=int, nargs="+", default=[2, 3], help="the rates compared (default 2 3)")
    ap.add_argument("--max-people", type=int, default=1, help="people BlazePose follows (default 1)")
    ap.add_argument("--frames", type=int, default=300, help="frames per video at most (default 300)")
    add_hand_model_option(ap)
    args = ap.parse_args()
    what = "face" if args.face else "hand"
    print(f"{'video':16}{'every':>6}{what + ' CPU ms':>14}{'run':>6}{'carried':>8}{'compared':>9}"
          f"{'points % mean/p95':>19}{'curl deg mean/p95':>19}{'only ref':>9}{'only N':>7}{'truth % mean/p95':>19}")
    for video in args.videos:
        images, matrices = read_frames(video, args.frames)
        pose = BlazePose(*blazepose_paths("full"), max_people=args.max_people)
        started = time.process_time()
        poses = [pose(image).keypoints for image in images]
        print(f"{Path(video).stem:16}  BlazePose full: {(time.process_time() - started) * 1000.0 / len(images):.2f} "
              "CPU ms a frame")
        reference, ref_ms, ref_runs, _ = run_model(images, poses, 1, args.face, "full")
        truth = matrices is not None and args.face
        print(f"{Path(video).stem:16}{1:6d}{ref_ms:14.2f}{ref_runs:6d}{0:8d}{'':62}"
              + (_spread(truth_error(reference, reference, matrices)) if truth else ""))
        for every in args.every:
            got, ms, runs, carried = run_model(images, poses, every, args.face, args.hand_model)
            points, curls, only_ref, only_got = differences(reference, got, args.face)
            print(f"{Path(video).stem:16}{every:6d}{ms:14.2f}{runs:6d}{carried:8d}{len(points):9d}"
                  f"{_spread(points)} {_spread(curls)}{only_ref:9d}{only_got:7d}"
                  + (_spread(truth_error(reference, got, matrices)) if truth else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
