"""A pose detector's 2D quality without 2D ground truth (issue 28, item 5): the keypoints of one
detector on every camera of a calibrated take, triangulated, and re-projected.

Per frame the main person is the body most views' detections lie on under the calibration's cameras
(:func:`mocapdb.evaluation.stereo_pairs.reference_person`: a bystander seen by fewer views loses);
each view's detection closest to it (:func:`~mocapdb.evaluation.stereo_pairs.on_body`) is taken as
the detector gave it (a left-right swap is not undone: it is the detector's error, and is counted).
Each compared joint (:data:`BODY_JOINTS`, and :data:`FOOT_JOINTS` where the layout has them) is
triangulated by DLT (:func:`~mocapdb.evaluation.stereo_pairs.triangulate_views`) from the views
where its confidence is above the threshold, when at least two are; the residual of a view is the
distance (px) from its detection to the triangulated point projected through its calibrated camera
(lens distortion included). With two views a residual has one degree of freedom left, with four
five: a joint seen by fewer views shows a smaller residual for the same detector noise. Residuals are
also given as % of the body height in that view: the projected nose to the mid-ankle (pixels).

The reconstruction from camera 1 alone (``mocapdb reconstruct --floor --people main`` with the
calibration's focal length): its main track's planted-foot slide, the horizontal speed of its ankles
(cm/s) in the frames where a 4-view triangulation's ankles are planted
(:func:`mocapdb.evaluation.metrics.planted_feet`, as :func:`mocapdb.evaluation.real_take.score` does
against a TRC), and its mean joint acceleration (m/s²). The planted frames are the same for every
detector: those of the detector with the smallest body residual, its triangulation low-passed at
:data:`LOW_PASS_HZ` first (raw, a 20 px detector noise moves a triangulated ankle faster than a
planted foot goes). The 2D jitter of each view's detections (mean frame-to-frame acceleration,
px/frame²) is the figure issue 28 quotes for YOLO11n-pose on camera 1.
"""
from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt

from mocapdb.core.cameras import CameraModel
from mocapdb.core.errors import UsageError
from mocapdb.core.formats.keypoint_layouts import LAYOUTS, SOURCE_INDEX
from mocapdb.core.formats.keypoints import CONFIDENCE_THRESHOLD, KeypointFrame, RawPerson
from mocapdb.core.formats.openpose import read_openpose_folder, read_raw_folder
from mocapdb.core.formats.take import read_take
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D
from mocapdb.evaluation.metrics import foot_skating_mps, planted_feet
from mocapdb.evaluation.real_take import focal_px, world_to_trc
from mocapdb.evaluation.stereo_pairs import on_body, reference_person, triangulate_views
from mocapdb.render.tracks import read_csv_joints, read_world, track_file_names

# Compared joints: the body joints every layout has (universal names; "nose" is the universal head) …
BODY_JOINTS = ("nose", "r_shoulder", "l_shoulder", "r_elbow", "l_elbow", "r_wrist", "l_wrist",
               "r_hip", "l_hip", "r_knee", "l_knee", "r_ankle", "l_ankle")
# … and the foot points, under each layout's own names (the first the layout has).
FOOT_JOINTS = {"r_heel": ("right_heel", "RHeel"), "l_heel": ("left_heel", "LHeel"),
               "r_toe": ("right_foot_index", "right_big_toe", "RBigToe"),
               "l_toe": ("left_foot_index", "left_big_toe", "LBigToe")}
LOW_PASS_HZ = 6.0  # the triangulation's low-pass before its planted feet and acceleration are taken


@dataclass
class Detections:
    """One detector on every camera: the layout, the main person's compared ``joints``,
    ``points_px [V, T, J, 2]`` and ``confidence [V, T, J]`` (0 where the view has no main person),
    and per view and frame whether the best fit to the main person was mirrored ``[V, T]``."""

    layout: str
    joints: tuple[str, ...]
    points_px: np.ndarray
    confidence: np.ndarray
    mirrored: np.ndarray


def joint_sources(layout: str) -> dict[str, int]:
    """Each compared joint the layout has → its index in the layout's keypoints."""
    body = {name: SOURCE_INDEX[layout][KP["head" if name == "nose" else name]] for name in BODY_JOINTS}
    names = LAYOUTS[layout]
    feet = {joint: names.index(next(n for n in options if n in names))
            for joint, options in FOOT_JOINTS.items() if any(n in names for n in options)}
    return {name: index for name, index in (body | feet).items() if index >= 0}


def read_views(folders: list[Path]) -> tuple[list[list[KeypointFrame]], list[list[list[RawPerson]]], str]:
    """Every camera's frames (universal 14, the project's reader), the same people as the files hold
    them, and the layout; UsageError when the cameras' frame counts or layouts differ."""
    frames = [list(read_openpose_folder(folder)) for folder in folders]
    raw = [read_raw_folder(folder) for folder in folders]
    counts = {str(folder): len(f) for folder, f in zip(folders, frames)}
    if len(set(counts.values())) > 1:
        raise UsageError(f"the cameras' frame counts differ ({counts}): the frames must correspond one to one")
    layouts = {f.layout for view in frames for f in view if f.people}
    layout = next(iter(layouts)) if len(layouts) == 1 else None
    if layout is None:
        raise UsageError(f"the folders {', '.join(counts)} do not hold one keypoint layout ({layouts})")
    return frames, raw, layout


def choose_people(frames: list[list[KeypointFrame]], cams: list[CameraModel], confidence: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per view and frame ``[V, T]`` the index of the detection on the main person (-1: none) and
    whether it fits mirrored (module docstring)."""
    body = reference_person(frames, cams, confidence)[:, :N_KEYPOINTS_2D]
    chosen = np.full((len(frames), len(frames[0])), -1)
    mirrored = np.zeros(chosen.shape, dtype=bool)
    for v, (view, cam) in enumerate(zip(frames, cams)):
        for t, frame in enumerate(view):
            fits = [(fit, k) for k, p in enumerate(frame.people)
                    if (fit := on_body(p.points_px, p.confidence >= confidence, body[t], cam)) is not None]
            if fits:
                (_, mirrored[v, t]), chosen[v, t] = min(fits)
    return chosen, mirrored


def read_detections(folders: list[Path], cams: list[CameraModel], confidence: float) -> Detections:
    """One detector's keypoint folders (one per camera of ``cams``, frames aligned) → its main person's
    compared joints in every view."""
    frames, raw, layout = read_views(folders)
    chosen, mirrored = choose_people(frames, cams, confidence)
    sources = joint_sources(layout)
    index = np.array(list(sources.values()))
    empty = np.zeros((len(index), 3))
    picked = np.array([[view[t][k].raw[index] if k >= 0 else empty for t, k in enumerate(ks)]
                       for view, ks in zip(raw, chosen)])                          # [V, T, J, 3]
    ok = np.isfinite(picked).all(axis=-1) & (picked[..., 2] > 0)
    return Detections(layout, tuple(sources), np.where(ok[..., None], picked[..., :2], np.nan),
                      np.where(ok, picked[..., 2], 0.0), mirrored)


def project_all(points_m: np.ndarray, cams: list[CameraModel]) -> np.ndarray:
    """World points ``[T, J, 3]`` (metres, NaN where unknown) in every camera ``[V, T, J, 2]`` (px)."""
    known = np.isfinite(points_m).all(axis=-1, keepdims=True)
    return np.array([np.where(known, cam.project(np.nan_to_num(points_m)), np.nan) for cam in cams])


def residuals(det: Detections, cams: list[CameraModel], confidence: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The triangulated joints ``[T, J, 3]`` (world, metres), each view's residual vectors
    ``[V, T, J, 2]`` (px; NaN where the view did not take part) and its body height ``[V, T]`` (px)."""
    seen = det.confidence > confidence
    joints_m = triangulate_views(list(det.points_px), list(seen), cams)
    projected = project_all(joints_m, cams)
    offset = np.where(seen[..., None], det.points_px - projected, np.nan)
    nose, ankles = det.joints.index("nose"), [det.joints.index("r_ankle"), det.joints.index("l_ankle")]
    height_px = np.linalg.norm(projected[:, :, nose] - projected[:, :, ankles].mean(axis=2), axis=-1)
    return joints_m, offset, height_px


def _stats(px: np.ndarray, pct: np.ndarray) -> dict:
    """Median and mean of residuals (px) and of their shares of the body height (%), NaN ignored."""
    px, pct = px[np.isfinite(px)], pct[np.isfinite(pct)]
    return {"observations": int(px.size),
            "median_px": float(np.median(px)) if px.size else None, "mean_px": float(np.mean(px)) if px.size else None,
            "median_pct": float(np.median(pct)) if pct.size else None,
            "mean_pct": float(np.mean(pct)) if pct.size else None}


def jitter_px(points_px: np.ndarray) -> float:
    """Mean frame-to-frame acceleration ``|p[t+1] − 2 p[t] + p[t−1]|`` (px/frame²) of ``[T, J, 2]``."""
    acc = np.linalg.norm(points_px[2:] - 2 * points_px[1:-1] + points_px[:-2], axis=-1)
    return float(np.nanmean(acc)) if np.isfinite(acc).any() else float("nan")


def acceleration_mps2(points_m: np.ndarray, fps: float) -> float:
    """Mean joint acceleration (m/s²) of ``[T, J, 3]`` (metres; NaN frames left out)."""
    return jitter_px(points_m) * fps ** 2


def quality(det: Detections, cams: list[CameraModel], confidence: float) -> tuple[dict, np.ndarray]:
    """The residual figures of ``det`` (a JSON-able dict: per joint, the body joints together, the feet
    together, per camera) and the triangulated joints ``[T, J, 3]`` (world, metres)."""
    joints_m, offset, height_px = residuals(det, cams, confidence)
    px = np.linalg.norm(offset, axis=-1)
    pct = 100 * px / height_px[..., None]
    body = [det.joints.index(j) for j in BODY_JOINTS]
    feet = [i for i, j in enumerate(det.joints) if j in FOOT_JOINTS]
    views = np.isfinite(px).sum(axis=0)
    per_camera: dict[str, dict] = {}
    report = {"layout": det.layout, "joints": {j: _stats(px[..., i], pct[..., i]) | {
        "mean_views": float(views[..., i][views[..., i] >= 2].mean()) if (views[..., i] >= 2).any() else None}
        for i, j in enumerate(det.joints)},
        "body": _stats(px[..., body], pct[..., body]), "feet": _stats(px[..., feet], pct[..., feet]) if feet else None,
        "frames_triangulated": int(np.isfinite(joints_m[:, body]).all(axis=-1).any(axis=-1).sum()),
        "frames": int(px.shape[1]), "cameras": per_camera}
    for v, cam in enumerate(cams):
        per_camera[cam.name] = _stats(px[v][:, body], pct[v][:, body]) | {
            "mean_offset_px": np.nanmean(offset[v][:, body].reshape(-1, 2), axis=0).tolist(),
            "jitter_px_per_frame2": jitter_px(det.points_px[v][:, body]),
            "frames_with_person": int((det.confidence[v] > 0).any(axis=-1).sum()),
            "frames_mirrored": int(det.mirrored[v].sum())}
    return report, joints_m


def reconstruct(folder: Path, db: Path, out: Path, cam: CameraModel, fps: float) -> None:
    """``mocapdb reconstruct`` of one camera's folder into ``out`` (main track, CSV, on the floor) with
    ``cam``'s focal length (and its image size and ``fps`` where the folder has no take.json)."""
    command = [sys.executable, "-m", "mocapdb", "reconstruct", str(folder), "--db", str(db), "--out", str(out),
               "--format", "csv", "--floor", "--people", "main", "--focal", f"{focal_px(cam):.2f}", "-q"]
    take = read_take(folder)
    if take is None or take.image_size is None:
        command += ["--image-size", f"{cam.size[0]}x{cam.size[1]}"]
    if take is None or take.fps is None:
        command += ["--fps", f"{fps:g}"]
    subprocess.run(command, check=True)


def main_track_joints(out: Path, frames: int) -> np.ndarray:
    """The main track's joints ``[T, 15, 3]`` (floor frame, y up, metres; NaN where it has none) of
    a reconstruction folder (its ``world.json`` names the track, its CSV files hold it)."""
    world = read_world(out)
    if world is None or world.main_track is None:
        raise UsageError(f"{out}: no world.json naming the main track")
    joints = np.full((frames, len(KP), 3), np.nan)
    for files in track_file_names(out)[world.main_track].values():
        index, points = read_csv_joints(files["csv"])
        keep = (index >= 0) & (index < frames)
        joints[index[keep]] = points[keep]
    return joints


def low_pass(points: np.ndarray, fps: float, cutoff_hz: float = LOW_PASS_HZ) -> np.ndarray:
    """``points [T, ...]`` through a zero-phase 4th-order Butterworth low-pass (as Pose2Sim filters its
    TRC), gaps bridged linearly for the filter and left NaN after it."""
    flat = points.reshape(len(points), -1)
    known = np.isfinite(flat)
    frames = np.arange(len(points))
    filled = np.array([np.interp(frames, frames[k], c[k]) if k.any() else c for c, k in zip(flat.T, known.T)]).T
    b, a = butter(4, cutoff_hz / (fps / 2))
    return np.where(known, filtfilt(b, a, filled, axis=0, padlen=min(3 * len(b), len(points) - 1)),
                    np.nan).reshape(points.shape)


def planted_reference(triangulated_m: np.ndarray, joints: tuple[str, ...], fps: float) -> np.ndarray:
    """Which ankles ``[T, 2]`` (right, left) are planted: :func:`~mocapdb.evaluation.metrics.planted_feet`
    of a triangulation ``[T, J, 3]`` (world, z up; ``joints`` its names) low-passed (:func:`low_pass`)."""
    ankles = world_to_trc(triangulated_m[:, [joints.index("r_ankle"), joints.index("l_ankle")]])
    return planted_feet(low_pass(ankles, fps), fps)


def motion_figures(rec_m: np.ndarray, planted: np.ndarray, fps: float) -> dict:
    """Planted-foot slide (cm/s: the horizontal speed of the ankles where ``planted [T, 2]``) and mean
    joint acceleration (m/s²) of the reconstruction ``rec_m [T, 15, 3]`` (floor frame, y up)."""
    slide = 100 * foot_skating_mps(rec_m[:, [KP["r_ankle"], KP["l_ankle"]]], planted, fps)
    return {"frames_with_output": int(np.isfinite(rec_m).all(axis=(1, 2)).sum()),
            "planted_ankle_frames": int(slide.size),
            "slide_cm_per_s": {"mean": float(np.mean(slide)) if slide.size else None,
                               "median": float(np.median(slide)) if slide.size else None},
            "acceleration_mps2": acceleration_mps2(rec_m, fps)}


def _cell(stats: dict | None) -> str:
    if not stats or stats["median_px"] is None:
        return "–"
    views = f", {stats['mean_views']:.1f} views" if stats.get("mean_views") else ""
    return (f"{stats['median_px']:.1f} / {stats['mean_px']:.1f} px "
            f"({stats['median_pct']:.2f} / {stats['mean_pct']:.2f} %{views})")


def format_table(report: dict) -> str:
    """A markdown table of :func:`evaluate`'s ``report``: a row per joint, a column per detector
    (median / mean residual, px and % of the body height; the mean number of views it was triangulated
    from), then the reconstructions' figures."""
    names = list(report["detectors"])
    joints = list(BODY_JOINTS) + [j for j in FOOT_JOINTS if any(j in d["joints"] for d in report["detectors"].values())]
    lines = ["| joint | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    rows = [(j, [d["joints"].get(j) for d in report["detectors"].values()]) for j in joints]
    rows += [("**body (13)**", [d["body"] for d in report["detectors"].values()]),
             ("**feet**", [d["feet"] for d in report["detectors"].values()])]
    lines += [f"| {label} | " + " | ".join(_cell(s) for s in cells) + " |" for label, cells in rows]
    for name, d in report["detectors"].items():
        cams = ", ".join(f"{c} {s['median_px']:.1f} px, offset ({s['mean_offset_px'][0]:+.1f}, "
                         f"{s['mean_offset_px'][1]:+.1f}), jitter {s['jitter_px_per_frame2']:.1f} px/frame², "
                         f"mirrored {s['frames_mirrored']}" for c, s in d["cameras"].items())
        lines += ["", f"{name} ({d['layout']}): {d['frames_triangulated']}/{d['frames']} frames triangulated; "
                      f"per camera (body joints, median): {cams}"]
        rec = d.get("reconstruction")
        if rec:
            slide = rec["slide_cm_per_s"]
            lines.append(f"{name}, camera 1 alone through `mocapdb reconstruct`: {rec['frames_with_output']} frames; "
                         f"planted-foot slide {_number(slide['mean'])} cm/s mean, {_number(slide['median'])} median "
                         f"over {rec['planted_ankle_frames']} planted ankle-frames; mean joint acceleration "
                         f"{rec['acceleration_mps2']:.1f} m/s² (the 4-view triangulation low-passed at "
                         f"{LOW_PASS_HZ:g} Hz: {d['triangulation_acceleration_mps2']:.1f} m/s²)")
    planted = report["planted_from"]
    lines += ["", f"Planted ankles ({planted['ankle_frames']} ankle-frames) from {planted['detector']}'s 4-view "
                  f"triangulation (the smallest body residual), low-passed at {LOW_PASS_HZ:g} Hz."]
    return "\n".join(lines)


def _number(value: float | None) -> str:
    return "–" if value is None else f"{value:.1f}"


def evaluate(detectors: dict[str, list[Path]], cams: list[CameraModel], fps: float,
             confidence: float = CONFIDENCE_THRESHOLD, db: Path | None = None, work: Path | None = None) -> dict:
    """Every detector (name → one keypoint folder per camera of ``cams``, camera 1 first) scored
    (:func:`quality`); with a database ``db`` also camera 1 reconstructed into ``work/<name>`` and
    its motion scored (:func:`motion_figures`)."""
    per_detector: dict[str, dict] = {}
    report = {"fps": fps, "confidence": confidence, "cameras": [c.name for c in cams], "detectors": per_detector}
    triangulated: dict[str, tuple[np.ndarray, tuple[str, ...]]] = {}
    for name, folders in detectors.items():
        det = read_detections(folders, cams, confidence)
        entry, joints_m = quality(det, cams, confidence)
        per_detector[name] = entry
        triangulated[name] = (joints_m, det.joints)
    reference = min(per_detector, key=lambda n: per_detector[n]["body"]["median_px"] or np.inf)
    planted = planted_reference(*triangulated[reference], fps)
    report["planted_from"] = {"detector": reference, "ankle_frames": int(planted.sum())}
    for name, folders in detectors.items():
        joints_m, names = triangulated[name]
        body = low_pass(joints_m[:, [names.index(j) for j in BODY_JOINTS]], fps)
        per_detector[name]["triangulation_acceleration_mps2"] = acceleration_mps2(body, fps)
        if db is not None and work is not None:
            reconstruct(folders[0], db, work / name, cams[0], fps)
            per_detector[name]["reconstruction"] = motion_figures(
                main_track_joints(work / name, len(joints_m)), planted, fps)
    return report
