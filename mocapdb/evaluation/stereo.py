"""Accuracy and speed of `mocapdb stereo` (ElliPose): held-out views rendered, scored, tabulated.

Synthetic (Table 1, Table 2): the held-out CMU subject-7 walks (``data_specs/evaluation_split.md``)
on the universal skeleton, seen by two 1000×1000 px pinhole cameras placed like Human3.6M's, with
CNN-like 2D noise (Gaussian σ = 5 px, 2 % of keypoints moved by up to 50 px). Each clip is one
sequence; the camera distance is given (the method's protocol) and the estimate is taken to the
world with the TRUE camera-1 pose (no Procrustes) for MPJPE and PCK; PMPJPE aligns per frame.

Real: every pair of the 4 Pose2Sim cameras (intrinsics and distortion from the calibration, its
extrinsics only to score the estimated relative pose) against the 4-camera triangulation (TRC).

The script ``tools/eval_stereo.py`` prints the tables and the pass/fail lines of the targets.
"""
from __future__ import annotations

import itertools
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TypedDict

import numpy as np

from mocapdb.core.cameras import CameraModel, intrinsics_only, read_calibration_toml
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.trc import read_trc, trc_keypoints
from mocapdb.core.skeleton import N_KEYPOINTS_2D
from mocapdb.evaluation.metrics import mpjpe, pa_mpjpe, pck
from mocapdb.stereo.config import StereoConfig
from mocapdb.stereo.ellipose import reconstruct
from mocapdb.stereo.pipeline import select_people
from mocapdb.stereo.relative_pose import rotation_angle_deg, triangulate

FPS = 60.0                  # the held-out clips are resampled to this rate (Hz)
FOCAL_PX = 1145.0           # Human3.6M's focal length
IMAGE_SIZE = (1000, 1000)
NOISE_PX = 5.0              # Gaussian detector noise, σ
OUTLIER_FRACTION = 0.02     # keypoints moved by a gross error
OUTLIER_PX = 50.0           # up to this far, uniform direction and magnitude
CONFIDENCE = 0.9            # of every rendered keypoint inside the image
WIDE_PAIR_DEG = 60.0        # a real pair is "wide" when its optical axes are at least this far apart
MIN_SCORED_JOINTS = 10      # a real frame is scored over its valid joints when it has this many

# Camera pairs around the subject's mean position: (azimuth° in the floor plane from +x towards
# +z, horizontal distance m, height m) per camera. The walks run along ±z.
PAIRS = {
    # adjacent Human3.6M corners: optical axes ~90° apart
    "side": ((0.0, 4.6, 1.6), (-90.0, 4.9, 1.75)),
    # two cameras 3.5 m apart on the same side of the room, ~4.5 m from the subject (narrow)
    "front": ((-90.0 - 22.9, 4.5, 1.6), (-90.0 + 22.9, 4.5, 1.7)),
}
PCK_MM = (50, 100, 150)
TARGET_CUT = 0.40           # front pair: full method MPJPE at least 40 % below stage 1
TARGET_REAL_PMPJPE_MM = 30.0
TARGET_ROTATION_DEG = 3.0
TARGET_SPEED_S = 2.0        # a 1,000-frame sequence
SPEED_FRAMES = 1000

class StereoChanges(TypedDict, total=False):
    """The :class:`StereoConfig` fields an ablation variant changes."""
    epsilon: float
    delta: float
    gamma: float
    max_rounds: int
    bone_rounds: int
    noise_correction: bool


ABLATION: dict[str, StereoChanges] = {  # Table 2: label → StereoConfig changes
    "ElliPose (ε 0.025, δ 0.2, γ 0.2, m 5)": {},
    "ε 0.01": {"epsilon": 0.01},
    "no ellipsoid correction": {"max_rounds": 0},
    "δ 0.1": {"delta": 0.1},
    "δ 0.3": {"delta": 0.3},
    "γ 1.0": {"gamma": 1.0},
    "m 0 (no bone-length step)": {"bone_rounds": 0},
    "plain ellipsoid fit (the paper: no noise correction)": {"noise_correction": False},
}


# --------------------------------------------------------------------------- synthetic views

def look_at(position: np.ndarray, target: np.ndarray, name: str = "") -> CameraModel:
    """A distortion-free pinhole camera at ``position`` (m, y-up world) looking at ``target``."""
    forward = (target - position) / np.linalg.norm(target - position)
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    rot = np.stack([right, np.cross(forward, right), forward])  # rows: x right, y down, z forward
    k = np.array([[FOCAL_PX, 0.0, IMAGE_SIZE[0] / 2], [0.0, FOCAL_PX, IMAGE_SIZE[1] / 2], [0.0, 0.0, 1.0]])
    return CameraModel(k, np.zeros(5), rot, -rot @ position, IMAGE_SIZE, name)


def pair_cameras(kind: str, target: np.ndarray) -> tuple[CameraModel, CameraModel]:
    """The two cameras of pair ``kind`` looking at ``target`` (the subject's mean position, m)."""
    cams = []
    for i, (azimuth, distance, height) in enumerate(PAIRS[kind]):
        a = np.radians(azimuth)
        position = np.array([target[0] + distance * np.cos(a), height, target[2] + distance * np.sin(a)])
        cams.append(look_at(position, target, f"{kind}_{i + 1}"))
    return cams[0], cams[1]


def render(points_m: np.ndarray, cam: CameraModel, rng: np.random.Generator, noise_px: float = NOISE_PX,
           outlier_fraction: float = OUTLIER_FRACTION) -> tuple[np.ndarray, np.ndarray]:
    """Detections ``[T, 14, 2]`` px (NaN outside the image) and confidences ``[T, 14]`` of ``points_m [T, ≥14, 3]``.

    Gaussian noise ``noise_px`` (σ), and ``outlier_fraction`` of the keypoints moved by up to
    :data:`OUTLIER_PX` in a uniform direction.
    """
    px = cam.project(points_m[:, :N_KEYPOINTS_2D])
    px = px + rng.normal(0.0, noise_px, px.shape)
    gross = rng.random(px.shape[:2]) < outlier_fraction
    angle = rng.uniform(0, 2 * np.pi, px.shape[:2])
    length = rng.uniform(0, OUTLIER_PX, px.shape[:2]) * gross
    px += np.stack([np.cos(angle), np.sin(angle)], axis=-1) * length[..., None]
    depth = (points_m[:, :N_KEYPOINTS_2D] @ cam.R.T + cam.t)[..., 2]
    inside = (depth > 0) & np.all((px >= 0) & (px < np.array(cam.size)), axis=-1)
    return np.where(inside[..., None], px, np.nan), np.where(inside, CONFIDENCE, 0.0)


@dataclass
class Scored:
    """Aligned estimates and truth over all frames scored, world metres ``[F, 14, 3]``."""

    stage1: np.ndarray
    full: np.ndarray
    true: np.ndarray
    frames: int
    seconds: float

    def row(self) -> dict[str, float]:
        """MPJPE of stage 1 and of the full method (mm), the cut, PMPJPE (mm) and PCK (%) per threshold."""
        s1, full = mpjpe(self.stage1, self.true).mean(), mpjpe(self.full, self.true).mean()
        out = {"stage1": 1000 * s1, "full": 1000 * full, "cut": 1 - full / s1,
               "pmpjpe": 1000 * pa_mpjpe(self.full, self.true).mean()}
        out.update({f"pck{m}": 100 * pck(self.full, self.true, m / 1000) for m in PCK_MM})
        return out


def load_held_out(folder: Path, quick: bool = False) -> list[tuple[str, np.ndarray]]:
    """Subject 7's clips of the BVH ``folder`` on the universal skeleton at :data:`FPS`: (name,
    positions ``[F, 15, 3]`` m); the first 3 only when ``quick``. SystemExit when there are none."""
    files = sorted(folder.glob("007_*.bvh"))[: 3 if quick else None]
    if not files:
        raise SystemExit(f"no held-out clips in {folder}")
    return [(f.stem, process_clip(f, folder, ClipOptions(fps=FPS)).positions.astype(np.float64)) for f in files]


def to_world(points_cam: np.ndarray, cam1: CameraModel) -> np.ndarray:
    """Camera-1 coordinates → world with the true camera-1 pose."""
    return (points_cam - cam1.t) @ cam1.R


def score_pair(clips: list[tuple[str, np.ndarray]], kind: str, config: StereoConfig, seed: int = 0) -> Scored:
    """Reconstruct every clip seen by pair ``kind``; frames where every joint is valid are scored."""
    rng = np.random.default_rng(seed)
    parts: list[tuple[np.ndarray, ...]] = []
    seconds = 0.0
    for _, positions in clips:
        cam1, cam2 = pair_cameras(kind, positions.mean(axis=(0, 1)))
        (x1, c1), (x2, c2) = render(positions, cam1, rng), render(positions, cam2, rng)
        run = replace(config, camera_distance_m=float(np.linalg.norm(cam1.center_m - cam2.center_m)))
        t0 = time.perf_counter()
        result = reconstruct(x1, c1, x2, c2, cam1, cam2, run)
        seconds += time.perf_counter() - t0
        ok = result.valid.all(axis=1) & np.isfinite(result.stage1_points).all(axis=(1, 2))
        parts.append((to_world(result.stage1_points[ok], cam1), to_world(result.points_m[ok], cam1),
                      positions[ok, :N_KEYPOINTS_2D]))
    stage1, full, true = (np.concatenate(p) for p in zip(*parts))
    return Scored(stage1, full, true, len(true), seconds)


# --------------------------------------------------------------------------- tables

def table1(clips: list[tuple[str, np.ndarray]], kinds: list[str]) -> tuple[str, dict[str, dict[str, float]]]:
    """Markdown Table 1 (stage 1 against the full method per pair) and its rows."""
    rows = {}
    lines = ["| pair | frames | stage-1 MPJPE | ElliPose MPJPE | MPJPE cut | ElliPose PMPJPE | "
             + " | ".join(f"PCK@{m}" for m in PCK_MM) + " | time |",
             "|---|---|---|---|---|---|" + "---|" * len(PCK_MM) + "---|"]
    for kind in kinds:
        scored = score_pair(clips, kind, StereoConfig())
        r = rows[kind] = scored.row()
        lines.append(f"| {kind} | {scored.frames} | {r['stage1']:.1f} | {r['full']:.1f} | {100 * r['cut']:.0f} % | "
                     f"{r['pmpjpe']:.1f} | " + " | ".join(f"{r[f'pck{m}']:.1f}" for m in PCK_MM)
                     + f" | {scored.seconds:.1f} s |")
    return "\n".join(lines), rows


def table2(clips: list[tuple[str, np.ndarray]], kinds: list[str]) -> str:
    """Markdown Table 2: MPJPE (mm) of each ablation variant per pair."""
    lines = ["| variant | " + " | ".join(f"{k} MPJPE" for k in kinds) + " |", "|---|" + "---|" * len(kinds)]
    for label, change in ABLATION.items():
        cells = [f"{score_pair(clips, k, StereoConfig(**change)).row()['full']:.1f}" for k in kinds]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def real_pairs(folder: Path) -> tuple[str, list[str]]:
    """Markdown table of the six pairs of the Pose2Sim take in ``folder`` (``calibration.toml``,
    ``triangulated_4cam.trc``, ``openpose_body25b/camNN_json``) and the pass/fail lines of the real targets.

    "calibrated" is the floor a two-camera reconstruction of these detections can reach: the same
    keypoints triangulated with the calibration's own relative pose.
    """
    cams = read_calibration_toml(folder / "calibration.toml")
    truth = trc_keypoints(read_trc(folder / "triangulated_4cam.trc"))[:, :N_KEYPOINTS_2D]
    frames = {n: list(read_openpose_folder(folder / "openpose_body25b" / f"cam{n[-2:]}_json")) for n in cams}
    lines = [("| pair | axes apart | frames | PMPJPE | PMPJPE, calibrated | rotation error stage 1 → final | "
              "baseline direction error | kept round |"),
             "|---|---|---|---|---|---|---|---|"]
    checks = []
    for a, b in itertools.combinations(sorted(cams), 2):
        r = _real_pair(cams[a], cams[b], frames[a], frames[b], truth)
        lines.append(f"| {a}–{b} | {r['apart']:.0f}° | {r['frames']} | {r['pmpjpe']:.1f} mm | {r['floor']:.1f} mm | "
                     f"{r['rot1']:.2f}° → {r['rot']:.2f}° | {r['dir']:.2f}° | {r['round']} |")
        if r["apart"] >= WIDE_PAIR_DEG:
            checks.append(check_line(f"real {a}–{b} (wide) PMPJPE {r['pmpjpe']:.1f} mm ≤ {TARGET_REAL_PMPJPE_MM:g} mm "
                                     f"(calibrated two-view: {r['floor']:.1f} mm)",
                                     r["pmpjpe"] <= TARGET_REAL_PMPJPE_MM))
        checks.append(check_line(f"real {a}–{b} rotation error {r['rot']:.2f}° ≤ {TARGET_ROTATION_DEG:g}°",
                                 r["rot"] <= TARGET_ROTATION_DEG))
    return "\n".join(lines), checks


def _real_pair(cam1: CameraModel, cam2: CameraModel, frames1: list, frames2: list,
               truth: np.ndarray) -> dict[str, float]:
    """One real pair: selection, reconstruction with the true camera distance, scores."""
    rel_rot = cam2.R @ cam1.R.T
    rel_t = cam2.t - rel_rot @ cam1.t
    config = StereoConfig(camera_distance_m=float(np.linalg.norm(rel_t)))
    c1, c2 = intrinsics_only(cam1), intrinsics_only(cam2)
    sel = select_people(frames1, frames2, c1, c2, config)
    result = reconstruct(sel.x1, sel.c1, sel.x2, sel.c2, c1, c2, config)
    valid = result.valid & sel.kept[:, None] & np.isfinite(truth).all(axis=-1)
    calibrated = np.full(valid.shape + (3,), np.nan)
    calibrated[valid] = triangulate(np.hstack([np.eye(3), np.zeros((3, 1))]), np.hstack([rel_rot, rel_t[:, None]]),
                                    c1.undistort_normalized(sel.x1[valid]), c2.undistort_normalized(sel.x2[valid]))
    cos_dir = np.dot(result.t, rel_t) / (np.linalg.norm(result.t) * np.linalg.norm(rel_t))
    return {"apart": float(np.degrees(np.arccos(np.clip(cam1.R[2] @ cam2.R[2], -1, 1)))),
            "frames": int(np.sum(valid.sum(axis=1) >= MIN_SCORED_JOINTS)),
            "pmpjpe": 1000 * float(np.mean(masked_pa_mpjpe(result.points_m, truth, valid))),
            "floor": 1000 * float(np.mean(masked_pa_mpjpe(calibrated, truth, valid))),
            "rot1": rotation_angle_deg(np.asarray(result.stage1_R) @ rel_rot.T),
            "rot": rotation_angle_deg(np.asarray(result.R) @ rel_rot.T),
            "dir": float(np.degrees(np.arccos(np.clip(cos_dir, -1, 1)))), "round": int(result.kept_round)}


def masked_pa_mpjpe(pred: np.ndarray, true: np.ndarray, valid: np.ndarray,
                    min_joints: int = MIN_SCORED_JOINTS) -> np.ndarray:
    """PMPJPE (m) of each frame with at least ``min_joints`` valid joints, over those joints only."""
    return np.array([pa_mpjpe(pred[f, m][None], true[f, m][None])[0]
                     for f, m in enumerate(valid) if m.sum() >= min_joints])


def speed(clips: list[tuple[str, np.ndarray]]) -> tuple[float, int]:
    """Seconds to reconstruct one sequence of :data:`SPEED_FRAMES` frames (side pair), and its length."""
    positions = np.concatenate([p for _, p in clips])
    positions = np.concatenate([positions] * int(np.ceil(SPEED_FRAMES / len(positions))))[:SPEED_FRAMES]
    cam1, cam2 = pair_cameras("side", positions.mean(axis=(0, 1)))
    rng = np.random.default_rng(1)
    (x1, c1), (x2, c2) = render(positions, cam1, rng), render(positions, cam2, rng)
    config = StereoConfig(camera_distance_m=float(np.linalg.norm(cam1.center_m - cam2.center_m)))
    reconstruct(x1[:100], c1[:100], x2[:100], c2[:100], cam1, cam2, config)  # compile numba kernels, if any
    t0 = time.perf_counter()
    reconstruct(x1, c1, x2, c2, cam1, cam2, config)
    return time.perf_counter() - t0, len(positions)


def check_line(text: str, ok: bool) -> str:
    """A pass/fail line: ``PASS  text`` or ``FAIL  text``."""
    return f"{'PASS' if ok else 'FAIL'}  {text}"
