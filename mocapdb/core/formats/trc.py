"""TRC marker files (OpenSim / Pose2Sim 3D trajectories): reading, writing, and the universal keypoints in them.

A TRC file is tab-separated text: ``PathFileType`` line, a line of header keys (``DataRate``,
``NumFrames``, ``NumMarkers``, ``Units``, ...) and one of their values, a line ``Frame# Time
<marker> <marker> ...`` (each marker name followed by two empty cells), a line of coordinate
labels (``X1 Y1 Z1 ...``), then one row per frame: frame number, time in seconds, then x y z per
marker. An empty cell is a missing value.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB, read_input_text
from mocapdb.core.skeleton import KP, N_POINTS

TRC_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}  # metres per file unit
MAX_TRC_BYTES = 256 * MIB  # an hour of 60 markers at 100 Hz takes ~250 MiB
_REQUIRED_KEYS = ("DataRate", "NumFrames", "NumMarkers", "Units")
# The marker giving each universal keypoint (OpenPose names, as Pose2Sim writes them); the neck
# and the pelvis are midpoints (the universal neck is the mid-shoulder point, not a neck marker).
_MARKER_OF = {
    "head": "Nose", "r_shoulder": "RShoulder", "r_elbow": "RElbow", "r_wrist": "RWrist",
    "l_shoulder": "LShoulder", "l_elbow": "LElbow", "l_wrist": "LWrist", "r_hip": "RHip",
    "r_knee": "RKnee", "r_ankle": "RAnkle", "l_hip": "LHip", "l_knee": "LKnee", "l_ankle": "LAnkle"}
_MIDPOINTS = {"neck": ("r_shoulder", "l_shoulder"), "pelvis": ("r_hip", "l_hip")}


class TrcError(MocapdbError, ValueError):
    """A TRC file that cannot be read; the message names the file, the line and the problem."""


@dataclass
class Trc:
    """Marker trajectories: ``positions [F, M, 3]`` metres (NaN where missing), in the file's axes."""

    markers: list[str]
    rate_hz: float
    frame_numbers: np.ndarray  # [F] int, as in the file
    times_s: np.ndarray        # [F] seconds
    positions: np.ndarray      # [F, M, 3] metres
    source: str = ""


def _fail(source: str, line: int, message: str) -> TrcError:
    return TrcError(f"{source}:{line}: {message}")


def _header(lines: list[str], source: str) -> dict[str, str]:
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise _fail(source, 1, "not a TRC file (it does not start with PathFileType and four header lines)")
    keys, values = lines[1].split("\t"), lines[2].split("\t")
    header = {k.strip(): v.strip() for k, v in zip(keys, values)}
    missing = [k for k in _REQUIRED_KEYS if k not in header]
    if missing:
        raise _fail(source, 2, f"header lacks {', '.join(missing)}")
    return header


def _number(text: str, what: str, kind: type, source: str, line: int):
    try:
        value = kind(text)
    except ValueError:
        raise _fail(source, line, f"{what} {text!r} is not a number") from None
    if not (value > 0 and np.isfinite(value)):
        raise _fail(source, line, f"{what} must be positive, got {text!r}")
    return value


def _data(rows: list[str], n_markers: int, source: str, first_line: int) -> np.ndarray:
    """Rows → ``[F, 2 + 3M]`` floats (NaN for empty cells); errors name the line."""
    width = 2 + 3 * n_markers
    out = np.full((len(rows), width), np.nan)
    for i, row in enumerate(rows):
        cells = row.rstrip("\r\n").split("\t")
        while len(cells) > width and not cells[-1].strip():
            cells.pop()
        if len(cells) != width:
            raise _fail(source, first_line + i,
                        f"{len(cells)} values, expected {width} (frame, time, xyz × {n_markers})")
        try:
            out[i] = [float(c) if c.strip() else np.nan for c in cells]
        except ValueError:
            raise _fail(source, first_line + i, "non-numeric value") from None
    return out


def parse_trc(text: str, source: str = "<text>") -> Trc:
    """Parse TRC text; raises :class:`TrcError` naming ``source`` and the line on any defect."""
    lines = text.splitlines()
    header = _header(lines, source)
    n_frames = _number(header["NumFrames"], "NumFrames", int, source, 3)
    n_markers = _number(header["NumMarkers"], "NumMarkers", int, source, 3)
    rate = _number(header["DataRate"], "DataRate", float, source, 3)
    units = header["Units"]
    if units not in TRC_UNITS:
        raise _fail(source, 3, f"unit {units!r} is not one of {', '.join(TRC_UNITS)}")
    names = [c.strip() for c in lines[3].split("\t")[2:] if c.strip()]
    if lines[3].split("\t")[:2] != ["Frame#", "Time"] or len(names) != n_markers:
        raise _fail(source, 4, f"expected 'Frame#', 'Time' and {n_markers} marker names, got {len(names)} names")
    rows = [(i + 6, row) for i, row in enumerate(lines[5:]) if row.strip()]
    if len(rows) < n_frames:
        raise _fail(source, len(lines), f"header says {n_frames} frames but only {len(rows)} are present (truncated?)")
    values = _data([r for _, r in rows[:n_frames]], n_markers, source, rows[0][0])
    if np.isnan(values[:, :2]).any():
        raise _fail(source, rows[0][0], "a row lacks its frame number or time")
    positions = values[:, 2:].reshape(n_frames, n_markers, 3) * TRC_UNITS[units]
    return Trc(names, rate, values[:, 0].astype(np.int64), values[:, 1], positions, source)


def read_trc(path: str | Path) -> Trc:
    """Read a TRC file; raises :class:`TrcError` naming the file."""
    path = Path(path)
    return parse_trc(read_input_text(path, MAX_TRC_BYTES, TrcError, "TRC file"), str(path))


def trc_keypoints(trc: Trc) -> np.ndarray:
    """The universal keypoints ``[F, 15, 3]`` (metres, the file's axes) the TRC's markers give.

    Markers by their OpenPose names (``Nose``, ``RShoulder``, ...); neck and pelvis are the
    mid-shoulder and mid-hip points. NaN for a keypoint whose marker the file lacks.
    """
    out = np.full((len(trc.positions), N_POINTS, 3), np.nan)
    for keypoint, marker in _MARKER_OF.items():
        if marker in trc.markers:
            out[:, KP[keypoint]] = trc.positions[:, trc.markers.index(marker)]
    for keypoint, (a, b) in _MIDPOINTS.items():
        out[:, KP[keypoint]] = 0.5 * (out[:, KP[a]] + out[:, KP[b]])
    return out


def format_trc(markers: list[str], positions_m: np.ndarray, rate_hz: float, frame_numbers: np.ndarray | None = None,
               times_s: np.ndarray | None = None, name: str = "markers.trc", decimals: int = 5) -> str:
    """TRC text (OpenSim's layout, metres) of ``positions_m [F, M, 3]``; NaN becomes an empty cell.

    ``frame_numbers`` default 1..F, ``times_s`` default ``(frame_numbers - first) / rate_hz``.
    """
    positions = np.asarray(positions_m, dtype=np.float64)
    n_frames, n_markers = positions.shape[:2]
    if len(markers) != n_markers:
        raise ValueError(f"{len(markers)} marker names for {n_markers} markers")
    frames = np.arange(1, n_frames + 1) if frame_numbers is None else np.asarray(frame_numbers, dtype=np.int64)
    times = (frames - frames[0]) / rate_hz if times_s is None else np.asarray(times_s, dtype=np.float64)
    header = [f"PathFileType\t4\t(X/Y/Z)\t{name}",
              "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames",
              f"{rate_hz:g}\t{rate_hz:g}\t{n_frames}\t{n_markers}\tm\t{rate_hz:g}\t{int(frames[0])}\t{n_frames}",
              "Frame#\tTime\t" + "\t".join(f"{m}\t\t" for m in markers).rstrip("\t"),
              "\t\t" + "\t".join(f"X{i}\tY{i}\tZ{i}" for i in range(1, n_markers + 1)),
              ""]
    values = np.char.mod(f"%.{decimals}f", np.round(positions.reshape(n_frames, -1), decimals) + 0.0)
    values[np.isnan(positions.reshape(n_frames, -1))] = ""
    rows = [f"{f}\t{t:.6f}\t" + "\t".join(v) for f, t, v in zip(frames, times, values)]
    return "\n".join(header + rows) + "\n"
