"""Real motion's angular accelerations per rig joint: the process noise of the stream's rotation filter
(runtime/rotation_kalman.py, ROTATION_ACCEL_RAD_S2).

Every BVH clip of the sources retargeted to the universal rig at --fps (as the database builder does),
each joint's local angular velocity (rad/s, in the joint's own frame) from frame to frame, its change per
frame (rad/s²); printed per joint: the RMS per tangent axis, left and right pooled, and the median.

    .venv/bin/python tools/rotation_motion.py ../shared/data/cmu_bvh            # 24 fps, the table's
"""
from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from mocapdb.builder.config import BuildConfig
from mocapdb.builder.read_stage import find_sources
from mocapdb.core.clips import process_clip
from mocapdb.core.geometry import quat_conj, quat_mul
from mocapdb.core.skeleton import RIG_JOINTS


def rotation_vectors(q: np.ndarray) -> np.ndarray:
    """``[..., 3]`` the rotation vectors (radians, full angle) of unit quaternions ``q [..., 4]``."""
    q = np.where(q[..., :1] < 0, -q, q)
    sin_half = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    return q[..., 1:] * np.where(sin_half > 1e-12, angle / np.maximum(sin_half, 1e-12), 2.0)


def accelerations(quats: np.ndarray, fps: float) -> np.ndarray:
    """``[F − 2, R, 3]`` the angular accelerations (rad/s²) of one clip's local rotations ``[F, R, 4]``."""
    velocity = rotation_vectors(quat_mul(quat_conj(quats[:-1]), quats[1:])) * fps
    return np.diff(velocity, axis=0) * fps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sources", nargs="+", help="BVH files or folders")
    parser.add_argument("--fps", type=float, default=24.0, help="the rate the clips are retargeted at (%(default)s)")
    args = parser.parse_args()
    options = replace(BuildConfig().clip_options(), fps=args.fps)
    acc = np.concatenate([accelerations(process_clip(path, root, options).quaternions.astype(np.float64), args.fps)
                          for path, root in find_sources(args.sources)])
    rms = np.sqrt(np.mean(acc ** 2, axis=(0, 2)))
    median = np.median(np.linalg.norm(acc, axis=-1), axis=0) / np.sqrt(3.0)
    print(f"{len(acc)} frames at {args.fps:g} fps; rad/s² per tangent axis")
    print("| joint | RMS | RMS, left and right pooled | median |\n|---|---|---|---|")
    for j, name in enumerate(RIG_JOINTS):
        pair = [RIG_JOINTS.index(n) for n in {name, name.replace("r_", "l_"), name.replace("l_", "r_")}]
        pooled = np.sqrt(np.mean(rms[pair] ** 2)) if len(pair) > 1 else rms[j]
        print(f"| {name} | {rms[j]:.1f} | {pooled:.1f} | {median[j]:.1f} |")


if __name__ == "__main__":
    main()
