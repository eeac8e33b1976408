"""Check that Blender imports a BVH file as mocapdb means it: same joints, frames and positions.

    python tools/blender_check.py FILE.bvh [--frames 0 10 50]

Runs Blender's own BVH importer (a Python with the ``bpy`` wheel given by ``--bpy-python`` or
the ``MOCAPDB_BPY_PYTHON`` environment variable, else ``blender`` on the PATH in background mode),
reads every bone's head and tail at the given frames, and compares them with
mocapdb's forward kinematics of the same file (Blender turns the BVH's y-up into its z-up:
x → x, y → z, z → −y). Prints the largest difference in millimetres; exit code 0 when it is
below 1 mm.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.bvh import forward_kinematics, read_bvh  # noqa: E402

# Runs inside Blender. Blender 3.4's importer opens files with mode "rU", which Python 3.11
# rejects; the shim drops the "U" (a Blender bug, not a property of the file).
INSIDE = r"""
import builtins, json, sys
import bpy
_open = builtins.open
builtins.open = lambda f, mode="r", *a, **k: _open(f, mode.replace("U", ""), *a, **k)
path, frames = sys.argv[-2], json.loads(sys.argv[-1])
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=path, update_scene_fps=True, update_scene_duration=True)
arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
scene = bpy.context.scene
first, last = arm.animation_data.action.frame_range
out = {"fps": scene.render.fps / scene.render.fps_base, "first": int(first), "last": int(last), "bones": {}}
for f in frames:
    scene.frame_set(int(first) + f)
    for b in arm.pose.bones:
        h, t = arm.matrix_world @ b.head, arm.matrix_world @ b.tail
        out["bones"].setdefault(b.name, {})[f] = [list(h), list(t)]
print("MOCAPDB" + json.dumps(out))
"""

BLENDER_FROM_BVH = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
BPY_PYTHON_ENV = "MOCAPDB_BPY_PYTHON"  # a Python with the bpy wheel, used instead of the blender program


def blender_available(bpy_python: str | None = None) -> bool:
    return bool(bpy_python or os.environ.get(BPY_PYTHON_ENV) or shutil.which("blender"))


def run_in_blender(script: str, args: list[str], bpy_python: str | None = None) -> subprocess.CompletedProcess:
    """Run ``script`` inside Blender with ``args`` last on its ``sys.argv``."""
    python = bpy_python or os.environ.get(BPY_PYTHON_ENV)
    command = [python, "-c", script] if python else ["blender", "-b", "--factory-startup", "--python-expr", script]
    return subprocess.run(command + ["--", *args], capture_output=True, text=True, timeout=600)


def blender_pose(path: Path, frames: list[int], bpy_python: str | None = None) -> dict:
    """Bone heads/tails (Blender world, metres per BVH unit) at ``frames`` after Blender's import."""
    run = run_in_blender(INSIDE, [str(path), json.dumps(frames)], bpy_python)
    line = next((ln for ln in run.stdout.splitlines() if ln.startswith("MOCAPDB")), None)
    if line is None:
        raise RuntimeError(f"Blender did not import {path}:\n{run.stdout[-2000:]}\n{run.stderr[-2000:]}")
    return json.loads(line[len("MOCAPDB"):])


def compare(path: Path, frames: list[int], bpy_python: str | None = None) -> float:
    """Largest distance (file units) between Blender's bone heads and mocapdb's joint positions."""
    bvh = read_bvh(path)
    positions, _ = forward_kinematics(bvh)
    seen = blender_pose(path, frames, bpy_python)
    print(f"{path}: Blender imported {len(seen['bones'])} bones, frames {seen['first']}–{seen['last']}, "
          f"{seen['fps']:.3f} fps (the file: {bvh.n_frames} frames at {bvh.fps:.3f} fps)")
    worst = 0.0
    for name, per_frame in seen["bones"].items():
        for f, (head, _) in per_frame.items():
            ours = BLENDER_FROM_BVH @ positions[int(f), bvh.index(name)]
            worst = max(worst, float(np.linalg.norm(np.array(head) - ours)))
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bvh", type=Path, nargs="+", help="BVH files")
    ap.add_argument("--frames", type=int, nargs="+", default=[0, 1], help="0-based frames to compare")
    ap.add_argument("--bpy-python", help=f"a Python with `pip install bpy` (default: ${BPY_PYTHON_ENV}, else blender)")
    args = ap.parse_args()
    if not blender_available(args.bpy_python):
        print("no Blender: pass --bpy-python or install blender (Debian: apt-get install blender)", file=sys.stderr)
        return 2
    ok = True
    for path in args.bvh:
        worst = compare(path, args.frames, args.bpy_python)
        print(f"  largest joint difference: {worst * 1000:.3f} mm (in the file's units × 1000)")
        ok &= worst < 1e-3
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
