"""The scene's lines against a calibration with a known rotation added (issue 51, item 4): each
calibrated camera's video frames warped by ``K R K⁻¹`` (a camera turned by ``R`` about its centre:
pitched and rolled by known angles), the people's keypoints warped alike for their boxes, then the
line segments (`mocapdb/detect/scene.py`), the vanishing points and the tilt the scene alone gives
(no people: the vertical about the image's up) and the focal (`runtime/world/scene_lines.py`),
against the calibration's pitch, roll and focal turned by ``R``. Real images, known truth.

    .venv/bin/python tools/eval_scene_lines.py --calibration ../shared/data/pose2sim_balancing/calibration.toml \\
        cam_01=../shared/data/videos/pose2sim_balancing/cam01.mp4:kp/cam01 ...
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.cameras import read_calibration_toml  # noqa: E402
from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.core.formats.keypoints import KeypointFrame  # noqa: E402
from mocapdb.core.formats.openpose import read_openpose_folder  # noqa: E402
from mocapdb.detect.scene import SAMPLE_PERIOD_S, SceneSampler  # noqa: E402
from mocapdb.detect.video import VideoReader  # noqa: E402
from mocapdb.evaluation.real_take import focal_px  # noqa: E402
from mocapdb.evaluation.world_camera import (  # noqa: E402
    VIEW_FROM_OPENCV,
    scene_world,
    score_world_camera,
    tilt_lines,
    tracks_of_frames,
    world_of_tracks,
)
from mocapdb.runtime.engine_config import EngineConfig  # noqa: E402
from mocapdb.runtime.world.scene_lines import SceneEvidence, pitch_roll_deg, vanishing_points  # noqa: E402

TURNS_DEG = [(p, r) for p in (-10.0, 0.0, 10.0) for r in (-20.0, -10.0, 0.0, 10.0, 20.0)]   # pitch, roll added


def turn(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """The rotation (OpenCV camera axes) of a camera pitched up by ``pitch_deg`` (about x) then
    rolled by ``roll_deg`` about its optical axis."""
    return cv2.Rodrigues(np.array([0.0, 0.0, np.radians(roll_deg)]))[0] @ \
        cv2.Rodrigues(np.array([np.radians(pitch_deg), 0.0, 0.0]))[0]


def sampled_frames(video: str, every: int) -> list:
    """Every ``every``-th frame of ``video`` (what ``detect``'s scene sampler takes at its rate)."""
    reader = VideoReader(video)
    try:
        return [frame for frame in reader.frames() if frame.index % every == 0]
    finally:
        reader.close()


def warp_points(points: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """Pixels ``[..., 2]`` moved by ``homography`` (NaN stays NaN)."""
    flat = points.reshape(-1, 1, 2).astype(np.float64)
    return cv2.perspectiveTransform(flat, homography).reshape(points.shape)


def turned_frames(frames: list[KeypointFrame], rotation: np.ndarray, homography: np.ndarray
                  ) -> list[KeypointFrame]:
    """Keypoint frames as the turned camera sees them: pixels by ``homography``, the detector's 3D
    (camera-aligned axes) by ``rotation``; hands and faces dropped."""
    def person(p):
        extremities = None if p.extremities is None else np.column_stack(
            [warp_points(p.extremities[:, :2], homography), p.extremities[:, 2]])
        def turned(world):
            return None if world is None else world @ rotation.T
        return replace(p, points_px=warp_points(p.points_px, homography), extremities=extremities, hands=None,
                       face=None, world_m=turned(p.world_m), extremities_world_m=turned(p.extremities_world_m))
    return [replace(f, people=[person(p) for p in f.people]) for f in frames]


def scene_of(images: list, frames: dict[int, KeypointFrame], homography: np.ndarray, every: int):
    """The scene's lines of the sampled video ``images`` warped by ``homography``, the people's boxes
    from the warped keypoint ``frames`` (by frame number)."""
    sampler = SceneSampler(None)
    sampler.every = every
    for image in images:
        warped = cv2.warpPerspective(image.image, homography, (image.image.shape[1], image.image.shape[0]))
        people = frames[image.index].people if image.index in frames else []
        points = np.array([np.column_stack([np.nan_to_num(p.points_px), p.confidence]) for p in people])
        sampler.see(image.index, warped, points.reshape(-1, 14, 3))
    return sampler.scene()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calibration", required=True, type=Path)
    parser.add_argument("--db", default="demo/sample.db", help="the motion database (for the people's world)")
    parser.add_argument("--fps", type=float, default=60.0, help="the video's and keypoints' frame rate (Hz)")
    parser.add_argument("cameras", nargs="+", metavar="NAME=VIDEO:KEYPOINTS")
    args = parser.parse_args()
    cams, db = read_calibration_toml(args.calibration), load_database(args.db)
    results = []
    for spec in args.cameras:
        name, _, rest = spec.partition("=")
        video, _, folder = rest.partition(":")
        if name not in cams or not folder:
            parser.error(f"{spec}: expected NAME=VIDEO:KEYPOINTS with NAME one of {', '.join(sorted(cams))}")
        cam, every = cams[name], max(round(args.fps * SAMPLE_PERIOD_S), 1)
        frames, images = list(read_openpose_folder(Path(folder), fps=args.fps)), sampled_frames(video, every)
        f, size = focal_px(cam), (int(cam.size[0]), int(cam.size[1]))
        k = np.array([[f, 0, size[0] / 2], [0, f, size[1] / 2], [0, 0, 1.0]])
        config = EngineConfig(fps=args.fps, focal_px=f, image_size=size)
        for pitch, roll in TURNS_DEG:
            rotation = turn(pitch, roll)
            homography = k @ rotation @ np.linalg.inv(k)
            seen = turned_frames(frames, rotation, homography)
            points = vanishing_points(scene_of(images, {fr.index: fr for fr in seen}, homography, every))
            true_pitch, true_roll = pitch_roll_deg((rotation @ cam.R[:, 2]) * VIEW_FROM_OPENCV)
            truth = {"height_m": float(cam.center_m[2]), "pitch_deg": float(true_pitch), "roll_deg": float(true_roll)}
            evidence = SceneEvidence(points, f, 0.0)
            tracks = tracks_of_frames(db, seen, config)
            alone = evidence.tilt(None)
            results.append({"camera": name, "turn": (pitch, roll), "truth": truth,
                            "people": score_world_camera(world_of_tracks(tracks, config), truth),
                            "scene": None if alone is None else score_world_camera(scene_world(alone), truth),
                            "fused": score_world_camera(world_of_tracks(tracks, config, evidence), truth),
                            "focal": points.focal(), "focal_true": f})
    print("\n".join(table(results) + [""] + summary(results)))
    return 0


def _tilt(score: dict | None) -> str:
    """``pitch off ± SD / roll off ± SD`` of one score, or "none"."""
    if score is None:
        return "none"
    w = score["world"]
    return (f"{score['pitch_error_deg']:+.1f} ± {w['pitch_sd_deg']:.1f} / "
            f"{score['roll_error_deg']:+.1f} ± {w['roll_sd_deg']:.1f}")


def table(results: list[dict]) -> list[str]:
    """A markdown row per camera and turn: the tilt's errors of the people, the scene alone and both."""
    lines = ["| camera | turn: pitch / roll | truth: pitch / roll | people: off ± SD | scene alone | fused | "
             "focal off |", "|---|---|---|---|---|---|---|"]
    for r in results:
        focal = "none" if r["focal"] is None else f"{100 * (r['focal'].focal_px / r['focal_true'] - 1):+.1f} %"
        lines.append(f"| {r['camera']} | {r['turn'][0]:+.0f}° / {r['turn'][1]:+.0f}° | "
                     f"{r['truth']['pitch_deg']:.1f}° / {r['truth']['roll_deg']:.1f}° | {_tilt(r['people'])} | "
                     f"{_tilt(r['scene'])} | "
                     f"{_tilt(r['fused'])} | {focal} |")
    return lines


def summary(results: list[dict]) -> list[str]:
    """Per mode: medians, worsts and how many truths lie inside ±2 SD; the focal's errors."""
    lines = []
    for mode in ("people", "scene", "fused"):
        lines += tilt_lines(f"{mode} ({'vertical about the image up, no people' if mode == 'scene' else 'all'})",
                            {str(i): r[mode] for i, r in enumerate(results)})
    focal = np.abs([100 * (r["focal"].focal_px / r["focal_true"] - 1) for r in results if r["focal"] is not None])
    if len(focal):
        lines.append(f"focal from the scene on {len(focal)} of {len(results)}: off {np.median(focal):.1f} % "
                     f"(median; worst {focal.max():.1f} %)")
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
