"""Real MP4 files with the faults phones and interrupted copies leave, made by editing an MP4's boxes
(ISO/IEC 14496-12) written by OpenCV's VideoWriter: no FFmpeg binary needed.

- :func:`with_gap`: the sample durations (``stts``) say one frame lasts ``1 + gap_frames`` frame
  times, so every later frame's timestamp jumps by ``gap_frames`` frame times (a dropped stretch).
- :func:`moov_first` then cutting bytes off the end: the index (``moov``) before the media data, as
  phones write it, so a file cut short still opens and promises every frame its index lists.
"""
from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np

CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl"}   # boxes whose payload is boxes
SAMPLE_TABLE = [b"moov", b"trak", b"mdia", b"minf", b"stbl"]


def write_mp4(path: Path, frames: int, fps: float, size: tuple[int, int] = (160, 120)) -> Path:
    """An MPEG-4 (``mp4v``) file of ``frames`` frames at ``fps``, frame i showing the number i."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, size)
    assert writer.isOpened()
    for i in range(frames):
        image = np.full((size[1], size[0], 3), (i * 7) % 256, np.uint8)
        cv2.putText(image, str(i), (10, size[1] - 20), cv2.FONT_HERSHEY_SIMPLEX, 2, (255, 255, 255), 3)
        writer.write(image)
    writer.release()
    return path


def boxes(data: bytes, start: int = 0, end: int | None = None) -> list[tuple[bytes, int, int]]:
    """The boxes in ``data[start:end]``: (type, offset, size), 32-bit sizes only."""
    found, at, end = [], start, len(data) if end is None else end
    while at + 8 <= end:
        size, kind = struct.unpack(">I4s", data[at:at + 8])
        assert size >= 8, f"box {kind!r} at {at}: size {size} (64-bit or open-ended sizes are not handled)"
        found.append((kind, at, size))
        at += size
    return found


def _child(data: bytes, parent: tuple[bytes, int, int], kind: bytes) -> tuple[bytes, int, int]:
    _, at, size = parent
    return next(b for b in boxes(data, at + 8, at + size) if b[0] == kind)


def _path(data: bytes, kinds: list[bytes]) -> list[tuple[bytes, int, int]]:
    """The chain of boxes ``kinds`` from the top level (the first of each type)."""
    chain = [next(b for b in boxes(data) if b[0] == kinds[0])]
    for kind in kinds[1:]:
        chain.append(_child(data, chain[-1], kind))
    return chain


def _resized(data: bytes, chain: list[tuple[bytes, int, int]], payload: bytes) -> bytes:
    """``data`` with the last box of ``chain`` given ``payload``, every box of the chain resized."""
    kind, at, size = chain[-1]
    grow = 8 + len(payload) - size
    out = bytearray(data[:at] + struct.pack(">I4s", 8 + len(payload), kind) + payload + data[at + size:])
    for _, parent_at, parent_size in chain[:-1]:
        struct.pack_into(">I", out, parent_at, parent_size + grow)
    return bytes(out)


def with_gap(data: bytes, after_frame: int, gap_frames: int) -> bytes:
    """An MP4 (``moov`` after ``mdat``, one track) whose frames after ``after_frame`` come
    ``gap_frames`` frame times late: frame k is at ``k`` frame times up to ``after_frame``, then
    ``k + gap_frames``. The edit list is renamed ``free`` so it cannot trim the longer track."""
    assert [b[0] for b in boxes(data)][-1] == b"moov", "the index must come after the media data"
    table = _path(data, SAMPLE_TABLE)[-1]
    assert b"ctts" not in [b[0] for b in boxes(data, table[1] + 8, table[1] + table[2])], \
        "B-frames (composition offsets) would reorder the frames around the gap"
    chain = _path(data, [*SAMPLE_TABLE, b"stts"])
    _, at, _ = chain[-1]
    count = struct.unpack(">I", data[at + 12:at + 16])[0]
    samples, delta = struct.unpack(">II", data[at + 16:at + 24])
    assert count == 1, "one duration for every frame expected"
    entries = [(after_frame, delta), (1, delta * (1 + gap_frames)), (samples - after_frame - 1, delta)]
    payload = struct.pack(">II", 0, len(entries)) + b"".join(struct.pack(">II", *e) for e in entries)
    out = bytearray(_resized(data, chain, payload))
    trak = _path(bytes(out), SAMPLE_TABLE[:2])[-1]
    edits = [b for b in boxes(bytes(out), trak[1] + 8, trak[1] + trak[2]) if b[0] == b"edts"]
    for _, edit_at, _ in edits:
        out[edit_at + 4:edit_at + 8] = b"free"
    return bytes(out)


def moov_first(data: bytes) -> bytes:
    """The same MP4 with its ``moov`` moved before the media data (chunk offsets shifted)."""
    top = boxes(data)
    moov = next(b for b in top if b[0] == b"moov")
    assert moov is top[-1], "the index must come after the media data"
    stco = _path(data, [*SAMPLE_TABLE, b"stco"])[-1]
    index = bytearray(data[moov[1]:])
    table = stco[1] - moov[1]
    count = struct.unpack(">I", index[table + 12:table + 16])[0]
    for i in range(count):
        entry = table + 16 + 4 * i
        struct.pack_into(">I", index, entry, struct.unpack(">I", index[entry:entry + 4])[0] + len(index))
    ftyp_end = top[0][1] + top[0][2]
    return data[:ftyp_end] + bytes(index) + data[ftyp_end:moov[1]]
