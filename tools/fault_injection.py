"""Feed mocapdb bad input of every kind and check it fails clearly and loses nothing.

    python tools/fault_injection.py [--keep DIR]

Each case runs a real ``mocapdb`` command (a subprocess) on input the script writes: broken BVH
files and options for ``build``, damaged databases, bad keypoint files and parameters for
``reconstruct``, bad calibrations and views for ``stereo``, bad ``eval`` input. A case passes when
the command ends with its expected exit code (2 for a user error), prints no Python traceback, and
leaves the output it was told to protect as it was (a previous database or output folder).
Prints one row per case and a summary table: cases, clean errors, tracebacks, files lost.
"""
from __future__ import annotations

import argparse
import hashlib
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BVH = ROOT / "data" / "sample_bvh"
SAMPLE_KEYPOINTS = ROOT / "data" / "sample_keypoints"
GOOD_CLIP = SAMPLE_BVH / "002_01.bvh"


@dataclass
class Case:
    name: str
    args: list[str]
    expect: int = 2
    protect: Path | None = None  # a file or folder that must come out unchanged


def _digest(path: Path) -> str:
    """A hash of a file or of every file under a folder (names and bytes)."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        h.update(str(f.relative_to(path.parent)).encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def _bvh_variant(tmp: Path, name: str, edit) -> Path:
    """A copy of the good clip with ``edit(text) -> text`` applied."""
    folder = tmp / f"bvh_{name}"
    folder.mkdir()
    (folder / f"{name}.bvh").write_text(edit(GOOD_CLIP.read_text()))
    return folder


def build_cases(tmp: Path, db: Path) -> list[Case]:
    def frame_time(value: str):
        return lambda t: "\n".join(f"Frame Time: {value}" if line.startswith("Frame Time") else line
                                   for line in t.splitlines())

    def second_offset(value: str):
        """The first joint below the root gets OFFSET value value value."""
        def edit(text: str) -> str:
            lines = text.splitlines()
            i = [k for k, line in enumerate(lines) if line.strip().startswith("OFFSET")][1]
            lines[i] = lines[i].split("OFFSET")[0] + f"OFFSET {value} {value} {value}"
            return "\n".join(lines)
        return edit

    cases = [Case(f"build: Frame Time {v}", ["build", str(_bvh_variant(tmp, f"ft{i}", frame_time(v))), "--out", str(db)],
                  protect=db) for i, v in enumerate(("0", "inf", "nan", "-1"))]
    cases += [Case(f"build: OFFSET {v}", ["build", str(_bvh_variant(tmp, f"off{i}", second_offset(v))), "--out", str(db)],
                   protect=db) for i, v in enumerate(("nan", "inf"))]
    cases.append(Case("build: binary file", ["build", str(_bvh_variant(tmp, "bin", lambda t: "\x00\x01" * 64)),
                                              "--out", str(db)], protect=db))
    cases.append(Case("build: truncated motion", ["build", str(_bvh_variant(tmp, "cut", lambda t: t[: len(t) // 2])),
                                                   "--out", str(db)], protect=db))
    for option, value in (("--clusters", "0"), ("--dims", "0"), ("--landmarks", "1"), ("--fps", "0"),
                          ("--yaw-step", "0"), ("--yaw-step", "nan"), ("--focal", "0"), ("--workers", "0")):
        cases.append(Case(f"build: {option} {value}", ["build", str(GOOD_CLIP), "--out", str(db), option, value],
                          protect=db))
    cases.append(Case("build: --out is a file", ["build", str(GOOD_CLIP), "--out", str(GOOD_CLIP)], protect=GOOD_CLIP))
    return cases


def _flipped_database(db: Path, tmp: Path) -> Path:
    bad = tmp / "flipped.db"
    shutil.copytree(db, bad)
    target = bad / "frames.parquet"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x10
    target.write_bytes(bytes(data))
    return bad


def _npy(tmp: Path, name: str, payload: bytes) -> Path:
    path = tmp / name
    path.write_bytes(payload)
    return path


def reconstruct_cases(tmp: Path, db: Path, out: Path) -> list[Case]:
    base = ["--db", str(db), "--out", str(out), "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
    cam = str(SAMPLE_KEYPOINTS / "pose2sim_cam01")
    huge = b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (5000000000000, 3), }" + b" " * 40
    empty = tmp / "empty_folder"
    empty.mkdir()
    (empty / "readme.txt").write_text("no keypoints here")
    cases = [
        Case("reconstruct: damaged database", ["reconstruct", cam, "--db", str(_flipped_database(db, tmp)),
                                                "--out", str(out)], protect=out),
        Case("reconstruct: missing input", ["reconstruct", str(tmp / "missing"), *base], protect=out),
        Case("reconstruct: empty folder", ["reconstruct", str(empty), *base], protect=out),
        Case("reconstruct: truncated .npz", ["reconstruct", str(_npy(tmp, "cut.npz", b"PK\x03\x04garbage")), *base],
             protect=out),
        Case("reconstruct: .npy claiming 5e12 values", ["reconstruct", str(_npy(tmp, "huge.npy", huge)), *base],
             protect=out),
        Case("reconstruct: swapped --image-size", ["reconstruct", cam, "--db", str(db), "--out", str(out), "--fps", "60",
                                                    "--image-size", "1920x1088", "--focal", "1681"], protect=out),
        Case("reconstruct: --image-size syntax", ["reconstruct", cam, "--db", str(db), "--out", str(out),
                                                   "--image-size", "1088by1920"], protect=out),
        Case("reconstruct: --subject-height 0", ["reconstruct", cam, *base, "--subject-height", "0"], protect=out),
    ]
    return cases


def stereo_cases(tmp: Path, out: Path) -> list[Case]:
    cal = SAMPLE_KEYPOINTS / "calibration.toml"
    cam1, cam4 = str(SAMPLE_KEYPOINTS / "pose2sim_cam01"), str(SAMPLE_KEYPOINTS / "pose2sim_cam04")
    binary = tmp / "binary.toml"
    binary.write_bytes(bytes(range(256)) * 4)
    common = ["--fps", "60", "--out", str(out)]
    return [
        Case("stereo: the same view twice", ["stereo", cam1, cam1, "--calibration", str(cal), "--cameras", "cam_01",
                                             "cam_01", *common], protect=out),
        Case("stereo: binary calibration", ["stereo", cam1, cam4, "--calibration", str(binary), "--cameras", "cam_01",
                                            "cam_04", *common], protect=out),
        Case("stereo: --focal -1000", ["stereo", cam1, cam4, "--focal", "-1000", "--size", "1088", "1920", *common],
             protect=out),
        Case("stereo: --size 0 0", ["stereo", cam1, cam4, "--focal", "1681", "--size", "0", "0", *common], protect=out),
        Case("stereo: --camera-distance 0", ["stereo", cam1, cam4, "--calibration", str(cal), "--cameras", "cam_01",
                                             "cam_04", "--camera-distance", "0", *common], protect=out),
    ]


def eval_cases(tmp: Path, db: Path) -> list[Case]:
    empty = tmp / "no_bvh"
    empty.mkdir()
    return [Case("eval: folder without BVH", ["eval", "--db", str(db), "--bvh", str(empty)]),
            Case("eval: no database", ["eval", "--db", str(tmp / "missing.db"), "--bvh", str(GOOD_CLIP)])]


def run_case(case: Case) -> dict:
    before = _digest(case.protect) if case.protect is not None and case.protect.exists() else None
    run = subprocess.run([sys.executable, "-m", "mocapdb", *case.args], capture_output=True, text=True,
                         timeout=600, cwd=ROOT)
    lost = before is not None and (not case.protect.exists() or _digest(case.protect) != before)
    traceback = "Traceback (most recent call last)" in run.stderr
    message = (run.stderr.strip().splitlines() or [""])[-1][:150]
    return {"case": case.name, "exit": run.returncode, "ok": run.returncode == case.expect and not traceback
            and not lost, "traceback": traceback, "lost": lost, "message": message}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--keep", type=Path, help="work in this folder and keep it (default: a temporary one)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="mocapdb-faults-")) if args.keep is None else args.keep
    tmp.mkdir(parents=True, exist_ok=True)
    db, out, stereo_out = tmp / "good.db", tmp / "out", tmp / "stereo_out"
    subprocess.run([sys.executable, "-m", "mocapdb", "build", str(SAMPLE_BVH), "--out", str(db), "--clusters", "50",
                    "--landmarks", "300"], check=True, capture_output=True, cwd=ROOT)
    subprocess.run([sys.executable, "-m", "mocapdb", "reconstruct", str(SAMPLE_KEYPOINTS / "pose2sim_cam01"), "--db",
                    str(db), "--out", str(out), "--fps", "60", "--image-size", "1088x1920", "--focal", "1681"],
                   check=True, capture_output=True, cwd=ROOT)
    stereo_out.mkdir()
    (stereo_out / "earlier.txt").write_text("an earlier run's output")
    cases = build_cases(tmp, db) + reconstruct_cases(tmp, db, out) + stereo_cases(tmp, stereo_out) + eval_cases(tmp, db)
    rows = [run_case(c) for c in cases]
    for r in rows:
        flag = "ok  " if r["ok"] else "FAIL"
        print(f"{flag} exit {r['exit']:>3}  {r['case']:<40} {r['message']}")
    print()
    print("| cases | clean errors | tracebacks | files lost | unexpected exit codes |")
    print("|---|---|---|---|---|")
    print(f"| {len(rows)} | {sum(r['ok'] for r in rows)} | {sum(r['traceback'] for r in rows)} | "
          f"{sum(r['lost'] for r in rows)} | {sum(not r['ok'] and not r['traceback'] and not r['lost'] for r in rows)} |")
    if args.keep is None:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
