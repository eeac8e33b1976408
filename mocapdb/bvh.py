"""BVH motion files: reading, writing and forward kinematics.

Reads what real exporters write: any channel order and count per joint, ``End Site`` blocks,
CRLF or LF, tabs, scientific notation. Semantics (the common reading, also Blender's):

* a joint's local translation is ``OFFSET`` plus its position channels (if any);
* rotation channels compose intrinsically in the listed order: ``Zrotation Yrotation Xrotation``
  gives ``R = Rz @ Ry @ Rx`` (degrees);
* ``End Site`` blocks become joints with no channels whose name is ``<parent>_End``.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .geometry import euler_to_matrix, matrix_to_euler

VALID_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")


class BvhError(ValueError):
    """A BVH file that cannot be read; the message names the file and the problem."""


@dataclass
class Bvh:
    """A BVH skeleton and its motion.

    ``names[j]``, ``parents[j]`` (-1 for the root; parents come before children),
    ``offsets[j]`` (file units), ``channels[j]`` (channel names, empty for end sites),
    ``end_site[j]``; ``motion [F, C]`` holds the channel values frame by frame in file order.
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    end_site: np.ndarray
    frame_time: float
    motion: np.ndarray
    source: str = ""
    channel_start: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        counts = np.array([len(c) for c in self.channels], dtype=np.int64)
        self.channel_start = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    def index(self, name: str) -> int:
        return self.names.index(name)

    def children(self, joint: int) -> list[int]:
        return [int(c) for c in np.flatnonzero(self.parents == joint)]


_TOKEN = re.compile(r"\S+")


def _fail(source: str, line: int, message: str) -> BvhError:
    where = f"{source}:{line}" if line else source
    return BvhError(f"{where}: {message}")


def parse_bvh(text: str, source: str = "<text>") -> Bvh:
    """Parse BVH text; raises :class:`BvhError` naming ``source`` and the line on any defect."""
    motion_at = re.search(r"^\s*MOTION\s*$", text, flags=re.MULTILINE)
    if not text.lstrip().startswith("HIERARCHY"):
        raise _fail(source, 1, "not a BVH file (it does not start with HIERARCHY)")
    if motion_at is None:
        raise _fail(source, 0, "no MOTION section (file truncated?)")
    header = text[:motion_at.start()]
    names, parents, offsets, channels, end_site = _parse_hierarchy(header, source)
    first_motion_line = header.count("\n") + 2
    frame_time, motion = _parse_motion(text[motion_at.end():], sum(len(c) for c in channels),
                                       source, first_motion_line)
    return Bvh(names, np.array(parents, dtype=np.int64), np.array(offsets, dtype=np.float64),
               channels, np.array(end_site, dtype=bool), frame_time, motion, source)


def _parse_hierarchy(header: str, source: str):
    tokens = [(m.group(0), header.count("\n", 0, m.start()) + 1) for m in _TOKEN.finditer(header)]
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    end_site: list[bool] = []
    stack: list[int] = []
    pending: int | None = None  # joint declared, waiting for its "{"
    i = 1  # skip HIERARCHY
    while i < len(tokens):
        tok, line = tokens[i]
        if tok in ("ROOT", "JOINT") or tok == "End":
            if tok == "ROOT" and names:
                raise _fail(source, line, "more than one ROOT is not supported")
            if tok == "JOINT" and not stack:
                raise _fail(source, line, "JOINT outside any parent")
            if tok == "End":
                if i + 1 >= len(tokens) or tokens[i + 1][0] != "Site":
                    raise _fail(source, line, "'End' must be followed by 'Site'")
                name = f"{names[stack[-1]]}_End" if stack else "End"
            else:
                if i + 1 >= len(tokens):
                    raise _fail(source, line, f"{tok} without a name")
                name = tokens[i + 1][0]
            if name in names:
                raise _fail(source, line, f"joint name {name!r} appears twice")
            names.append(name)
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append([])
            end_site.append(tok == "End")
            pending = len(names) - 1
            i += 2
        elif tok == "{":
            if pending is None:
                raise _fail(source, line, "'{' without a joint")
            stack.append(pending)
            pending = None
            i += 1
        elif tok == "}":
            if not stack:
                raise _fail(source, line, "unbalanced '}'")
            stack.pop()
            i += 1
        elif tok == "OFFSET":
            if not stack:
                raise _fail(source, line, "OFFSET outside a joint")
            try:
                offsets[stack[-1]] = [float(t) for t, _ in tokens[i + 1:i + 4]]
            except ValueError:
                raise _fail(source, line, "OFFSET needs three numbers") from None
            if len(offsets[stack[-1]]) != 3:
                raise _fail(source, line, "OFFSET needs three numbers")
            i += 4
        elif tok == "CHANNELS":
            if not stack or end_site[stack[-1]]:
                raise _fail(source, line, "CHANNELS outside a joint")
            try:
                count = int(tokens[i + 1][0])
            except (ValueError, IndexError):
                raise _fail(source, line, "CHANNELS needs a count") from None
            names_here = [t for t, _ in tokens[i + 2:i + 2 + count]]
            bad = [c for c in names_here if c not in VALID_CHANNELS]
            if bad or len(names_here) != count:
                raise _fail(source, line, f"bad channel list {names_here!r} (count {count})")
            channels[stack[-1]] = names_here
            i += 2 + count
        else:
            raise _fail(source, line, f"unexpected {tok!r} in HIERARCHY")
    if stack:
        raise _fail(source, tokens[-1][1] if tokens else 0, "unclosed '{' in HIERARCHY")
    if not names:
        raise _fail(source, 0, "no ROOT joint")
    return names, parents, offsets, channels, end_site


def _parse_motion(body: str, n_channels: int, source: str, line0: int) -> tuple[float, np.ndarray]:
    lines = body.splitlines()
    fields = {}
    k = 0
    while k < len(lines) and len(fields) < 2:
        stripped = lines[k].strip()
        k += 1
        if not stripped:
            continue
        key, _, value = stripped.partition(":")
        key = " ".join(key.split())
        if key not in ("Frames", "Frame Time"):
            raise _fail(source, line0 + k - 1, f"expected 'Frames:' and 'Frame Time:', got {stripped[:40]!r}")
        fields[key] = value.strip()
    try:
        n_frames = int(fields["Frames"])
        frame_time = float(fields["Frame Time"])
    except (KeyError, ValueError):
        raise _fail(source, line0, "missing or malformed 'Frames:' / 'Frame Time:'") from None
    if n_frames < 1 or not frame_time > 0:
        raise _fail(source, line0, f"{n_frames} frames at frame time {frame_time}: nothing to read")
    rows = [ln for ln in lines[k:] if ln.strip()]
    if len(rows) < n_frames:
        raise _fail(source, 0, f"header says {n_frames} frames but only {len(rows)} are present (truncated?)")
    try:
        values = np.array(" ".join(rows[:n_frames]).split(), dtype=np.float64)
    except ValueError:
        raise _fail(source, 0, "non-numeric value in the MOTION data") from None
    if values.size != n_frames * n_channels:
        per_row = [len(r.split()) for r in rows[:n_frames]]
        bad = next(i for i, n in enumerate(per_row) if n != n_channels)
        raise _fail(source, line0 + k + bad, f"frame {bad} has {per_row[bad]} values, expected {n_channels}")
    if not np.all(np.isfinite(values)):
        raise _fail(source, 0, "NaN or infinite value in the MOTION data")
    return frame_time, values.reshape(n_frames, n_channels)


def read_bvh(path: str | os.PathLike) -> Bvh:
    """Read a BVH file (any line endings); raises :class:`BvhError` naming the file."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise BvhError(f"{path}: cannot read ({exc.strerror})") from None
    return parse_bvh(text, str(path))


def _fmt(x: float) -> str:
    return f"{x:.6f}" if abs(x) >= 1e-4 or x == 0 else f"{x:.9e}"


def format_bvh(bvh: Bvh, decimals: int = 6) -> str:
    """BVH text for ``bvh`` (LF line endings, tab indentation, values with ``decimals`` places)."""
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "\t" * depth
        if bvh.end_site[j]:
            out.append(f"{pad}End Site")
        else:
            out.append(f"{pad}{'ROOT' if bvh.parents[j] < 0 else 'JOINT'} {bvh.names[j]}")
        out.append(pad + "{")
        out.append(f"{pad}\tOFFSET " + " ".join(_fmt(v) for v in bvh.offsets[j]))
        if not bvh.end_site[j]:
            out.append(f"{pad}\tCHANNELS {len(bvh.channels[j])} " + " ".join(bvh.channels[j]))
        for c in bvh.children(j):
            emit(c, depth + 1)
        out.append(pad + "}")

    emit(0, 0)
    out.append("MOTION")
    out.append(f"Frames: {bvh.n_frames}")
    out.append(f"Frame Time: {bvh.frame_time:.8f}")
    body = np.char.mod(f"%.{decimals}f", np.round(bvh.motion, decimals) + 0.0)
    out.extend(" ".join(row) for row in body)
    return "\n".join(out) + "\n"


def write_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (never a half file)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def write_bvh(path: str | os.PathLike, bvh: Bvh, decimals: int = 6) -> None:
    """Write ``bvh`` atomically."""
    write_atomic(path, format_bvh(bvh, decimals))


def local_transforms(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame local rotations ``[F, J, 3, 3]`` and translations ``[F, J, 3]`` (file units)."""
    n_frames, n_joints = bvh.n_frames, len(bvh.names)
    rot = np.broadcast_to(np.eye(3), (n_frames, n_joints, 3, 3)).copy()
    trans = np.broadcast_to(bvh.offsets, (n_frames, n_joints, 3)).copy()
    for j, chans in enumerate(bvh.channels):
        start = bvh.channel_start[j]
        rot_cols = [start + i for i, c in enumerate(chans) if c.endswith("rotation")]
        if rot_cols:
            order = "".join(c[0] for c in chans if c.endswith("rotation"))
            rot[:, j] = euler_to_matrix(bvh.motion[:, rot_cols], order)
        for i, c in enumerate(chans):
            if c.endswith("position"):
                trans[:, j, "XYZ".index(c[0])] += bvh.motion[:, start + i]
    return rot, trans


def accumulate_transforms(parents: np.ndarray, local_rot: np.ndarray,
                          local_trans: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chain local rotations ``[F, J, 3, 3]`` and translations ``[F, J, 3]`` down a hierarchy.

    ``parents[j] < j`` (or -1 for a root). Returns global positions ``[F, J, 3]`` and rotations
    ``[F, J, 3, 3]``; one pass over the joints, vectorised over frames.
    """
    g_rot = np.empty_like(local_rot)
    g_pos = np.empty_like(local_trans)
    for j, p in enumerate(parents):
        if p < 0:
            g_rot[:, j] = local_rot[:, j]
            g_pos[:, j] = local_trans[:, j]
        else:
            g_rot[:, j] = g_rot[:, p] @ local_rot[:, j]
            g_pos[:, j] = g_pos[:, p] + np.einsum("fab,fb->fa", g_rot[:, p], local_trans[:, j])
    return g_pos, g_rot


def forward_kinematics(bvh: Bvh) -> tuple[np.ndarray, np.ndarray]:
    """Global joint positions ``[F, J, 3]`` (file units) and rotations ``[F, J, 3, 3]``."""
    rot, trans = local_transforms(bvh)
    return accumulate_transforms(bvh.parents, rot, trans)


def motion_from_rotations(bvh: Bvh, local_rot: np.ndarray, root_translation: np.ndarray) -> np.ndarray:
    """Channel values ``[F, C]`` that give local rotations ``[F, J, 3, 3]`` and root translation.

    ``root_translation [F, 3]`` is the root's position channels (added to its OFFSET).
    Every joint's rotation channels must be three distinct axes.
    """
    motion = np.zeros((local_rot.shape[0], int(sum(len(c) for c in bvh.channels))))
    for j, chans in enumerate(bvh.channels):
        start = bvh.channel_start[j]
        rot_cols = [start + i for i, c in enumerate(chans) if c.endswith("rotation")]
        if rot_cols:
            order = "".join(c[0] for c in chans if c.endswith("rotation"))
            motion[:, rot_cols] = matrix_to_euler(local_rot[:, j], order)
        for i, c in enumerate(chans):
            if c.endswith("position") and j == 0:
                motion[:, start + i] = root_translation[:, "XYZ".index(c[0])]
    return motion
