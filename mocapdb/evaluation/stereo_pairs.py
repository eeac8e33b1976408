"""`mocapdb stereo` on every camera pair of a calibrated take, through the real pipeline
(:func:`mocapdb.stereo.run_stereo`), against what both views saw and a reference person: a Pose2Sim
take's 4-camera TRC (:func:`all_pairs`), or, for keypoint folders without one (e.g. a video's
detections), the person the most views' detections agree on under the calibration's true cameras,
triangulated from all of them (:func:`reference_person`, :func:`calibrated_pairs`).

Per pair: the frames where both views see the person (the detection of each view that lies on the
reference person projected through that camera, left and right as detected or swapped, with at least
``MIN_SHARED_JOINTS`` joints confident in both views: what the matching itself needs), the frames of
those that the main person (track 0) is written for, the joints it writes ``null`` although both views
saw them confidently, the ellipsoid rounds, camera 2's rotation error against the calibration's
relative pose, and MPJPE (camera 1's true pose, the true camera distance given: metres) and PA-MPJPE
against the reference. The calibration's extrinsics serve only the scoring; the run gets the
intrinsics, as a user's would. ``tools/eval_stereo_pairs.py`` prints the table.
"""
from __future__ import annotations

import itertools
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel, intrinsics_only, read_calibration
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.formats.openpose import read_openpose_folder
from mocapdb.core.formats.trc import read_trc, trc_keypoints
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D
from mocapdb.evaluation.metrics import pa_mpjpe
from mocapdb.evaluation.real_take import camera_to_trc, trc_to_world, world_to_trc
from mocapdb.stereo import StereoConfig, StereoError, StereoSummary, run_stereo
from mocapdb.stereo.epipolar_pairs import MIN_SHARED_JOINTS, MIRROR
from mocapdb.stereo.relative_pose import projection_matrix, rotation_angle_deg

TARGET_MISSING = 0.02   # of the frames where both views see the person (issue 19)
ON_PERSON = 0.1         # a detection is the reference person when its confident joints lie within this
#                         share of the projected person's box diagonal (median)


@dataclass
class PairRow:
    """One pair's figures (frames are counts; errors in mm and degrees)."""

    pair: str
    both_see: int            # frames where both views see the person
    reconstructed: int       # of those, frames the main person is written for
    null_seen: int           # joint-frames written null although both views saw the joint
    null_frames: int         # frames written with such a null joint
    null_any_frames: int     # frames written with any null joint (also one a view does not see)
    rounds: int
    converged: bool | None
    last_epsilon: float
    rotation_error_deg: float
    mpjpe_mm: float
    pa_mpjpe_mm: float
    refused: str = ""        # the run's error when `mocapdb stereo` refused the pair (nothing reconstructed)

    @property
    def missing(self) -> float:
        """Share of the frames both views see the person in that are not reconstructed."""
        return 1.0 - self.reconstructed / self.both_see if self.both_see else 0.0


def seen_joints(frames: list[KeypointFrame], cam: CameraModel, truth_world: np.ndarray,
                confidence: float) -> np.ndarray:
    """``[T, 14]``: the joints that each frame's detections of the reference person (``truth_world
    [T, 15, 3]``, metres, NaN where unknown) show with at least ``confidence`` (a body split in two
    detections: both halves); all False where no detection lies on it (:func:`on_body`)."""
    seen = np.zeros((len(frames), N_KEYPOINTS_2D), dtype=bool)
    for t, frame in enumerate(frames):
        for person in frame.people:
            ok = (person.confidence >= confidence) & np.isfinite(person.points_px).all(axis=-1)
            if on_body(person.points_px, ok, truth_world[t, :N_KEYPOINTS_2D], cam) is not None:
                seen[t] |= ok
    return seen


def on_body(points_px: np.ndarray, ok: np.ndarray, body_world: np.ndarray,
            cam: CameraModel) -> tuple[float, bool] | None:
    """How far (median px) a detection ``points_px [14, 2]`` (its confident joints ``ok``, at least 3 of the
    body's) lies from ``body_world [14, 3]`` (metres, NaN where unknown) projected through ``cam``, and
    whether with its left and right swapped (whichever is closer); None when the body is behind the camera
    or the detection is beyond :data:`ON_PERSON` of the projected body's box diagonal."""
    known = np.isfinite(body_world).all(axis=-1)
    if known.sum() < 2 or np.median((body_world[known] @ cam.R.T + cam.t)[:, 2]) <= 0:
        return None
    projected = np.full((N_KEYPOINTS_2D, 2), np.nan)
    projected[known] = cam.project(body_world[known])
    fits = [(float(np.median(np.linalg.norm(points_px[order][both] - projected[both], axis=-1))), mirrored)
            for mirrored, order in enumerate((np.arange(N_KEYPOINTS_2D), MIRROR))
            if (both := ok[order] & known).sum() >= 3]
    best = min(fits, default=None)
    diagonal = np.linalg.norm(np.ptp(projected[known], axis=0))
    return (best[0], bool(best[1])) if best and best[0] <= ON_PERSON * diagonal else None


def score_pair(name: str, folders: tuple[Path, Path], cams: tuple[CameraModel, CameraModel],
               truth_trc: np.ndarray, fps: float) -> PairRow:
    """Run `mocapdb stereo` on one pair (the true camera distance given) and score it (module docstring)."""
    cam1, cam2 = cams
    frames = [list(read_openpose_folder(folder)) for folder in folders]
    config = StereoConfig(camera_distance_m=float(np.linalg.norm(cam1.center_m - cam2.center_m)))
    seen = [seen_joints(f, c, trc_to_world(truth_trc), config.confidence) for f, c in zip(frames, cams)]
    both = seen[0] & seen[1]
    both_see = both.sum(axis=1) >= MIN_SHARED_JOINTS
    try:
        summary, joints, estimated_R = run_pair(folders, cams, config, fps, len(frames[0]))
    except StereoError as exc:
        nan = float("nan")
        return PairRow(name, int(both_see.sum()), 0, 0, 0, 0, 0, None, nan, nan, nan, nan, refused=str(exc))
    written = np.isfinite(joints[:, :N_KEYPOINTS_2D]).all(axis=-1)               # [T, 14]
    present = written.any(axis=1)
    lost = both & present[:, None] & ~written
    eps = summary.epsilons
    return PairRow(name, int(both_see.sum()), int((both_see & present).sum()), int(lost.sum()),
                   int(lost.any(axis=1).sum()), int((present & ~written.all(axis=1)).sum()),
                   len(eps), summary.converged, eps[-1] if eps else float("nan"),
                   rotation_angle_deg(estimated_R @ (cam2.R @ cam1.R.T).T), *joint_errors_mm(joints, truth_trc, cam1))


def run_pair(folders: tuple[Path, Path], cams: tuple[CameraModel, CameraModel], config: StereoConfig, fps: float,
             n_frames: int) -> tuple[StereoSummary, np.ndarray, np.ndarray]:
    """:func:`mocapdb.stereo.run_stereo` on the pair with the cameras' intrinsics only, into a temporary
    folder: its summary, the main person's joints (:func:`main_person_joints`) and camera 2's estimated R."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out"
        summary = run_stereo(folders[0], folders[1], intrinsics_only(cams[0]), intrinsics_only(cams[1]), config, fps,
                             out)
        cameras = json.loads((out / "cameras.json").read_text())["cameras"]
        return summary, main_person_joints(out, n_frames), np.array(cameras[1]["R"])


def joint_errors_mm(joints: np.ndarray, truth_trc: np.ndarray, cam1: CameraModel) -> tuple[float, float]:
    """MPJPE and PA-MPJPE (mm) of ``joints [T, 15, 3]`` (camera 1's camera-aligned frame, NaN where not
    written) against ``truth_trc [T, 15, 3]``, taken to the TRC's frame with camera 1's true pose."""
    pred = camera_to_trc(joints, cam1)
    valid = np.isfinite(pred).all(axis=-1) & np.isfinite(truth_trc).all(axis=-1)
    pa = [pa_mpjpe(pred[f, ok][None], truth_trc[f, ok][None])[0] for f, ok in enumerate(valid) if ok.sum() >= 4]
    return 1000 * float(np.mean(np.linalg.norm(pred - truth_trc, axis=-1)[valid])), 1000 * float(np.mean(pa))


def main_person_joints(out_dir: Path, n_frames: int) -> np.ndarray:
    """Track 0's joints ``[T, 15, 3]`` (camera 1's camera-aligned frame, metres; NaN where not written)
    from ``out_dir/result.jsonl``."""
    joints = np.full((n_frames, N_KEYPOINTS_2D + 1, 3), np.nan)
    for line in (out_dir / "result.jsonl").read_text().splitlines()[1:]:
        record = json.loads(line)
        for person in record["people"]:
            if person["track"] == 0:
                joints[record["frame"]] = np.array(person["joints"], dtype=np.float64)  # null → nan
    return joints


def all_pairs(folder: Path) -> list[PairRow]:
    """Every pair of the take in ``folder`` (``calibration.toml``, ``triangulated_4cam.trc``,
    ``openpose_body25b/camNN_json``)."""
    cams = read_calibration(folder / "calibration.toml")
    trc = read_trc(folder / "triangulated_4cam.trc")
    truth = trc_keypoints(trc)
    rows = []
    for a, b in itertools.combinations(sorted(cams), 2):
        views = folder / "openpose_body25b"
        folders = (views / f"cam{a[-2:]}_json", views / f"cam{b[-2:]}_json")
        rows.append(score_pair(f"{a}–{b}", folders, (cams[a], cams[b]), truth, trc.rate_hz))
    return rows


def calibrated_pairs(folders: list[Path], calibration: Path, names: list[str], fps: float) -> list[PairRow]:
    """Every pair of the keypoint ``folders`` (one per camera ``names[k]`` of ``calibration``), scored
    against :func:`reference_person`."""
    cams = read_calibration(calibration)
    chosen = [cams[name] for name in names]
    truth = world_to_trc(reference_person([list(read_openpose_folder(f)) for f in folders], chosen,
                                          StereoConfig().confidence))
    return [score_pair(f"{names[a]}–{names[b]}", (folders[a], folders[b]), (chosen[a], chosen[b]), truth, fps)
            for a, b in itertools.combinations(range(len(names)), 2)]


def reference_person(views: list[list[KeypointFrame]], cams: list[CameraModel], confidence: float) -> np.ndarray:
    """``[T, 15, 3]`` (the calibration's world, metres; NaN where unknown): in each frame the body that the
    most views' detections lie on (:func:`on_body`) under the cameras' true poses, triangulated from all of
    them (:func:`triangulate_views`; the 15th point the mid-hip). Candidates: each two views' detections
    with at least ``MIN_SHARED_JOINTS`` joints confident in both, triangulated; ties go to the closest."""
    out = np.full((len(views[0]), N_KEYPOINTS_2D + 1, 3), np.nan)
    for t in range(len(views[0])):
        found = [[(p.points_px, (p.confidence >= confidence) & np.isfinite(p.points_px).all(axis=-1))
                  for p in view[t].people] for view in views]
        best: tuple[int, float, np.ndarray] = (1, 0.0, out[t, :N_KEYPOINTS_2D])
        for a, b in itertools.combinations(range(len(views)), 2):
            for (pa, oa), (pb, ob) in itertools.product(found[a], found[b]):
                if (oa & ob).sum() >= MIN_SHARED_JOINTS:
                    body = triangulate_views([pa, pb], [oa & ob] * 2, [cams[a], cams[b]])
                    best = max(best, _support(body, found, cams), key=lambda s: (s[0], -s[1]))
        out[t, :N_KEYPOINTS_2D] = best[2]
    out[:, N_KEYPOINTS_2D] = 0.5 * (out[:, KP["r_hip"]] + out[:, KP["l_hip"]])
    return out


def _support(body: np.ndarray, found: list[list[tuple[np.ndarray, np.ndarray]]],
             cams: list[CameraModel]) -> tuple[int, float, np.ndarray]:
    """How many views have a detection on ``body`` (:func:`on_body`; the closest of each, its left and right
    put the body's way), their summed distance (px), and the body triangulated from all of them."""
    points, seen, chosen, total = [], [], [], 0.0
    for view, cam in zip(found, cams):
        fits = [(fit, k) for k, (px, ok) in enumerate(view) if (fit := on_body(px, ok, body, cam)) is not None]
        if fits:
            (distance, mirrored), k = min(fits)
            order = MIRROR if mirrored else np.arange(N_KEYPOINTS_2D)
            points.append(view[k][0][order])
            seen.append(view[k][1][order])
            chosen.append(cam)
            total += distance
    return len(chosen), total, triangulate_views(points, seen, chosen) if len(chosen) >= 2 else body


def triangulate_views(points: list[np.ndarray], seen: list[np.ndarray], cams: list[CameraModel]) -> np.ndarray:
    """Points ``[..., 3]`` (world, metres) by linear triangulation (DLT) from the views that see them
    (``points[v] [..., 2]`` pixels, ``seen[v] [...]``, camera ``cams[v]``; e.g. ``[14]`` joints of one frame
    or ``[T, J]``); NaN where fewer than two views do."""
    rows = []
    for px, ok, cam in zip(points, seen, cams):
        n = cam.undistort_normalized(np.nan_to_num(px))
        P = projection_matrix(cam.R, cam.t)
        rows.append((n[..., None] * P[2] - P[:2]) * ok[..., None, None])  # [..., 2, 4]: x P₃ − P₁, y P₃ − P₂
    system = np.concatenate(rows, axis=-2)
    valid = np.sum(seen, axis=0) >= 2
    out = np.full(valid.shape + (3,), np.nan)
    homogeneous = np.linalg.svd(system[valid])[2][..., -1, :]
    out[valid] = homogeneous[:, :3] / homogeneous[:, 3:]
    return out


def format_table(rows: list[PairRow]) -> str:
    """Markdown table of the pairs, then a PASS/FAIL line per pair on the missing-frame target."""
    lines = ["| pair | both views see the person | reconstructed | missing | null joints seen by both "
             "(frames) | frames with any null joint | ellipsoid rounds | last ε | converged | rotation error | "
             "MPJPE | PA-MPJPE |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r.pair} | {r.both_see} | {r.reconstructed} | {100 * r.missing:.1f} % | {r.null_seen} "
                     f"({r.null_frames}) | {r.null_any_frames} | {r.rounds} | {r.last_epsilon:.3f} | "
                     f"{_yes(r.converged)} | {r.rotation_error_deg:.2f}° | {r.mpjpe_mm:.1f} mm | "
                     f"{r.pa_mpjpe_mm:.1f} mm |")
    lines.append("")
    lines += [f"{'PASS' if r.missing <= TARGET_MISSING + 1e-9 else 'FAIL'}  {r.pair}: {100 * r.missing:.1f} % of the "
              f"{r.both_see} frames both views see the person missing (target ≤ {100 * TARGET_MISSING:g} %)"
              + (f"; refused: {r.refused}" if r.refused else "") for r in rows]
    return "\n".join(lines)


def _yes(flag: bool | None) -> str:
    return {True: "yes", False: "no", None: "–"}[flag]
