"""Where Blender puts a take's feet: every `track_<id>.bvh` of a reconstruction folder imported with
Blender's own BVH importer (y up → Blender's z up), and per track the median height above Blender's
ground plane (z = 0) of each ankle while it is still (slower than 0.2 m/s), and its lowest over the
take: a person on the floor has ankles about 8 cm (× its size) above it; one standing on something,
that much above its top. A jumper's ankles are "still" at the jumps' tops too; its lowest is its
landing.

Run it with a Python that has the `bpy` wheel (as `.ci/run` makes: `.venv-bpy`):

    .venv-bpy/bin/python tools/blender_feet.py demo/reconstruction --fps 60
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import bpy
import numpy as np

STILL_MPS = 0.2   # an ankle slower than this is taken as planted


def ankle_paths(bvh: Path) -> dict[str, np.ndarray]:
    """Per leg, the ankle's path ``[F, 3]`` (Blender's world, metres): the tail of the knee bone, over
    the frames the track exists (:func:`shown_frames`)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_anim.bvh(filepath=str(bvh), axis_forward="-Z", axis_up="Y", update_scene_fps=False)
    armature = next(o for o in bpy.context.scene.objects if o.type == "ARMATURE")
    first, last = (int(v) for v in armature.animation_data.action.frame_range)
    knees = [b.name for b in armature.pose.bones if b.name.lower().endswith("knee") or b.name.endswith("Leg")
             and not b.name.endswith("UpLeg")]
    paths: dict[str, list] = {name: [] for name in knees}
    poses = []
    for frame in range(first, last + 1):
        bpy.context.scene.frame_set(frame)
        for name in knees:
            paths[name].append(tuple(armature.matrix_world @ armature.pose.bones[name].tail))
        poses.append([tuple(armature.matrix_world @ b.tail) for b in armature.pose.bones])
    shown = shown_frames(np.array(poses))
    return {name: np.array(points)[shown] for name, points in paths.items()}


def shown_frames(poses: np.ndarray) -> slice:
    """The frames ``[F, B, 3]`` between the first and last pose change: a track file lines up with the
    video frame for frame, holding its first pose before the track appears and its last after it ends."""
    changes = np.flatnonzero(np.abs(np.diff(poses, axis=0)).max(axis=(1, 2)) > 1e-9)
    return slice(0, len(poses)) if not len(changes) else slice(int(changes[0]), int(changes[-1]) + 2)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("folder", type=Path, help="a reconstruction folder (track_<id>.bvh files)")
    parser.add_argument("--fps", type=float, default=30.0, help="the take's frame rate (Hz)")
    args = parser.parse_args()
    files = sorted(args.folder.glob("track_*.bvh"))
    if not files:
        sys.exit(f"{args.folder}: no track_<id>.bvh")
    for bvh in files:
        cells = []
        for name, path in ankle_paths(bvh).items():
            speed = np.r_[np.inf, np.linalg.norm(np.diff(path, axis=0), axis=1) * args.fps]
            still = speed < STILL_MPS
            height = f"{np.median(path[still, 2]):.3f} m" if still.any() else "never still"
            cells.append(f"{name} {height} ({int(still.sum())} frames; lowest {path[:, 2].min():.3f} m)")
        print(f"{bvh.name}: ankle above Blender's ground while still: " + ", ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
