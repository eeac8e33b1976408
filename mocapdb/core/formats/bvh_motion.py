"""The MOTION section of BVH text, read and checked (the header's frame count and frame time, then
the rows, parsed in chunks in linear time), and the error every BVH reader raises: it names the
file, the line and the problem."""
from __future__ import annotations

import numpy as np

from mocapdb.core.errors import MocapdbError

MAX_FRAMES = 10_000_000     # more is a broken header, not motion (a day at 100 fps is 8.6 M)
MAX_FRAME_TIME_S = 10.0     # a longer frame time is a broken header
MAX_POSITION = 1e7          # |OFFSET| and position channels, file units: 10 km in millimetres, the smallest unit
MOTION_CHUNK_VALUES = 1 << 19  # motion values parsed per numpy call, in whole rows (memory bounded, time linear)


class BvhError(MocapdbError, ValueError):
    """A BVH file that cannot be read; the message names the file and the problem."""


def bvh_error(source: str, line: int, message: str) -> BvhError:
    """The error ``message`` at ``line`` of ``source`` (1-based; 0: about the whole file)."""
    where = f"{source}:{line}" if line else source
    return BvhError(f"{where}: {message}")


def _motion_header(lines: list[str], source: str, line0: int) -> tuple[int, float, int]:
    """``Frames:`` and ``Frame Time:``, checked, and the index of the line after them.

    ``lines[k]`` is line ``line0 + k`` of the file (``lines[0]``: the rest of the MOTION line).
    """
    fields: dict[str, tuple[str, int]] = {}
    k = 0
    while k < len(lines) and len(fields) < 2:
        stripped = lines[k].strip()
        k += 1
        if not stripped:
            continue
        key, _, value = stripped.partition(":")
        key = " ".join(key.split())
        if key not in ("Frames", "Frame Time"):
            raise bvh_error(source, line0 + k - 1, f"expected 'Frames:' and 'Frame Time:', got {stripped[:40]!r}")
        fields[key] = (value.strip(), line0 + k - 1)
    try:
        (frames_text, frames_line), (time_text, time_line) = fields["Frames"], fields["Frame Time"]
        n_frames, frame_time = int(frames_text), float(time_text)
    except (KeyError, ValueError):
        raise bvh_error(source, line0, "missing or malformed 'Frames:' / 'Frame Time:'") from None
    if n_frames < 1:
        raise bvh_error(source, frames_line, f"Frames: {n_frames}: no motion to read")
    if n_frames > MAX_FRAMES:
        raise bvh_error(source, frames_line, f"Frames: {n_frames} is absurd (more than {MAX_FRAMES}): a broken header")
    if not 0 < frame_time <= MAX_FRAME_TIME_S:  # also false for NaN
        raise bvh_error(source, time_line, f"Frame Time: {time_text} is not a frame duration "
                                       f"(seconds, above 0 and at most {MAX_FRAME_TIME_S:g})")
    return n_frames, frame_time, k


def parse_motion(body: str, labels: list[str], source: str, line0: int) -> tuple[float, np.ndarray]:
    """Frame time and motion ``[F, C]`` from what follows the MOTION keyword (on line ``line0``);
    ``labels`` name the C channels ("joint Xrotation"). Exactly ``Frames:`` rows must follow; they
    are parsed about :data:`MOTION_CHUNK_VALUES` values at a time (linear time; the temporary text
    values take memory bounded by the chunk, not the file)."""
    lines = body.splitlines()
    n_frames, frame_time, k = _motion_header(lines, source, line0)
    if n_frames * max(len(labels), 1) > len(body):  # every value takes at least a digit and a space
        raise bvh_error(source, 0, f"header says {n_frames} frames of {len(labels)} values, more than the file "
                               "holds (truncated?)")
    motion = np.empty((n_frames, len(labels)), dtype=np.float64)
    row_lines = np.empty(n_frames, dtype=np.int64)  # the file line of each frame
    n_rows, chunk = 0, []
    chunk_rows = max(MOTION_CHUNK_VALUES // max(len(labels), 1), 1)
    for i in range(k, len(lines)):
        if not lines[i].strip():
            continue
        if n_rows == n_frames:
            raise bvh_error(source, line0 + i, f"more motion rows than the header's 'Frames: {n_frames}' "
                                           "(a wrong frame count?)")
        row_lines[n_rows] = line0 + i
        chunk.append(lines[i])
        n_rows += 1
        if len(chunk) == chunk_rows:
            _fill_rows(motion, row_lines, n_rows - len(chunk), chunk, labels, source)
            chunk = []
    if n_rows < n_frames:
        raise bvh_error(source, 0, f"header says {n_frames} frames but only {n_rows} are present (truncated?)")
    _fill_rows(motion, row_lines, n_rows - len(chunk), chunk, labels, source)
    return frame_time, motion


def _fill_rows(motion: np.ndarray, row_lines: np.ndarray, first: int, rows: list[str], labels: list[str],
               source: str) -> None:
    """Parse ``rows`` (text) into ``motion[first:first + len(rows)]``, checked: numbers, one per channel,
    finite, positions within :data:`MAX_POSITION`; errors name the file line."""
    if not rows:
        return
    n_channels = len(labels)
    try:
        values = np.array(" ".join(rows).split(), dtype=np.float64)
    except ValueError:
        bad = next(i for i, r in enumerate(rows) if not _is_numeric_row(r))
        raise bvh_error(source, int(row_lines[first + bad]), "non-numeric value in the MOTION data") from None
    if values.size != len(rows) * n_channels:
        bad = next(i for i, r in enumerate(rows) if len(r.split()) != n_channels)
        raise bvh_error(source, int(row_lines[first + bad]),
                    f"frame {first + bad} has {len(rows[bad].split())} values, expected {n_channels}")
    block = values.reshape(len(rows), n_channels)
    positions = np.array([label.endswith("position") for label in labels], dtype=bool)
    bad_value = ~np.isfinite(block) | (positions & (np.abs(block) > MAX_POSITION))
    if bad_value.any():
        row, column = np.argwhere(bad_value)[0]
        value, where = block[row, column], f"frame {first + row}, {labels[column]}"
        raise bvh_error(source, int(row_lines[first + row]),
                    f"NaN or infinite value in the MOTION data ({where})" if not np.isfinite(value) else
                    f"{where} {value:g} is beyond {MAX_POSITION:g} units (10 km in millimetres)")
    motion[first:first + len(rows)] = block


def _is_numeric_row(row: str) -> bool:
    try:
        np.array(row.split(), dtype=np.float64)
    except ValueError:
        return False
    return True
