"""Feed mocapdb bad input of every kind and check it fails clearly and loses nothing.

    python tools/fault_injection.py [--keep DIR] [--family NAME]

Each case runs a real ``mocapdb`` command (a subprocess) on input the script writes, grouped in
the families of issue 20: numeric and path options, messages a live stream may carry, outputs
pointed at inputs, files that are not files (FIFOs, devices, zip bombs, 100,000-joint BVH), content
that should be refused, rendering and stereo on absurd input, and a service account without a
writable home or package folder. A case passes when the command ends with its expected exit code
(2 for a user error, 0 where a correct result is expected), prints no Python traceback, finishes
within :data:`TIMEOUT_S` (else it hangs), peaks below :data:`MAX_RSS_MB` of memory and
:data:`MAX_OUTPUT_MB` of files written, leaves the inputs it was told to protect unchanged, and,
where the case has a check, produces the right output (frames kept, reasons named).
Prints one row per case, then a table per family: cases, passed, tracebacks, hangs, runaway
resources, inputs lost, garbage accepted (exit 0 where a refusal was due).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_BVH = ROOT / "data" / "sample_bvh"
SAMPLE_KEYPOINTS = ROOT / "data" / "sample_keypoints"
CAM1, CAM4 = SAMPLE_KEYPOINTS / "pose2sim_cam01", SAMPLE_KEYPOINTS / "pose2sim_cam04"
CALIBRATION = SAMPLE_KEYPOINTS / "calibration.toml"
GOOD_CLIP = SAMPLE_BVH / "002_01.bvh"
CAMERA = ["--fps", "60", "--image-size", "1088x1920", "--focal", "1681"]
TIMEOUT_S = 120
MAX_RSS_MB = 1500
MAX_OUTPUT_MB = 50


@dataclass
class Case:
    family: str
    name: str
    args: list[str]
    expect: int | None = 2  # None: a clean refusal (2) or a result (0) are both right
    protect: Path | None = None  # a file or folder that must come out unchanged
    stdin: bytes = b""
    check: Callable[[str], str | None] | None = None  # given stderr: what is wrong with the outcome, or None
    prefix: list[str] = field(default_factory=list)  # run the command under this (e.g. unshare)
    env: dict[str, str] = field(default_factory=dict)


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


def _edit_lines(match: str, replace: Callable[[str], str]):
    """An edit replacing every line that starts with ``match`` (stripped) by ``replace(line)``."""
    return lambda t: "\n".join(replace(ln) if ln.strip().startswith(match) else ln for ln in t.splitlines()) + "\n"


def _second_offset(value: str):
    """The first joint below the root gets OFFSET value value value."""
    def edit(text: str) -> str:
        lines = text.splitlines()
        i = [k for k, line in enumerate(lines) if line.strip().startswith("OFFSET")][1]
        lines[i] = lines[i].split("OFFSET")[0] + f"OFFSET {value} {value} {value}"
        return "\n".join(lines) + "\n"
    return edit


def _first_channels_doubled(text: str) -> str:
    """The first 3-channel joint's rotations become ``Xrotation Xrotation ...`` (Y lost)."""
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.strip().startswith("CHANNELS 3"))
    head, _, channels = lines[i].partition("CHANNELS 3")
    names = channels.split()
    lines[i] = f"{head}CHANNELS 3 {names[0]} {names[0]} {names[2]}"
    return "\n".join(lines) + "\n"


def _chain_bvh(path: Path, n_joints: int) -> Path:
    """A BVH of ``n_joints`` joints in one chain (depth ``n_joints``)."""
    body = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0",
            "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
    for j in range(1, n_joints):
        body += [f"JOINT j{j}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    body += ["}"] * n_joints + ["MOTION", "Frames: 1", "Frame Time: 0.01", " ".join(["0"] * (3 * n_joints + 3))]
    path.write_text("\n".join(body) + "\n")
    return path


def _message_has(*words: str) -> Callable[[str], str | None]:
    return lambda err: None if all(w in err for w in words) else f"the message lacks {words}"


def bvh_content_cases(tmp: Path, db: Path) -> list[Case]:
    """Content that should be refused, each naming its file and line."""
    family = "bad content"
    edits = {
        "Frame Time 0": _edit_lines("Frame Time", lambda _: "Frame Time: 0"),
        "Frame Time inf": _edit_lines("Frame Time", lambda _: "Frame Time: inf"),
        "Frame Time nan": _edit_lines("Frame Time", lambda _: "Frame Time: nan"),
        "Frame Time 2 h": _edit_lines("Frame Time", lambda _: "Frame Time: 7200"),
        "OFFSET nan": _second_offset("nan"),
        "OFFSET inf": _second_offset("inf"),
        "OFFSET 20 km": _second_offset("2e7"),
        "binary file": lambda t: "\x00\x01" * 64,
        "truncated motion": lambda t: t[: len(t) // 2],
        "the same channel twice": _first_channels_doubled,
        "rows beyond Frames:": lambda t: t + t.splitlines()[-1] + "\n",
        "root 1e308 away": lambda t: t.replace("\n".join(t.splitlines()[-1:]), "1e308 " + " ".join(
            t.splitlines()[-1].split()[1:])),
    }
    cases = [Case(family, f"build: BVH {name}", ["build", str(_bvh_variant(tmp, f"c{i}", edit)), "--out", str(db)],
                  protect=db) for i, (name, edit) in enumerate(edits.items())]
    two_bad = tmp / "two_bad"
    two_bad.mkdir()
    (two_bad / "a.bvh").write_text(_first_channels_doubled(GOOD_CLIP.read_text()))
    (two_bad / "b.bvh").write_text("\x00binary")
    cases.append(Case(family, "build: every source skipped names each reason", ["build", str(two_bad), "--out",
                      str(db)], protect=db, check=_message_has("a.bvh", "twice", "b.bvh", "not a text file")))
    return cases


def _flipped_database(db: Path, tmp: Path) -> Path:
    bad = tmp / "flipped.db"
    shutil.copytree(db, bad)
    target = bad / "frames.parquet"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x10
    target.write_bytes(bytes(data))
    return bad


def _write(path: Path, payload: bytes | str) -> Path:
    path.write_bytes(payload.encode() if isinstance(payload, str) else payload)
    return path


def _zip_bomb(path: Path, megabytes: int) -> Path:
    """An .npz whose keypoints member inflates to ``megabytes`` MB of zeros (about 1000:1)."""
    import numpy as np

    n_frames = megabytes * 1_000_000 // (25 * 3 * 8)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf, zf.open("keypoints.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (n_frames, 25, 3)})
        block = bytes(25 * 3 * 8 * 1000)
        for _ in range(n_frames // 1000):
            f.write(block)
        f.write(bytes(25 * 3 * 8 * (n_frames % 1000)))
    return path


def _claiming_npz(path: Path, claimed_bytes: int) -> Path:
    """A small .npz whose zip index claims ``claimed_bytes`` (< 4 GiB) for its member."""
    import numpy as np

    np.savez(path, keypoints=np.zeros((2, 17, 3)))
    data = bytearray(path.read_bytes())
    central = data.index(b"PK\x01\x02")
    data[central + 24:central + 28] = claimed_bytes.to_bytes(4, "little")
    return _write(path, bytes(data))


def special_file_cases(tmp: Path, db: Path, out: Path) -> list[Case]:
    """Files that are not files, or are far bigger than they look."""
    family = "special files"
    fifo = tmp / "pipe.bvh"
    os.mkfifo(fifo)
    links = {}
    for device in ("zero", "urandom"):
        links[device] = tmp / f"{device}.bvh"
        links[device].symlink_to(f"/dev/{device}")
    (tmp / "folder.bvh").mkdir()
    npz_fifo = tmp / "pipe.npz"
    os.mkfifo(npz_fifo)
    recon = ["--db", str(db), "--out", str(out), *CAMERA]
    return [
        Case(family, "inspect: a FIFO named *.bvh", ["inspect", str(fifo)]),
        Case(family, "inspect: symlink to /dev/zero", ["inspect", str(links["zero"])]),
        Case(family, "inspect: symlink to /dev/urandom", ["inspect", str(links["urandom"])]),
        Case(family, "inspect: a folder named *.bvh", ["inspect", str(tmp / "folder.bvh")]),
        Case(family, "build: a FIFO among the sources", ["build", str(fifo), "--out", str(db)], protect=db),
        Case(family, "inspect: 100,000-joint chain (depth 100,000)", ["inspect", str(_chain_bvh(tmp / "chain.bvh",
                                                                                              100_000))]),
        Case(family, "reconstruct: .npz zip bomb (300 MB of zeros)",
             ["reconstruct", str(_zip_bomb(tmp / "bomb.npz", 300)), *recon], protect=out),
        Case(family, "reconstruct: .npz member claiming 4 GB",
             ["reconstruct", str(_claiming_npz(tmp / "liar.npz", 0xFFFFFFFE)), *recon], protect=out),
        Case(family, "reconstruct: .npy claiming 5e12 values", ["reconstruct", str(_write(
            tmp / "huge.npy", b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': "
                              b"(5000000000000, 3), }" + b" " * 40)), *recon], protect=out),
        Case(family, "reconstruct: a FIFO named *.npz", ["reconstruct", str(npz_fifo), *recon], protect=out),
        Case(family, "reconstruct: truncated .npz", ["reconstruct", str(_write(tmp / "cut.npz", b"PK\x03\x04garbage")),
                                                      *recon], protect=out),
        Case(family, "reconstruct: damaged database", ["reconstruct", str(CAM1), "--db", str(_flipped_database(
            db, tmp)), "--out", str(out)], protect=out),
    ]


def _stream_lines(frames: int, n_points: int = 25, start: int = 0) -> list[str]:
    """``frames`` JSON-lines frames of one standing person in BODY_25-like order (``n_points`` points)."""
    import numpy as np

    rng = np.random.default_rng(start)
    lines = []
    for f in range(start, start + frames):
        points = _person_points(n_points, rng)
        lines.append(json.dumps({"frame": f, "people": [{"id": 1, "keypoints": points}]}))
    return lines


def _person_points(n_points: int, rng) -> list[list[float]]:
    """A real person's keypoints from the bundled take (BODY_25B, frame 50), as COCO-17, BODY_25 or
    HALPE_26 by count, with half a pixel of noise."""
    frame = json.loads(sorted(CAM1.glob("*.json"))[50].read_text())
    raw = frame["people"][0]["pose_keypoints_2d"]
    body25b = [raw[i:i + 3] for i in range(0, len(raw), 3)]
    coco17 = body25b[:17]
    points = {17: coco17, 25: body25b, 26: body25b + [body25b[0]]}[n_points]
    return [[x + float(rng.normal(0, 0.5)), y + float(rng.normal(0, 0.5)), c] for x, y, c in points]


def stream_cases(tmp: Path, db: Path) -> list[Case]:
    """Messages a live stream or a keypoint file may carry (``live`` keeps every message: ``--buffer``)."""
    family = "live messages"
    huge = '{"frame": 1' + "0" * 400 + ', "people": []}'
    lines = _stream_lines(40) + [huge] + _stream_lines(40, start=41)
    stream = "\n".join(lines) + "\n"
    sink = tmp / "sink.jsonl"
    mixed = tmp / "mixed.jsonl"
    _write(mixed, "\n".join(_stream_lines(50, 25) + _stream_lines(50, 17, 50) + _stream_lines(50, 26, 100)) + "\n")
    loop_folder = tmp / "loop_take"
    shutil.copytree(CAM1, loop_folder)
    (loop_folder / "cam01.9999.json").symlink_to(loop_folder / "cam01.9999.json")
    os.mkfifo(loop_folder / "cam01.9998.json")
    huge_file = _write(tmp / "huge_frame.jsonl", stream)
    return [
        Case(family, "live: frame 10^400 among 80 good frames (stdin)",
             ["live", "--source", "-", "--db", str(db), "--sink", str(sink), "--buffer", "10000", *CAMERA], expect=0,
             stdin=stream.encode(), check=lambda err: _frames_in(sink, 80)),
        Case(family, "reconstruct: frame 10^400 in a .jsonl", ["reconstruct", str(huge_file), "--db", str(db),
             "--out", str(tmp / "o_huge"), *CAMERA], expect=0,
             check=lambda err: _frames_in(tmp / "o_huge" / "result.jsonl", 80)),
        Case(family, "reconstruct: layouts 25, 17, 26 points mid-stream", ["reconstruct", str(mixed), "--db", str(db),
             "--out", str(tmp / "o_mixed"), *CAMERA], expect=0,
             check=lambda err: _frames_in(tmp / "o_mixed" / "result.jsonl", 150, with_people=149)),  # a track's
        # first frame only starts it: every other frame, before and after each change of layout, holds the person
        Case(family, "reconstruct: folder with a symlink loop and a FIFO", ["reconstruct", str(loop_folder),
             "--db", str(db), "--out", str(tmp / "o_loop"), *CAMERA], expect=0,
             check=lambda err: _frames_in(tmp / "o_loop" / "result.jsonl", 100)),
        Case(family, "live: folder with a symlink loop and a FIFO", ["live", "--source", str(loop_folder), "--db",
             str(db), "--sink", str(tmp / "loop_sink.jsonl"), "--idle-timeout", "3", "--buffer", "10000", *CAMERA],
             expect=0,
             check=lambda err: _frames_in(tmp / "loop_sink.jsonl", 100)),
    ]


def _frames_in(result: Path, frames: int, with_people: int | None = None) -> str | None:
    """What is wrong with a result stream expected to hold ``frames`` frames (None: nothing)."""
    if not result.is_file():
        return f"no {result.name}"
    rows = [json.loads(line) for line in result.read_text().splitlines()[1:] if line.strip()]
    if len(rows) != frames:
        return f"{len(rows)} frames in {result.name}, expected {frames}"
    people = sum(bool(r.get("people")) for r in rows)
    if with_people is not None and people < with_people:
        return f"{people} frames with a person, expected {with_people}"
    return None


def option_cases(tmp: Path, db: Path, out: Path) -> list[Case]:
    """A sample of the numeric options the issue named (tests/test_options.py walks them all)."""
    family = "numeric options"
    recon = ["reconstruct", str(CAM1), "--db", str(db), "--out", str(out)]
    values = [(recon, "--per-cluster", "0"), (recon, "--clusters-searched", "100000000000000000000"),
              (recon, "--fps", "nan"), (recon, "--fps", "-1"), (recon, "--focal", "1e308"),
              (recon, "--image-size", "100000000000000000000x2000"), (recon, "--bvh-part-min", "inf"),
              (recon, "--window-weights", "nan,1"), (recon, "--min-cutoff", "-1"), (recon, "--subject-height", "0"),
              (["live", "--source", "-", "--db", str(db)], "--buffer", "0"),
              (["live", "--source", "-", "--db", str(db)], "--max-rate", "inf"),
              (["stereo", str(CAM1), str(CAM4), "--out", str(tmp / "s"), "--image-size", "1088x1920"], "--center",
               "1e308 5"),
              (["stereo", str(CAM1), str(CAM4), "--out", str(tmp / "s"), "--calibration", str(CALIBRATION),
                "--cameras", "cam_01", "cam_04"], "--camera-distance", "1e308"),
              (["render", str(out), "--out", str(tmp / "r")], "--scale", "0"),
              (["build", str(GOOD_CLIP), "--out", str(db)], "--fps", "1e-6"),
              (["build", str(GOOD_CLIP), "--out", str(db)], "--yaw-step", "nan"),
              (["eval", "--db", str(db), "--bvh", str(GOOD_CLIP)], "--weight-2d", "nan")]
    return [Case(family, f"{argv[0]}: {option} {value[:24]}", [*argv, option, *value.split()], protect=out,
                 check=_message_has(f"argument {option}:")) for argv, option, value in values]


def output_cases(tmp: Path, db: Path, out: Path) -> list[Case]:
    """Outputs pointed at inputs, or at folders holding the user's files."""
    family = "outputs over inputs"
    take = tmp / "take_copy"
    shutil.copytree(CAM1, take)
    users = tmp / "users_folder"
    users.mkdir()
    (users / "calibration.toml").write_text("# the user's own calibration\n")
    (users / "result.jsonl").write_text("the user's own results\n")
    stereo = [str(CAM1), str(CAM4), "--calibration", str(CALIBRATION), "--cameras", "cam_01", "cam_04", "--fps", "60"]
    sources = tmp / "bvh_sources"
    shutil.copytree(SAMPLE_BVH, sources)
    return [
        Case(family, "reconstruct: --out is the input", ["reconstruct", str(take), "--db", str(db), "--out",
             str(take), *CAMERA], protect=take),
        Case(family, "reconstruct: --out holds the input", ["reconstruct", str(take), "--db", str(db), "--out",
             str(tmp), *CAMERA], protect=take),
        Case(family, "reconstruct: --out a folder of the user's files", ["reconstruct", str(CAM1), "--db", str(db),
             "--out", str(users), *CAMERA], protect=users),
        Case(family, "stereo: --out a folder of the user's files", ["stereo", *stereo, "--out", str(users)],
             protect=users),
        Case(family, "stereo: --out is its own input view", ["stereo", str(take), str(CAM4), "--calibration",
             str(CALIBRATION), "--cameras", "cam_01", "cam_04", "--out", str(take)], protect=take),
        Case(family, "build: --out inside the sources", ["build", str(sources), "--out", str(sources / "db")],
             protect=sources),
        Case(family, "build: --out is a BVH file", ["build", str(GOOD_CLIP), "--out", str(GOOD_CLIP)],
             protect=GOOD_CLIP),
        Case(family, "render: --out inside its input", ["render", str(out), "--out", str(out / "frames")],
             protect=out),
        Case(family, "render: --out a folder of the user's files", ["render", str(out), "--out", str(users)],
             protect=users),
        Case(family, "live: --sink inside the watched folder", ["live", "--source", str(take), "--db", str(db),
             "--sink", str(take / "out.jsonl"), "--idle-timeout", "1"], protect=take),
        Case(family, "eval: --out is the database folder", ["eval", "--db", str(db), "--bvh", str(GOOD_CLIP),
             "--out", str(db)], protect=db),
    ]


def _far_result(tmp: Path, out: Path) -> Path:
    """The sample's result with every position moved 1e9 m away."""
    far = tmp / "far_result"
    far.mkdir()
    lines = (out / "result.jsonl").read_text().splitlines()
    moved = [lines[0]]
    for line in lines[1:]:
        frame = json.loads(line)
        for person in frame["people"]:
            person["joints"] = [[x + 1e9, y, z + 1e9] for x, y, z in person["joints"]]
            person["root"] = [person["root"][0] + 1e9, person["root"][1], person["root"][2] + 1e9]
        moved.append(json.dumps(frame))
    _write(far / "result.jsonl", "\n".join(moved[:6]) + "\n")
    return far


def _shifted_view(tmp: Path) -> Path:
    """Camera 4's frames from another moment of the take: frame i holds frame i + 50 (wrapped)."""
    view = tmp / "cam04_shifted"
    view.mkdir()
    files = sorted(CAM4.glob("cam04.*.json"))
    for i, f in enumerate(files):
        shutil.copy(files[(i + 50) % len(files)], view / f.name)
    return view


def render_stereo_cases(tmp: Path, out: Path) -> list[Case]:
    family = "render and stereo"
    binary = _write(tmp / "binary.toml", bytes(range(256)) * 4)
    common = ["--fps", "60", "--out", str(tmp / "stereo_out")]
    return [
        Case(family, "render: a person 1e9 m away", ["render", str(_far_result(tmp, out)), "--out",
                                                      str(tmp / "far_frames")], expect=None),
        Case(family, "stereo: unsynchronised views", ["stereo", str(CAM1), str(_shifted_view(tmp)), "--calibration",
             str(CALIBRATION), "--cameras", "cam_01", "cam_04", *common], expect=None),
        Case(family, "stereo: the same view twice", ["stereo", str(CAM1), str(CAM1), "--calibration", str(CALIBRATION),
             "--cameras", "cam_01", "cam_01", *common]),
        Case(family, "stereo: binary calibration", ["stereo", str(CAM1), str(CAM4), "--calibration", str(binary),
             "--cameras", "cam_01", "cam_04", *common]),
        Case(family, "eval: folder without BVH", ["eval", "--db", str(tmp / "good.db"), "--bvh", str(_empty(tmp))]),
    ]


def _empty(tmp: Path) -> Path:
    folder = tmp / "no_bvh"
    folder.mkdir(exist_ok=True)
    return folder


def service_account_cases(tmp: Path) -> list[Case]:
    """No writable home, package folder or (second case) temporary folder: a read-only container."""
    if subprocess.run(["unshare", "--mount", "true"], capture_output=True).returncode != 0:
        return []
    family = "service account"
    readonly = tmp / "readonly"
    readonly.mkdir()
    mounts = " && ".join(f"mount --bind -o ro {p} {p}" for p in (ROOT / "mocapdb", ROOT / "runtime", readonly))
    env = {"HOME": str(readonly), "XDG_CACHE_HOME": str(readonly)}
    return [Case(family, f"inspect: read-only home and package{extra}", ["inspect", str(GOOD_CLIP)], expect=0,
                 prefix=["unshare", "--mount", "sh", "-c", f'{mounts} && exec "$0" "$@"'],
                 env={**env, **({"TMPDIR": str(readonly)} if extra else {})})
            for extra in ("", ", no writable temporary folder")]


def _folder_bytes(folder: Path) -> int:
    total = 0
    for path, _, files in os.walk(folder):
        for name in files:
            try:
                total += os.lstat(os.path.join(path, name)).st_size
            except OSError:
                pass
    return total


def run_case(case: Case, work: Path) -> dict:
    """Run one case as a subprocess; its peak memory from ``wait4`` and its written bytes from ``work``."""
    before = _digest(case.protect) if case.protect is not None and case.protect.exists() else None
    written_before = _folder_bytes(work)
    argv = [*case.prefix, sys.executable, "-m", "mocapdb", *case.args]
    with tempfile.TemporaryFile() as err_file, tempfile.TemporaryFile() as in_file:
        in_file.write(case.stdin)
        in_file.seek(0)
        start = time.perf_counter()
        proc = subprocess.Popen(argv, stdin=in_file, stdout=subprocess.DEVNULL, stderr=err_file, cwd=ROOT,
                                env={**os.environ, **case.env}, start_new_session=True)
        timer = threading.Timer(TIMEOUT_S, lambda: os.killpg(proc.pid, signal.SIGKILL))
        timer.start()
        _, status, usage = os.wait4(proc.pid, 0)
        timer.cancel()
        seconds = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        err_file.seek(0)
        stderr = err_file.read().decode("utf-8", "replace")
    hang = seconds >= TIMEOUT_S
    lost = before is not None and (not case.protect.exists() or _digest(case.protect) != before)
    traceback = "Traceback (most recent call last)" in stderr
    runaway = usage.ru_maxrss / 1024 > MAX_RSS_MB or (_folder_bytes(work) - written_before) / 1e6 > MAX_OUTPUT_MB
    problem = case.check(stderr) if case.check is not None and not hang else None
    exit_ok = proc.returncode in ((0, 2) if case.expect is None else (case.expect,))
    garbage = proc.returncode == 0 and case.expect == 2
    return {"family": case.family, "case": case.name, "exit": proc.returncode, "seconds": seconds,
            "peak_mb": usage.ru_maxrss / 1024, "traceback": traceback, "hang": hang, "runaway": runaway,
            "lost": lost, "garbage": garbage, "problem": problem,
            "ok": exit_ok and not (traceback or hang or runaway or lost or problem),
            "message": problem or (stderr.strip().splitlines() or [""])[-1][:150]}


def _prepare(tmp: Path) -> tuple[Path, Path]:
    """A small database and the sample's reconstruction, the inputs most cases need."""
    db, out = tmp / "good.db", tmp / "out"
    subprocess.run([sys.executable, "-m", "mocapdb", "build", str(SAMPLE_BVH), "--out", str(db), "--clusters", "50",
                    "--landmarks", "300"], check=True, capture_output=True, cwd=ROOT)
    subprocess.run([sys.executable, "-m", "mocapdb", "reconstruct", str(CAM1), "--db", str(db), "--out", str(out),
                    *CAMERA], check=True, capture_output=True, cwd=ROOT)
    return db, out


def all_cases(tmp: Path, db: Path, out: Path) -> list[Case]:
    return (option_cases(tmp, db, out) + output_cases(tmp, db, out) + stream_cases(tmp, db)
            + special_file_cases(tmp, db, out) + bvh_content_cases(tmp, db) + render_stereo_cases(tmp, out)
            + service_account_cases(tmp))


def print_tables(rows: list[dict]) -> None:
    for r in rows:
        flag = "ok  " if r["ok"] else "FAIL"
        print(f"{flag} exit {r['exit']:>3} {r['seconds']:6.1f} s {r['peak_mb']:6.0f} MB  {r['case']:<52} "
              f"{r['message']}")
    print()
    print("| family | cases | passed | tracebacks | hangs | runaway resources | inputs lost | garbage accepted |")
    print("|---|---|---|---|---|---|---|---|")
    families = list(dict.fromkeys(r["family"] for r in rows))
    for family in [*families, "all"]:
        group = [r for r in rows if family in ("all", r["family"])]
        counts = [sum(r[k] for r in group) for k in ("ok", "traceback", "hang", "runaway", "lost", "garbage")]
        name = f"**{family}**" if family == "all" else family
        print(f"| {name} | {len(group)} | " + " | ".join(str(c) for c in counts) + " |")
    print(f"\npeak memory of any case: {max(r['peak_mb'] for r in rows):.0f} MB; slowest: "
          f"{max(r['seconds'] for r in rows):.1f} s")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--keep", type=Path, help="work in this folder and keep it (default: a temporary one)")
    ap.add_argument("--family", help="run only the cases of this family")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="mocapdb-faults-")) if args.keep is None else args.keep
    tmp.mkdir(parents=True, exist_ok=True)
    db, out = _prepare(tmp)
    cases = [c for c in all_cases(tmp, db, out) if args.family in (None, c.family)]
    rows = [run_case(c, tmp) for c in cases]
    print_tables(rows)
    if args.keep is None:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
