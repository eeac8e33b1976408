"""The head's rotation on a real take: each camera's humanoid BVH against the calibrated cameras'
triangulation of the detector's own face points (``tools/eval_head.py``; ``data_specs/head.md``).

Reference: in each frame the main person's nose, ears and shoulders and hips, seen by every camera
(BlazePose folders made by ``mocapdb detect``), triangulated by DLT. The chest frame: up from the
hips' to the shoulders' mid-point, x along right → left shoulder (made perpendicular), z = x × y
(forwards). The head frame: x along right → left ear, z from the ears' mid-point to the nose
(made perpendicular to x), y = z × x. The head relative to the chest, ``Rc⁻¹ Rh``, as intrinsic
Y-X-Z angles: the **turn** (about the chest's up, positive to the subject's left), the **nod**
(about the ear axis, positive chin down) and the **tilt** (about the face's forward axis).

Estimate: the BVH's ``Head`` global rotation against its ``Spine1`` (the chest: the shoulders are
rigid with it), the same angles. Both frames face +z at rest, so the angles compare directly; the
nod's zero differs by a convention (the ear → nose line is not the skull's rest), so the nod is
scored about its mean offset, the turn and tilt as they are (with their offset reported).
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import CameraModel
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.core.formats.keypoint_layouts import LAYOUTS
from mocapdb.core.formats.openpose import read_openpose_folder, read_raw_folder
from mocapdb.core.geometry import matrix_to_euler
from mocapdb.evaluation.detector_quality import choose_people
from mocapdb.evaluation.stereo_pairs import triangulate_views

ANGLES = ("turn", "nod", "tilt")
# BlazePose points of the reference (mediapipe33 names) and their partner in a mirrored detection
REFERENCE_POINTS = ("nose", "right_ear", "left_ear", "right_shoulder", "left_shoulder", "right_hip", "left_hip")
_PARTNER = {"nose": "nose", **{f"{a}_{p}": f"{b}_{p}" for a, b in (("right", "left"), ("left", "right"))
                               for p in ("ear", "shoulder", "hip", "heel", "foot_index")}}
CONFIDENCE = 0.5  # a point takes part in the triangulation from this BlazePose visibility


@dataclass
class HeadScore:
    """One camera's head angles against the reference: per angle (:data:`ANGLES`) the RMS error
    (degrees; the nod's about its mean offset), the mean offset (estimate − reference), Pearson's r
    and the reference's own SD (its movement), over ``frames`` frames seen by both."""

    rms_deg: dict[str, float]
    offset_deg: dict[str, float]
    r: dict[str, float]
    reference_sd_deg: dict[str, float]
    frames: int


def triangulated_points(folders: list[Path], cams: list[CameraModel],
                        names: tuple[str, ...] = REFERENCE_POINTS) -> np.ndarray:
    """``[T, N, 3]`` (calibration world, metres; NaN where fewer than two views see a point): the main
    person's ``names`` (mediapipe33; :data:`REFERENCE_POINTS`, or others with a partner in a mirrored
    detection) from BlazePose folders (one per camera, frames aligned)."""
    frames = [list(read_openpose_folder(folder)) for folder in folders]
    raw = [read_raw_folder(folder) for folder in folders]
    chosen, mirrored = choose_people(frames, cams, CONFIDENCE)
    layout = LAYOUTS["mediapipe33"]
    straight = np.array([layout.index(n) for n in names])
    swapped = np.array([layout.index(_PARTNER[n]) for n in names])
    points = np.full((len(cams), len(frames[0]), len(names), 3), np.nan)
    for v in range(len(cams)):
        for t, k in enumerate(chosen[v]):
            if k >= 0:
                points[v, t] = raw[v][t][k].raw[swapped if mirrored[v, t] else straight]
    seen = np.isfinite(points).all(axis=-1) & (points[..., 2] >= CONFIDENCE)
    return triangulate_views(list(points[..., :2]), list(seen), cams)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def frame_from_x_and_hint(x: np.ndarray, hint: np.ndarray, hint_axis: str) -> np.ndarray:
    """Rotations ``[..., 3, 3]`` (columns: the frame's x, y, z) with x along ``x`` and ``hint`` (its y
    or z, ``hint_axis``) made perpendicular to it; right-handed."""
    x = _unit(x)
    second = _unit(hint - np.sum(hint * x, axis=-1, keepdims=True) * x)
    if hint_axis == "y":
        return np.stack([x, second, np.cross(x, second)], axis=-1)
    return np.stack([x, np.cross(second, x), second], axis=-1)


def reference_angles(points_m: np.ndarray) -> np.ndarray:
    """``[T, 3]`` turn, nod, tilt (degrees) of triangulated :data:`REFERENCE_POINTS` ``[T, 7, 3]``."""
    nose, r_ear, l_ear, r_sh, l_sh, r_hip, l_hip = np.moveaxis(points_m, 1, 0)
    chest = frame_from_x_and_hint(l_sh - r_sh, 0.5 * (l_sh + r_sh) - 0.5 * (l_hip + r_hip), "y")
    head = frame_from_x_and_hint(l_ear - r_ear, nose - 0.5 * (l_ear + r_ear), "z")
    return relative_angles(chest, head)


def relative_angles(chest: np.ndarray, head: np.ndarray) -> np.ndarray:
    """``[T, 3]`` turn, nod, tilt (degrees): ``chest⁻¹ head`` ([T, 3, 3] global rotations) as
    intrinsic Y-X-Z angles."""
    return matrix_to_euler(np.swapaxes(chest, -1, -2) @ head, "YXZ")


def bvh_angles(path: Path) -> np.ndarray:
    """``[F, 3]`` turn, nod, tilt (degrees) of a humanoid BVH's ``Head`` against its ``Spine1``."""
    bvh = read_bvh(path)
    _, rotations = forward_kinematics(bvh, [bvh.names.index("Spine1"), bvh.names.index("Head")])
    return relative_angles(rotations[:, 0], rotations[:, 1])


def score(estimate_deg: np.ndarray, reference_deg: np.ndarray) -> HeadScore:
    """``estimate_deg`` against ``reference_deg`` (both ``[T, 3]``, NaN where unknown)."""
    both = np.isfinite(estimate_deg).all(axis=1) & np.isfinite(reference_deg).all(axis=1)
    est, ref = estimate_deg[both], reference_deg[both]
    error = est - ref
    offset = error.mean(axis=0)
    centred = [False, True, False]
    rms = {a: float(np.sqrt(np.mean((error[:, i] - (offset[i] if centred[i] else 0.0)) ** 2)))
           for i, a in enumerate(ANGLES)}
    r = {a: float(np.corrcoef(est[:, i], ref[:, i])[0, 1]) for i, a in enumerate(ANGLES)}
    return HeadScore(rms, {a: float(offset[i]) for i, a in enumerate(ANGLES)}, r,
                     {a: float(ref[:, i].std()) for i, a in enumerate(ANGLES)}, int(both.sum()))


def format_table(scores: dict[str, HeadScore]) -> str:
    """A Markdown table of every camera's :class:`HeadScore`."""
    lines = ["| camera | frames | turn RMS / r / offset | nod RMS (centred) / r | tilt RMS / r | reference SD turn, "
             "nod, tilt |", "|---|---|---|---|---|---|"]
    for name, s in scores.items():
        lines.append(f"| {name} | {s.frames} | {s.rms_deg['turn']:.1f}° / {s.r['turn']:.2f} / "
                     f"{s.offset_deg['turn']:+.1f}° | {s.rms_deg['nod']:.1f}° / {s.r['nod']:.2f} | "
                     f"{s.rms_deg['tilt']:.1f}° / {s.r['tilt']:.2f} | {s.reference_sd_deg['turn']:.1f}°, "
                     f"{s.reference_sd_deg['nod']:.1f}°, {s.reference_sd_deg['tilt']:.1f}° |")
    return "\n".join(lines)


@dataclass
class MeshRun:
    """The face landmark model on one camera's main person: the frames by outcome ("found", the reason it is
    absent, "no person"), the largest face flag and the meshes ``[T, 468, 4]`` (NaN where absent)."""

    outcomes: Counter[str]
    best_flag: float
    meshes: np.ndarray


def face_mesh_runs(folders: list[Path], cams: list[CameraModel], videos: list[Path], model_path: Path
                   ) -> list[MeshRun]:
    """Per camera, the face landmark model (``detect/face.py``, at ``model_path``) on the main person of
    each frame (BlazePose folders ``folders`` of ``videos``, the person chosen as the reference's)."""
    import cv2

    from mocapdb.detect.face import FaceLandmarker, Faces

    chosen, _ = choose_people([list(read_openpose_folder(f)) for f in folders], cams, CONFIDENCE)
    landmarker, out = FaceLandmarker(model_path), []
    for view, (folder, video) in enumerate(zip(folders, videos)):
        raw, capture = read_raw_folder(folder), cv2.VideoCapture(str(video))
        run = MeshRun(Counter(), 0.0, np.repeat(Faces.empty(1).points, len(chosen[view]), axis=0))
        for t, k in enumerate(chosen[view]):
            ok, image = capture.read()
            if not ok or k < 0:
                run.outcomes["no person"] += 1
                continue
            faces = landmarker(image, raw[t][k].raw[None])
            run.outcomes[faces.absent[0] or "found"] += 1
            run.best_flag = max(run.best_flag, float(faces.presence[0]))
            run.meshes[t] = faces.points[0]
        capture.release()
        out.append(run)
    return out


def mesh_angles(meshes: np.ndarray, cam: CameraModel, points_m: np.ndarray) -> np.ndarray:
    """``[T, 3]`` turn, nod, tilt (degrees; NaN without a mesh) of the head fitted to one camera's meshes
    ``[T, 468, 4]`` (``runtime/mesh_head.py``: the person's own model from these meshes, the head's depth
    from the mesh's 3D breadth, an upright prior facing the camera) against the chest of the triangulated
    :data:`REFERENCE_POINTS` ``[T, 7, 3]``: the head alone, the body fit left out."""
    from mocapdb.runtime.mesh_head import (
        MESH_BREADTH_M,
        MESH_LEFT,
        MESH_NOSE,
        MESH_RIGHT,
        fit_mesh_head,
        head_vertices,
        mesh_model,
    )

    model = mesh_model(head_vertices(meshes), 1.0)
    if model is None:
        return np.full((len(meshes), 3), np.nan)
    focal, cx, cy = float(cam.K[0, 0]), float(cam.K[0, 2]), float(cam.K[1, 2])
    # the breadth in 3D (the mesh's z is scaled like x): not shortened by the head's turn
    depth = focal * MESH_BREADTH_M / np.linalg.norm(meshes[:, MESH_LEFT, :3] - meshes[:, MESH_RIGHT, :3], axis=-1)
    nose = np.stack([(meshes[:, MESH_NOSE, 0] - cx) * depth / focal, (cy - meshes[:, MESH_NOSE, 1]) * depth / focal,
                     -depth], axis=-1)
    prior = np.broadcast_to(np.eye(3), (len(meshes), 3, 3)).copy()
    head_view, fixed = fit_mesh_head(head_vertices(meshes), np.nan_to_num(nose, nan=1.0), prior, 1.0,
                                     (focal, cx, cy), model)
    head_world = cam.R.T @ np.diag([1.0, -1.0, -1.0]) @ head_view       # view (y up, z to the camera) → world
    _, _, _, r_sh, l_sh, r_hip, l_hip = np.moveaxis(points_m, 1, 0)
    chest = frame_from_x_and_hint(l_sh - r_sh, 0.5 * (l_sh + r_sh) - 0.5 * (l_hip + r_hip), "y")
    return np.where(fixed[:, None], relative_angles(chest, head_world), np.nan)
