"""The stream's feet, hands and head against the whole take's (issue 49): how far the online take's end
joints (``end_quaternions`` of ``result.jsonl``) turn from the track file's (the humanoid BVH), and
whether the planted feet slide more with them.

Runs ``mocapdb reconstruct KEYPOINTS --db DB --rig humanoid --view-frame`` (the track file in the
stream's frame) at each ``--lag``, then per frame of the main track:

- the angle (degrees) between the global rotations (view frame) of each humanoid end bone (``…Foot``,
  ``…Hand``, ``Head``) in the stream and in the track file, and the same with the stream's end joints
  not turned (what the stream gave before: the identity), and of the bones they hang from (``…Leg``,
  ``…ForeArm``, ``Neck``: how far the two takes' bodies differ already);
- the planted feet's slide: the horizontal speed (cm/s, across the stream's ``up``) of the ankle and of
  the ball of the foot (``…ToeBase``) over the frames the stream says a foot is planted, with and without
  the end joints.

Usage: ``.venv/bin/python tools/eval_stream_ends.py data/sample_keypoints/blazepose_cam01 --db demo/sample.db``
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from pathlib import Path

import numpy as np

from mocapdb.cli.main import main as mocapdb
from mocapdb.core.formats.bvh import forward_kinematics, read_bvh
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import CAMERA_FROM_VIEW, motion_bvh
from mocapdb.core.skeleton import END_JOINTS, MEASURED_BONE_NAMES, UNIVERSAL_HEIGHT_M

ENDS = ("RightFoot", "LeftFoot", "RightHand", "LeftHand", "Head")   # END_JOINTS order
PARENTS = ("RightLeg", "LeftLeg", "RightForeArm", "LeftForeArm", "Neck")
BALLS = ("RightToeBase", "LeftToeBase")


def stream_track(path: Path, track: int) -> tuple[np.ndarray, Motion, np.ndarray, np.ndarray]:
    """The frames ``[F]`` of ``track`` in a stream, as a motion (view frame; end rotations), its
    contacts ``[F, 2]`` and ups ``[F, 3]``."""
    header, *lines = [json.loads(line) for line in path.read_text().splitlines()]
    fps = float(header["fps"])
    people = [(f["frame"], p) for f in lines for p in f["people"] if p["track"] == track]
    frames = np.array([f for f, _ in people])
    record = [p for _, p in people]
    scale = record[-1]["height"] / UNIVERSAL_HEIGHT_M
    proportions = np.array([record[-1]["bones"][b] for b in MEASURED_BONE_NAMES]) / scale
    motion = Motion(np.array([p["quaternions"] for p in record]), np.array([p["root"] for p in record]) *
                    CAMERA_FROM_VIEW, fps, "view", 0, scale, proportions,
                    np.array([p["end_quaternions"] for p in record]))
    return frames, motion, np.array([p["contacts"] for p in record]), np.array([p["up"] for p in record])


def humanoid_fk(motion: Motion, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Positions ``[F, K, 3]`` (metres) and global rotations ``[F, K, 3, 3]`` of the humanoid nodes ``names``."""
    bvh = motion_bvh(motion, rig="humanoid")
    return forward_kinematics(bvh, [bvh.names.index(n) for n in names])


def angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation angles (degrees) between rotation matrices ``a`` and ``b`` ``[..., 3, 3]``."""
    trace = np.einsum("...ji,...ji->...", a, b)
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def slide_cm_s(points: np.ndarray, planted: np.ndarray, up: np.ndarray, fps: float) -> float:
    """The median horizontal speed (cm/s) of ``points [F, 2, 3]`` over consecutive ``planted [F, 2]`` frames."""
    step = np.diff(points, axis=0)
    step -= np.einsum("fki,fi->fk", step, up[1:])[..., None] * up[1:, None]
    both = planted[1:] & planted[:-1]
    return float(np.median(np.linalg.norm(step, axis=-1)[both]) * 100.0 * fps) if both.any() else float("nan")


def evaluate(keypoints: str, db: str, lag: int, out: Path) -> dict:
    """One run's figures (see the module docstring)."""
    with contextlib.redirect_stdout(io.StringIO()):
        assert mocapdb(["reconstruct", keypoints, "--db", db, "--out", str(out), "--rig", "humanoid", "--view-frame",
                        "--lag-frames", str(lag), "-q"]) == 0
    bvh_path = sorted(out.glob("track_*.bvh"))[0]
    frames, stream, planted, up = stream_track(out / "result.jsonl", int(bvh_path.stem.split("_")[1]))
    take = read_bvh(bvh_path)
    take_pos, take_rot = (a[frames] for a in forward_kinematics(take, [take.names.index(n)
                                                                       for n in ENDS + PARENTS + BALLS]))
    positions, rotations = humanoid_fk(stream, ENDS + PARENTS + BALLS)
    unturned = Motion(stream.rotations, stream.root_m, stream.fps, "view", 0, stream.scale, stream.proportions_m)
    positions_0, rotations_0 = humanoid_fk(unturned, ENDS + PARENTS + BALLS)
    n = len(ENDS)
    figures = {"frames": len(frames), "lag": lag}
    for k, name in enumerate(END_JOINTS):
        figures[name] = {"turned": float(np.median(angles_deg(rotations[:, k], take_rot[:, k]))),
                         "not turned": float(np.median(angles_deg(rotations_0[:, k], take_rot[:, k]))),
                         "parent": float(np.median(angles_deg(rotations[:, n + k], take_rot[:, n + k])))}
    ankles = positions[:, :2]
    figures["slide_cm_s"] = {"ankle": slide_cm_s(ankles, planted, up, stream.fps),
                             "ball, turned": slide_cm_s(positions[:, 2 * n:], planted, up, stream.fps),
                             "ball, not turned": slide_cm_s(positions_0[:, 2 * n:], planted, up, stream.fps),
                             "ball, track file": slide_cm_s(take_pos[:, 2 * n:], planted, up, stream.fps),
                             "planted frames": int(planted.sum())}
    return figures


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("keypoints")
    parser.add_argument("--db", required=True)
    parser.add_argument("--lag", type=int, nargs="+", default=[0, 3])
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        for lag in args.lag:
            figures = evaluate(args.keypoints, args.db, lag, Path(tmp) / f"lag{lag}")
            print(f"lag {lag} ({figures['frames']} frames of the main track): end bone vs the track file, median deg")
            for name in END_JOINTS:
                f = figures[name]
                print(f"  {name:7s} turned {f['turned']:5.1f}   not turned {f['not turned']:5.1f}   "
                      f"(the bone it hangs from: {f['parent']:4.1f})")
            s = figures["slide_cm_s"]
            print(f"  planted feet ({s['planted frames']} foot-frames), median horizontal speed: ankle "
                  f"{s['ankle']:.1f} cm/s, ball of the foot {s['ball, turned']:.1f} (not turned: "
                  f"{s['ball, not turned']:.1f}; the track file's over the same frames: {s['ball, track file']:.1f})")


if __name__ == "__main__":
    main()
