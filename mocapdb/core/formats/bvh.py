"""BVH motion files: reading, writing and forward kinematics.

Reads what real exporters write: any channel order and count per joint, ``End Site`` blocks,
CRLF or LF, tabs, scientific notation, a UTF-8 byte-order mark, joint names with spaces (3ds Max
Biped's ``Bip01 L Thigh``: a name is the rest of its ``ROOT``/``JOINT`` line). Semantics
(``data_specs/joint_conventions.md``):

* the root's local translation is its ``OFFSET`` plus its position channels (if any);
* a non-root joint's position channels are read per file (:func:`detect_position_mode`): added
  to its ``OFFSET``, or replacing it when frame 0 repeats the offsets (as Blender's exporter
  writes them);
* rotation channels compose intrinsically in the listed order: ``Zrotation Yrotation Xrotation``
  gives ``R = Rz @ Ry @ Rx`` (degrees);
* ``End Site`` blocks become joints with no channels whose name is ``<parent>_End``.
"""
from __future__ import annotations

import functools
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import numpy as np

from mocapdb.core.files import MIB, read_input_text, write_atomic
from mocapdb.core.formats.bvh_motion import MAX_POSITION, BvhError, bvh_error, parse_motion
from mocapdb.core.geometry import euler_to_matrix, matrix_to_euler
from mocapdb.core.hierarchy import children_and_depths, subtree_bounds, with_ancestors

VALID_CHANNELS = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
MAX_BVH_BYTES = 256 * MIB   # a larger file is read in parts (hours of motion at 120 fps fit below)
MAX_INDENT_TABS = 32        # written HIERARCHY indentation stops deepening here (deep chains stay linear text)
# How non-root position channels are read (``Bvh.position_mode``), and how `mocapdb inspect` says it.
NO_POSITIONS = "none"
ADDED = "offset+channel"
REPLACED = "channel replaces offset"
POSITION_MODE_TEXT = {NO_POSITIONS: "none",
                      ADDED: "added to the OFFSET",
                      REPLACED: "replace the OFFSET (Blender style)"}
# Frame-0 position channels "equal" a joint's OFFSET within this fraction of the bone, or ABS units.
POSITION_MATCH_REL = 0.01
POSITION_MATCH_ABS = 1e-3


@dataclass
class Bvh:
    """A BVH skeleton and its motion.

    ``names[j]``, ``parents[j]`` (-1 for the root; parents come before children),
    ``offsets[j]`` (file units), ``channels[j]`` (channel names, empty for end sites),
    ``end_site[j]``; ``motion [F, C]`` holds the channel values frame by frame in file order.
    ``position_mode`` says how non-root position channels are read (:data:`ADDED`,
    :data:`REPLACED`, or :data:`NO_POSITIONS` when there are none).
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray
    channels: list[list[str]]
    end_site: np.ndarray
    frame_time: float
    motion: np.ndarray
    source: str = ""
    position_mode: str = NO_POSITIONS
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

    @functools.cached_property
    def subtree_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Each joint's pre-order rank and the rank after its last descendant (:func:`subtree_bounds`)."""
        return subtree_bounds(self.parents)

    def subtree(self, joint: int) -> np.ndarray:
        """Whether each joint ``[J]`` (bool) is ``joint`` or lies below it; O(J), any depth."""
        rank, end = self.subtree_bounds
        return (rank >= rank[joint]) & (rank < end[joint])


_TOKEN = re.compile(r"\S+")


def parse_bvh(text: str, source: str = "<text>") -> Bvh:
    """Parse BVH text; raises :class:`BvhError` naming ``source`` and the line on any defect."""
    text = text.removeprefix("\ufeff")
    if "\0" in text:
        raise bvh_error(source, 0, "not a text file (it holds NUL bytes: binary data, not BVH)")
    if not text.lstrip().startswith("HIERARCHY"):
        raise bvh_error(source, 1, "not a BVH file (it does not start with HIERARCHY)")
    motion_at = re.search(r"^[ \t]*MOTION[ \t\r]*$", text, flags=re.MULTILINE)
    if motion_at is None:
        raise bvh_error(source, 0, "no MOTION section (file truncated?)")
    header = text[:motion_at.start()]
    joints = _parse_hierarchy(header, source)
    labels = [f"{name} {c}" for name, chans in zip(joints.names, joints.channels) for c in chans]
    frame_time, motion = parse_motion(text[motion_at.end():], labels, source, header.count("\n") + 1)
    bvh = Bvh(joints.names, np.array(joints.parents, dtype=np.int64), np.array(joints.offsets, dtype=np.float64),
              joints.channels, np.array(joints.end_site, dtype=bool), frame_time, motion, source)
    bvh.position_mode = detect_position_mode(bvh)
    return bvh


class _Token(NamedTuple):
    text: str
    line: int   # 1-based
    start: int  # span within the line
    end: int


@dataclass
class _Hierarchy:
    """The joints a HIERARCHY section declares, filled token by token."""

    source: str
    names: list[str] = field(default_factory=list)
    parents: list[int] = field(default_factory=list)
    offsets: list[list[float]] = field(default_factory=list)
    channels: list[list[str]] = field(default_factory=list)
    end_site: list[bool] = field(default_factory=list)
    stack: list[int] = field(default_factory=list)  # the open joints
    declared: set[str] = field(default_factory=set)  # the names so far (a set: linear in the joint count)
    pending: int | None = None  # joint declared, waiting for its "{"

    def declare(self, keyword: str, name: str, line: int) -> None:
        """A ``ROOT``, ``JOINT`` or ``End`` (Site) line."""
        if keyword == "ROOT" and self.names:
            raise bvh_error(self.source, line, "more than one ROOT is not supported")
        if keyword != "ROOT" and not self.stack:
            raise bvh_error(self.source, line, f"{'End Site' if keyword == 'End' else keyword} outside any parent")
        if keyword == "End":
            name = f"{self.names[self.stack[-1]]}_End"
        elif not name:
            raise bvh_error(self.source, line, f"{keyword} without a name")
        if name in self.declared:
            raise bvh_error(self.source, line, f"joint name {name!r} appears twice")
        self.declared.add(name)
        self.names.append(name)
        self.parents.append(self.stack[-1] if self.stack else -1)
        self.offsets.append([0.0, 0.0, 0.0])
        self.channels.append([])
        self.end_site.append(keyword == "End")
        self.pending = len(self.names) - 1

    def open(self, line: int) -> None:
        if self.pending is None:
            raise bvh_error(self.source, line, "'{' without a joint")
        self.stack.append(self.pending)
        self.pending = None

    def close(self, line: int) -> None:
        if not self.stack:
            raise bvh_error(self.source, line, "unbalanced '}'")
        self.stack.pop()

    def offset(self, values: list[str], line: int) -> None:
        if not self.stack:
            raise bvh_error(self.source, line, "OFFSET outside a joint")
        try:
            offset = [float(v) for v in values]
        except ValueError:
            raise bvh_error(self.source, line, "OFFSET needs three numbers") from None
        if len(offset) != 3:
            raise bvh_error(self.source, line, "OFFSET needs three numbers")
        if not all(math.isfinite(v) for v in offset):
            raise bvh_error(self.source, line, f"OFFSET of {self.names[self.stack[-1]]!r} is not finite "
                                           f"({' '.join(values)})")
        if max(abs(v) for v in offset) > MAX_POSITION:
            raise bvh_error(self.source, line, f"OFFSET of {self.names[self.stack[-1]]!r} ({' '.join(values)}) is "
                                           f"beyond {MAX_POSITION:g} units (10 km in millimetres)")
        self.offsets[self.stack[-1]] = offset

    def set_channels(self, tokens: list[_Token], i: int) -> int:
        """The ``CHANNELS`` list at ``tokens[i]``; returns the index of the token after it."""
        line = tokens[i].line
        if not self.stack or self.end_site[self.stack[-1]]:
            raise bvh_error(self.source, line, "CHANNELS outside a joint")
        try:
            count = int(tokens[i + 1].text)
        except (ValueError, IndexError):
            raise bvh_error(self.source, line, "CHANNELS needs a count") from None
        names = [t.text for t in tokens[i + 2:i + 2 + max(count, 0)]]
        if count < 0 or len(names) != count or any(c not in VALID_CHANNELS for c in names):
            raise bvh_error(self.source, line, f"bad channel list {names!r} (count {count})")
        twice = sorted({c for c in names if names.count(c) > 1})
        if twice:
            raise bvh_error(self.source, line, f"channel list {' '.join(names)} names {', '.join(twice)} twice")
        self.channels[self.stack[-1]] = names
        return i + 2 + count


def _joint_name(tokens: list[_Token], lines: list[str], i: int) -> tuple[str, int]:
    """The name after the ROOT/JOINT at ``tokens[i]`` (the rest of its line but a final
    ``{``; spaces inside kept) and the index of the token after it."""
    end = i + 1
    while end < len(tokens) and tokens[end].line == tokens[i].line:
        end += 1
    if end > i + 1 and tokens[end - 1].text == "{":
        end -= 1
    if end == i + 1:
        return "", end
    return lines[tokens[i].line - 1][tokens[i + 1].start:tokens[end - 1].end], end


def _parse_hierarchy(header: str, source: str) -> _Hierarchy:
    lines = header.split("\n")
    tokens = [_Token(m.group(0), n, m.start(), m.end())
              for n, text in enumerate(lines, 1) for m in _TOKEN.finditer(text)]
    joints = _Hierarchy(source)
    i = 1  # skip HIERARCHY
    while i < len(tokens):
        tok, line = tokens[i].text, tokens[i].line
        if tok in ("ROOT", "JOINT"):
            name, i = _joint_name(tokens, lines, i)
            joints.declare(tok, name, line)
        elif tok == "End":
            if i + 1 >= len(tokens) or tokens[i + 1].text != "Site":
                raise bvh_error(source, line, "'End' must be followed by 'Site'")
            joints.declare(tok, "", line)
            i += 2
        elif tok in ("{", "}"):
            (joints.open if tok == "{" else joints.close)(line)
            i += 1
        elif tok == "OFFSET":
            joints.offset([t.text for t in tokens[i + 1:i + 4]], line)
            i += 4
        elif tok == "CHANNELS":
            i = joints.set_channels(tokens, i)
        else:
            raise bvh_error(source, line, f"unexpected {tok!r} in HIERARCHY")
    if joints.stack:
        raise bvh_error(source, tokens[-1].line if tokens else 0, "unclosed '{' in HIERARCHY")
    if not joints.names:
        raise bvh_error(source, 0, "no ROOT joint")
    return joints


def _position_channels(bvh: Bvh, joint: int) -> tuple[list[int], list[int]]:
    """Motion columns and axes (0 x, 1 y, 2 z) of a joint's position channels."""
    pairs = [(int(bvh.channel_start[joint]) + i, "XYZ".index(c[0]))
             for i, c in enumerate(bvh.channels[joint]) if c.endswith("position")]
    return [column for column, _ in pairs], [axis for _, axis in pairs]


def detect_position_mode(bvh: Bvh) -> str:
    """How ``bvh``'s non-root position channels are meant, judged on frame 0.

    :data:`REPLACED` (Blender's exporter) when they equal the ``OFFSET`` (within
    :data:`POSITION_MATCH_REL` of the bone or :data:`POSITION_MATCH_ABS` units) for more than half
    of the joints whose ``OFFSET`` is not ~0 (where the two readings differ); else :data:`ADDED`;
    :data:`NO_POSITIONS` when no non-root joint has position channels.
    """
    votes, found = [], False
    for j in np.flatnonzero(bvh.parents >= 0):
        columns, axes = _position_channels(bvh, int(j))
        if not columns:
            continue
        found = True
        offset = bvh.offsets[j]
        tolerance = max(POSITION_MATCH_REL * float(np.linalg.norm(offset)), POSITION_MATCH_ABS)
        if np.abs(offset[axes]).max() > tolerance:
            votes.append(np.abs(bvh.motion[0, columns] - offset[axes]).max() <= tolerance)
    if not found:
        return NO_POSITIONS
    return REPLACED if 2 * sum(votes) > len(votes) else ADDED


def read_bvh(path: str | os.PathLike) -> Bvh:
    """Read a BVH file (any line endings); raises :class:`BvhError` naming the file."""
    path = Path(path)
    text = read_input_text(path, MAX_BVH_BYTES, BvhError, "BVH file", errors="replace")
    return parse_bvh(text, str(path))


def _fmt(x: float) -> str:
    return f"{x:.6f}" if abs(x) >= 1e-4 or x == 0 else f"{x:.9e}"


def _hierarchy_lines(bvh: Bvh) -> list[str]:
    """The HIERARCHY section's lines below its keyword, depth first, without recursion (any depth);
    indented one tab a level up to :data:`MAX_INDENT_TABS` (the text stays linear in the joints)."""
    children, depth = children_and_depths(bvh.parents)
    out: list[str] = []
    pending = [(0, False)]  # (joint, whether its block is to be closed), the next on top
    while pending:
        j, closing = pending.pop()
        pad = "\t" * min(depth[j], MAX_INDENT_TABS)
        if closing:
            out.append(pad + "}")
            continue
        title = "End Site" if bvh.end_site[j] else f"{'ROOT' if depth[j] == 0 else 'JOINT'} {bvh.names[j]}"
        out += [pad + title, pad + "{", f"{pad}\tOFFSET " + " ".join(_fmt(v) for v in bvh.offsets[j])]
        if not bvh.end_site[j]:
            out.append(f"{pad}\tCHANNELS {len(bvh.channels[j])} " + " ".join(bvh.channels[j]))
        pending += [(j, True)] + [(c, False) for c in reversed(children[j])]
    return out


def format_bvh(bvh: Bvh, decimals: int = 6, lead_frames: int = 0) -> str:
    """BVH text for ``bvh`` (LF line endings, tab indentation, values with ``decimals`` places).

    ``lead_frames``: the first frame written that many more times before the motion (a track
    padded back to its input's first frame): one line formatted once, repeated as text.
    """
    if lead_frames < 0 or (lead_frames and not bvh.n_frames):
        raise ValueError(f"{lead_frames} lead frames for a motion of {bvh.n_frames} frames")
    out = ["HIERARCHY", *_hierarchy_lines(bvh), "MOTION"]
    out.append(f"Frames: {bvh.n_frames + lead_frames}")
    out.append(f"Frame Time: {bvh.frame_time:.8f}")
    body = np.char.mod(f"%.{decimals}f", np.round(bvh.motion, decimals) + 0.0)
    rows = [" ".join(row) for row in body]
    out.extend(rows[:1] * lead_frames)
    out.extend(rows)
    out.append("")  # the final newline, without copying the text once more
    return "\n".join(out)


def write_bvh(path: str | os.PathLike, bvh: Bvh, decimals: int = 6) -> None:
    """Write ``bvh`` atomically."""
    write_atomic(path, format_bvh(bvh, decimals))


def local_transforms(bvh: Bvh, joints: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per-frame local rotations ``[F, K, 3, 3]`` and translations ``[F, K, 3]`` (file units) of the
    K ``joints`` (every joint when None)."""
    joints = np.arange(len(bvh.names)) if joints is None else joints
    rot = np.broadcast_to(np.eye(3), (bvh.n_frames, len(joints), 3, 3)).copy()
    trans = np.broadcast_to(bvh.offsets[joints], (bvh.n_frames, len(joints), 3)).copy()
    replaced = bvh.position_mode == REPLACED
    for k, j in enumerate(joints.tolist()):
        chans = bvh.channels[j]
        start = bvh.channel_start[j]
        rot_cols = [start + i for i, c in enumerate(chans) if c.endswith("rotation")]
        if rot_cols:
            order = "".join(c[0] for c in chans if c.endswith("rotation"))
            rot[:, k] = euler_to_matrix(bvh.motion[:, rot_cols], order)
        columns, axes = _position_channels(bvh, j)
        if columns:
            base = 0.0 if replaced and bvh.parents[j] >= 0 else bvh.offsets[j, axes]
            trans[:, k, axes] = base + bvh.motion[:, columns]
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


def forward_kinematics(bvh: Bvh, joints: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Global positions ``[F, K, 3]`` (file units) and rotations ``[F, K, 3, 3]`` of the K ``joints``,
    in their order (every joint, J, when None). Only they and their ancestors are chained: the rest
    of a large rig costs no time or memory."""
    if joints is None:
        return accumulate_transforms(bvh.parents, *local_transforms(bvh))
    kept = with_ancestors(bvh.parents, joints)
    column = np.full(len(bvh.names), -1, dtype=np.int64)  # each kept joint's place in ``kept``
    column[kept] = np.arange(len(kept))
    parents = bvh.parents[kept]
    kept_parents = np.where(parents >= 0, column[parents], -1)
    positions, rotations = accumulate_transforms(kept_parents, *local_transforms(bvh, kept))
    wanted = column[list(joints)]
    return positions[:, wanted], rotations[:, wanted]


def motion_from_rotations(bvh: Bvh, local_rot: np.ndarray, root_translation: np.ndarray) -> np.ndarray:
    """Channel values ``[F, C]`` that give local rotations ``[F, J, 3, 3]`` and root translation.

    ``root_translation [F, 3]`` is the root's position channels (added to its OFFSET); other
    joints' position channels keep the OFFSET (0, or the OFFSET itself when they replace it).
    Every joint's rotation channels must be three distinct axes.
    """
    motion = np.zeros((local_rot.shape[0], int(sum(len(c) for c in bvh.channels))))
    for j, chans in enumerate(bvh.channels):
        start = bvh.channel_start[j]
        rot_cols = [start + i for i, c in enumerate(chans) if c.endswith("rotation")]
        if rot_cols:
            order = "".join(c[0] for c in chans if c.endswith("rotation"))
            motion[:, rot_cols] = matrix_to_euler(local_rot[:, j], order)
        columns, axes = _position_channels(bvh, j)
        if j == 0:
            motion[:, columns] = root_translation[:, axes]
        elif bvh.position_mode == REPLACED:
            motion[:, columns] = bvh.offsets[j, axes]
    return motion
