"""Round-trip a BVH file through Blender and check mocapdb reads both the same.

    python tools/blender_roundtrip.py ../shared/data/cmu_bvh/002_01.bvh [--bpy-python PYTHON]

Blender's importer reads the file, its exporter writes it back with default settings (position
channels on every joint, Blender's own rotation order), and mocapdb turns both files into
database clips (universal skeleton, 24 fps, floor at 0). Prints the largest and mean keypoint
difference and the pelvis path difference in centimetres; exit code 0 when the largest
difference is below 1 cm. Blender as in ``tools/blender_check.py``.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from blender_check import BPY_PYTHON_ENV, blender_available, run_in_blender  # noqa: E402

from mocapdb.core.clips import ClipOptions, clips_from_bvh  # noqa: E402
from mocapdb.core.skeleton import PELVIS  # noqa: E402

INSIDE = r"""
import builtins, sys
import bpy
_open = builtins.open
builtins.open = lambda f, mode="r", *a, **k: _open(f, mode.replace("U", ""), *a, **k)  # Blender 3.4's "rU"
source, target = sys.argv[-2], sys.argv[-1]
bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_anim.bvh(filepath=source, update_scene_fps=True, update_scene_duration=True)
arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
bpy.context.view_layer.objects.active = arm
arm.select_set(True)
first, last = arm.animation_data.action.frame_range
bpy.ops.export_anim.bvh(filepath=target, frame_start=int(first), frame_end=int(last))
"""


def round_trip(path: Path, out: Path, bpy_python: str | None = None) -> None:
    """Blender imports ``path`` and exports it to ``out`` (default export settings)."""
    run = run_in_blender(INSIDE, [str(path), str(out)], bpy_python)
    if run.returncode != 0 or not out.is_file():
        raise RuntimeError(f"Blender did not round-trip {path}:\n{run.stderr[-2000:]}")


def compare(original: Path, exported: Path) -> dict:
    """Largest and mean keypoint difference and pelvis-path difference (cm) of the two files' clips."""
    config = ClipOptions(mirror=False)
    a = max(clips_from_bvh(original, original.parent, config), key=lambda c: len(c.positions))
    b = max(clips_from_bvh(exported, exported.parent, config), key=lambda c: len(c.positions))
    n = min(len(a.positions), len(b.positions))
    diff = np.linalg.norm(a.positions[:n] - b.positions[:n], axis=-1) * 100
    pelvis = np.linalg.norm(a.positions[:n, PELVIS] - b.positions[:n, PELVIS], axis=-1) * 100
    return {"frames": (len(a.positions), len(b.positions)), "max_cm": float(diff.max()),
            "mean_cm": float(diff.mean()), "pelvis_max_cm": float(pelvis.max()), "pelvis_mean_cm": float(pelvis.mean())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bvh", type=Path)
    ap.add_argument("--bpy-python", help=f"a Python with `pip install bpy` (default: ${BPY_PYTHON_ENV}, else blender)")
    ap.add_argument("--keep", type=Path, help="also keep Blender's export here")
    args = ap.parse_args()
    if not blender_available(args.bpy_python):
        print("no Blender: pass --bpy-python or install blender", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        exported = Path(tmp) / f"{args.bvh.stem}_blender.bvh"
        round_trip(args.bvh.resolve(), exported, args.bpy_python)
        if args.keep:
            shutil.copy(exported, args.keep)
        result = compare(args.bvh, exported)
    print(f"{args.bvh.name}: database frames {result['frames'][0]} / {result['frames'][1]} (original / Blender), "
          f"keypoints max {result['max_cm']:.3f} cm, mean {result['mean_cm']:.3f} cm; "
          f"pelvis path max {result['pelvis_max_cm']:.3f} cm, mean {result['pelvis_mean_cm']:.3f} cm")
    return 0 if result["frames"][0] == result["frames"][1] and result["max_cm"] < 1.0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
