"""The world of a camera that turned (issue 51, item 2): what ``world.json`` and the summary say of
its path.

The session maps every frame's keypoints into the reference camera (the first frame's:
:meth:`~mocapdb.core.formats.camera_path.CameraPath.derotate`) before the engine sees them, so the
engine, the whole take and the world fit one still camera. The world found is the reference
camera's; frame ``t``'s camera is the reference turned by ``R_t`` about the same centre, so its
floor is the reference's normal turned into its view frame, at the same height.
``data_specs/world.md``, "A camera that turns".
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.formats.camera_path import CameraPath
from mocapdb.core.geometry import matrix_to_quat
from mocapdb.runtime.world.fuse import World
from mocapdb.runtime.world.summary import files_camera_pose

VIEW_FROM_OPENCV = np.diag([1.0, -1.0, -1.0])   # OpenCV camera axes (x right, y down, z forward) ↔ view frame


def view_turns(path: CameraPath) -> np.ndarray:
    """``[N, 3, 3]`` each frame's view-frame vectors (x right, y up, z towards the camera) taken to
    the reference camera's view frame: ``V R_tᵀ V``."""
    return VIEW_FROM_OPENCV @ np.transpose(path.rotations, (0, 2, 1)) @ VIEW_FROM_OPENCV


def frame_normals(path: CameraPath, world: World) -> np.ndarray:
    """``[N, 3]`` the world's up (the floor's normal) in each frame's view frame."""
    return np.einsum("nji,j->ni", view_turns(path), world.normal)


def camera_path_record(path: CameraPath, world: World, files_on_floor: bool) -> dict:
    """``world.json``'s ``camera_path`` (data_specs/world.md, "A camera that turns"): the frames,
    each frame's rotation to the files' frame (on the floor) or to the reference's view frame
    (quaternions w, x, y, z), its floor normal in its own view frame, how far it turned from the
    reference (degrees), the rotation-only fit's residual (px) and the frames that showed parallax.
    A still camera's: the reference, its focal and the frames that showed parallax only."""
    short = {"reference_frame": int(path.frames[0]), "still": path.still, "focal_px": round(path.focal_px, 3),
             "moved_frames": int(path.moved.sum())}
    if path.still:
        return short
    turns = view_turns(path)
    if files_on_floor and world.floor_known:
        key, turns = "view_to_files_wxyz", np.array(files_camera_pose(world)["view_to_files"]) @ turns
    else:
        key = "view_to_reference_wxyz"
    return short | {"frames": path.frames.tolist(), key: np.round(matrix_to_quat(turns), 6).tolist(),
                    "floor_normal_view": np.round(frame_normals(path, world), 5).tolist(),
                    "turn_deg": np.round(path.turn_deg(), 3).tolist(),
                    "residual_px": [None if not np.isfinite(r) else round(float(r), 3) for r in path.residual_px]}


def camera_path_line(path: CameraPath) -> str:
    """The summary's line on the camera's path."""
    if path.still:
        return "camera still (its path from the background)"
    line = (f"camera turned up to {path.turn_deg().max():.1f} deg: every frame's keypoints seen from frame "
            f"{int(path.frames[0])}'s camera, one world")
    if path.moved.any():
        line += (f"; it also moved in {int(path.moved.sum())} frame(s) (parallax in the background): that "
                 "translation is not compensated, the people move with it")
    return line
