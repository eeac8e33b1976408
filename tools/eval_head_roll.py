"""The head on a real face turned by known angles in the image plane (issue 49, item 1): a photo with a whole
body and a face (data/sample_faces/laughing_sitting.jpg) made into a video turned about the image's centre by
``--amplitude`` degrees (a sine of period ``--period`` s), through ``mocapdb detect`` (with and without ``--face``)
and ``mocapdb reconstruct`` (the camera's path dropped: the image turns, the camera is taken as still). Scored:
the head's and the chest's roll in the view frame (about the camera's axis) in the stream (``result.jsonl``, lag 0)
and the track's humanoid BVH (``--view-frame``) against the known turn, after the stream's first 0.3 s (its end
joints ease in): RMS about the means, Pearson's r and the fitted gain.

    .venv/bin/python tools/eval_head_roll.py [--photo data/sample_faces/laughing_sitting.jpg] [--work DIR]

Only the roll can be known from one photo: the turn and the nod need a face turning in depth.
Prints a Markdown table (docs/benchmarks.md, "The head from the face mesh").
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import cv2
import numpy as np

from mocapdb.cli.main import main as mocapdb
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.core.geometry import quat_to_matrix
from mocapdb.core.skeleton import RIG_JOINTS, global_rotations

EASE_FRAMES = 9   # the stream's end joints ease in over 0.3 s: 9 frames at 30 fps


def turned_video(photo: Path, path: Path, frames: int, fps: float, amplitude_deg: float, period_s: float) -> np.ndarray:
    """Write the photo turned by ``amplitude · sin(2π t / period)`` degrees (counter-clockwise positive) as an
    mp4 at ``fps``; returns the angles ``[frames]``."""
    image = cv2.imread(str(photo))
    if image is None:
        raise SystemExit(f"{photo}: not an image")
    height, width = image.shape[:2]
    angles = amplitude_deg * np.sin(2.0 * np.pi * np.arange(frames) / fps / period_s)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    for angle in angles:
        writer.write(cv2.warpAffine(image, cv2.getRotationMatrix2D((width / 2, height / 2), float(angle), 1.0),
                                    (width, height)))
    writer.release()
    return angles


def reconstructed(video: Path, db: Path, out: Path, face: bool) -> Path:
    """``detect`` (``--face``) then ``reconstruct --view-frame`` into ``out``, the camera path dropped."""
    keypoints = out / "keypoints"
    if mocapdb(["detect", str(video), "--out", str(keypoints), "-q"] + (["--face"] if face else [])) != 0:
        raise SystemExit("detect failed")
    (keypoints / "camera_path.json").unlink(missing_ok=True)
    if mocapdb(["reconstruct", str(keypoints), "--db", str(db), "--out", str(out / "result"), "--view-frame",
                "-q"]) != 0:
        raise SystemExit("reconstruct failed")
    return out / "result"


def roll_deg(rotations: np.ndarray) -> np.ndarray:
    """``[F]`` the roll (degrees, unwrapped) of rotations ``[F, 3, 3]`` about the view's z axis: the angle of
    their x axis in the image plane."""
    return np.degrees(np.unwrap(np.arctan2(rotations[:, 1, 0], rotations[:, 0, 0])))


def stream_rotations(result: Path) -> dict[str, dict[int, np.ndarray]]:
    """The main person's head and chest global rotations per frame of the stream."""
    out: dict[str, dict[int, np.ndarray]] = {"head": {}, "chest": {}}
    for line in (result / "result.jsonl").read_text().splitlines()[1:]:
        frame = json.loads(line)
        if not frame["people"]:
            continue
        person = frame["people"][0]
        rig = global_rotations(np.array(person["quaternions"])[None])[0]
        out["head"][frame["frame"]] = rig[RIG_JOINTS.index("neck")] @ quat_to_matrix(
            np.array(person["end_quaternions"][4]))
        out["chest"][frame["frame"]] = rig[RIG_JOINTS.index("spine")]
    return out


def bvh_rotations(result: Path) -> dict[str, dict[int, np.ndarray]]:
    """The track's humanoid BVH's Head and Spine1 global rotations per input frame (frame k of the BVH is input
    frame k - 1)."""
    bvh = read_bvh(next(result.glob("track_*.bvh")))
    rotations = forward_kinematics(bvh, [bvh.names.index("Head"), bvh.names.index("Spine1")])[1]
    return {name: {k - 1: r for k, r in enumerate(rotations[:, j]) if k >= 1}
            for j, name in enumerate(("head", "chest"))}


def score(rotations: dict[int, np.ndarray], angles: np.ndarray, first: int) -> tuple[float, float, float]:
    """RMS (degrees, about the means), Pearson's r and gain of the roll of ``rotations`` against ``angles``."""
    frames = np.array([k for k in sorted(rotations) if first <= k < len(angles)])
    roll, truth = roll_deg(np.array([rotations[k] for k in frames])), angles[frames]
    rms = float(np.sqrt(np.mean(((roll - roll.mean()) - (truth - truth.mean())) ** 2)))
    return rms, float(np.corrcoef(roll, truth)[0, 1]), float(np.polyfit(truth, roll, 1)[0])


def evaluate(photo: Path, db: Path, work: Path, frames: int = 45, fps: float = 30.0, amplitude_deg: float = 12.0,
             period_s: float = 1.5) -> dict[tuple[str, str, str], tuple[float, float, float]]:
    """Scores per (face mesh or not, output, bone)."""
    work.mkdir(parents=True, exist_ok=True)
    angles = turned_video(photo, work / "turned.mp4", frames, fps, amplitude_deg, period_s)
    scores = {}
    for face in (True, False):
        result = reconstructed(work / "turned.mp4", db, work / ("mesh" if face else "points"), face)
        for output, rotations, first in (("stream lag 0", stream_rotations(result), EASE_FRAMES),
                                         ("track BVH", bvh_rotations(result), 0)):
            for bone in ("head", "chest"):
                scores[("face mesh" if face else "face points", output, bone)] = score(rotations[bone], angles, first)
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--photo", type=Path, default=Path("data/sample_faces/laughing_sitting.jpg"))
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--work", type=Path, default=None, help="keep the video and results here")
    parser.add_argument("--amplitude", type=float, default=12.0, help="degrees")
    parser.add_argument("--period", type=float, default=1.5, help="seconds")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        scores = evaluate(args.photo, args.db, args.work or Path(tmp), amplitude_deg=args.amplitude,
                          period_s=args.period)
    print("| input | output | bone | roll RMS | r | gain |\n|---|---|---|---|---|---|")
    for (face, output, bone), (rms, r, gain) in scores.items():
        print(f"| {face} | {output} | {bone} | {rms:.2f}° | {r:.3f} | {gain:.2f} |")


if __name__ == "__main__":
    main()
