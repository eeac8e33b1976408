"""The head's turn, nod and tilt on the balancing take, each camera alone, against the 4 cameras'
triangulation of BlazePose's own nose, ears, shoulders and hips (mocapdb/evaluation/head_turn.py).

    .venv/bin/python tools/eval_head.py [--work /tmp/headeval] [--db demo/sample.db] [--mesh]

BlazePose runs once per video (``mocapdb detect``; its folders are kept in ``--work``, outside the
repository, and reused); each camera's folder then goes through ``mocapdb reconstruct --rig humanoid``
and its BVH is posed by forward kinematics. Prints a Markdown table (docs/benchmarks.md). ``--mesh``: also
how the face landmark model (``mocapdb models fetch face``) fares on each camera's main person and, where
its mesh runs through, the head fitted to the mesh (``runtime/mesh_head.py``) against the triangulation
(against the triangulated chest: the head alone, not the BVH).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

from mocapdb.core.cameras import read_calibration_toml
from mocapdb.detect.model_store import extra_model_path
from mocapdb.evaluation.head_turn import (
    bvh_angles,
    face_mesh_runs,
    format_table,
    mesh_angles,
    reference_angles,
    score,
    triangulated_points,
)
from mocapdb.evaluation.real_take import focal_px

VIDEOS = Path("/work/shared/data/videos/pose2sim_balancing")
CALIBRATION = Path("data/gate/pose2sim_balancing/calibration.toml")
CAMERAS = ("cam_01", "cam_02", "cam_03", "cam_04")


def detected(work: Path, camera: str) -> Path:
    """The BlazePose folder of ``camera``'s video in ``work`` (made by ``mocapdb detect`` when missing)."""
    folder = work / f"blazepose_{camera.replace('_', '')}"
    if not (folder / "take.json").exists():
        video = VIDEOS / f"{camera.replace('_', '')}.mp4"
        subprocess.run([sys.executable, "-m", "mocapdb", "detect", str(video), "--out", str(folder), "-q"], check=True)
    return folder


def reconstructed_bvh(folder: Path, out: Path, db: Path, focal: float) -> Path:
    """The main person's humanoid BVH of ``mocapdb reconstruct`` on one camera's folder."""
    subprocess.run([sys.executable, "-m", "mocapdb", "reconstruct", str(folder), "--db", str(db), "--out", str(out),
                    "--format", "bvh", "--rig", "humanoid", "--people", "main", "--focal", f"{focal:.2f}", "-q"],
                   check=True, stdout=subprocess.DEVNULL)
    return next(iter(sorted(out.glob("track_*.bvh"))))


def mesh_table(folders: list[Path], cams: list, reference: np.ndarray, points: np.ndarray) -> str:
    """Per camera, the face mesh's outcome and, where it ran through, the head fitted to it against the
    triangulation (its chest too: the head alone)."""
    videos = [VIDEOS / f"{name.replace('_', '')}.mp4" for name in CAMERAS]
    lines = ["", "| camera | face mesh: frames by outcome | largest face flag | the mesh's head: turn RMS / r, "
             "nod RMS / r, tilt RMS / r |", "|---|---|---|---|"]
    for name, cam, run in zip(CAMERAS, cams, face_mesh_runs(folders, cams, videos, extra_model_path("face"))):
        angles = mesh_angles(run.meshes, cam, points)
        if np.isfinite(angles).all(axis=1).sum() < 2:
            fitted = "no frames with a mesh"
        else:
            s = score(angles, reference)
            fitted = ", ".join(f"{s.rms_deg[a]:.1f}° / {s.r[a]:.2f}" for a in ("turn", "nod", "tilt")) + \
                f" ({s.frames} frames)"
        outcomes = ", ".join(f"{k} {v}" for k, v in sorted(run.outcomes.items()))
        lines.append(f"| {name} | {outcomes} | {run.best_flag:.4f} | {fitted} |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("/tmp/headeval"), help="detections and reconstructions")
    parser.add_argument("--db", type=Path, default=Path("demo/sample.db"))
    parser.add_argument("--mesh", action="store_true", help="also the face mesh's outcome per camera")
    args = parser.parse_args()
    cams = read_calibration_toml(CALIBRATION)
    folders = [detected(args.work, name) for name in CAMERAS]
    points = triangulated_points(folders, [cams[n] for n in CAMERAS])
    reference = reference_angles(points)
    scores = {}
    for name, folder in zip(CAMERAS, folders):
        bvh = reconstructed_bvh(folder, args.work / f"out_{name}", args.db, focal_px(cams[name]))
        angles = bvh_angles(bvh)[1:]                     # BVH frame k is input frame k - 1
        estimate = np.full_like(reference, np.nan)
        estimate[:len(angles)] = angles[:len(reference)]
        scores[name] = score(estimate, reference)
    print(format_table(scores))
    if args.mesh:
        print(mesh_table(folders, [cams[n] for n in CAMERAS], reference, points))

if __name__ == "__main__":
    main()
