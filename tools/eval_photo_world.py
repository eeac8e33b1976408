"""The camera's tilt from a photo: each frame of the calibrated balancing take alone, as `reconstruct` finds
its world from one frame (no planted foot: the people's up, or the scene's), against the calibration.

    python tools/eval_photo_world.py [--db demo/sample.db] [--every 5] [--rolls 0 10 20]

Every ``--every``-th frame of each of the four cameras (the take's own OpenPose keypoints,
data/gate/pose2sim_balancing) is a photo; each is also turned in the image about its centre by each of
``--rolls`` degrees, which is exactly a camera rolled by that much about its optical axis (the truth's
roll moves with it), so a camera that is not held level is scored too. Prints, per roll, the median,
90th percentile and worst of the pitch's and roll's errors (degrees) over the photos, and beside them the
same cameras' worlds from their whole 100 frames (as `reconstruct` finds a video's). Figures:
data_specs/world.md, "A photo's tilt".
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.core.formats.keypoints import KeypointFrame  # noqa: E402
from mocapdb.evaluation.real_take import focal_px, load_take  # noqa: E402
from mocapdb.evaluation.world_camera import VIEW_FROM_OPENCV, score_world_camera, world_of_frames  # noqa: E402
from mocapdb.runtime.engine_config import EngineConfig  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REAL_TAKE = ROOT / "data" / "gate" / "pose2sim_balancing"


def rolled_truth(cam, roll_deg: float) -> dict[str, float]:
    """The calibrated camera's height, pitch and roll (world_camera's definitions) after turning its
    image by ``roll_deg`` (counter-clockwise as seen)."""
    normal = cam.R[:, 2] * VIEW_FROM_OPENCV
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    nx, ny, nz = c * normal[0] - s * normal[1], s * normal[0] + c * normal[1], normal[2]
    return {"height_m": float(cam.center_m[2]), "pitch_deg": float(np.degrees(np.arctan2(nz, ny))),
            "roll_deg": float(np.degrees(np.arctan2(-nx, ny)))}


def turned(frame: KeypointFrame, roll_deg: float, center_px: tuple[float, float]) -> KeypointFrame:
    """``frame``'s people turned counter-clockwise (as seen) by ``roll_deg`` about ``center_px``, as frame 0."""
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))

    def turn(points: np.ndarray) -> np.ndarray:
        u, v = points[..., 0] - center_px[0], center_px[1] - points[..., 1]   # y up
        out = points.copy()
        out[..., 0], out[..., 1] = center_px[0] + c * u - s * v, center_px[1] - (s * u + c * v)
        return out
    people = [replace(p, points_px=turn(p.points_px),
                      extremities=None if p.extremities is None else turn(p.extremities)) for p in frame.people]
    return replace(frame, index=0, time_s=0.0, people=people)


def photo_scores(db, take, every: int, roll_deg: float) -> tuple[list[dict], list[dict]]:
    """Each photo's world camera (:func:`score_world_camera`) at ``roll_deg``, and each camera's from all
    its frames."""
    photos, videos = [], []
    for name, cam in take.cameras.items():
        config = EngineConfig(fps=take.fps, focal_px=focal_px(cam), image_size=(int(cam.size[0]), int(cam.size[1])))
        truth = rolled_truth(cam, roll_deg)
        frames = [turned(frame, roll_deg, config.center_px) for frame in take.frames[name]]
        videos.append(score_world_camera(world_of_frames(db, [replace(f, index=i, time_s=i / take.fps)
                                                              for i, f in enumerate(frames)], config), truth))
        one_frame = replace(config, tracker=replace(config.tracker, min_hits=1))   # as reconstruct runs a photo
        photos += [score_world_camera(world_of_frames(db, [frame], one_frame), truth)
                   for frame in frames[::every] if frame.people]
    return photos, videos


def summary(label: str, scores: list[dict]) -> str:
    """A table row: the pitch's and roll's errors (degrees), median / 90th percentile / worst."""
    pitch = np.abs([s["pitch_error_deg"] for s in scores])
    roll = np.abs([s["roll_error_deg"] for s in scores])
    return (f"| {label} | {len(scores)} | {np.median(pitch):.1f} / {np.percentile(pitch, 90):.1f} / "
            f"{pitch.max():.1f} | {np.median(roll):.1f} / {np.percentile(roll, 90):.1f} / {roll.max():.1f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", default=str(ROOT / "demo" / "sample.db"), help="database (default demo/sample.db)")
    ap.add_argument("--every", type=int, default=5, help="every N-th frame of each camera is a photo (default 5)")
    ap.add_argument("--rolls", type=float, nargs="+", default=[0.0, 10.0, 20.0],
                    help="the camera's roll added by turning the image (degrees; default 0 10 20)")
    args = ap.parse_args()
    db = load_database(args.db, projections=False)
    take = load_take(REAL_TAKE)
    print("| camera rolled by | scored | pitch off: median / 90 % / worst | roll off: median / 90 % / worst |\n"
          "|---|---|---|---|")
    for roll in args.rolls:
        photos, videos = photo_scores(db, take, args.every, roll)
        print(summary(f"{roll:g}°, photos", photos), flush=True)
        print(summary(f"{roll:g}°, the cameras' whole takes", videos), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
