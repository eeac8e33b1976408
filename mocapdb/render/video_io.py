"""The files of ``mocapdb render``: video frames read by index (``--video``) and the pictures
written (PNG, MP4, a folder of PNG frames).

Outputs are written as every command writes them (:mod:`mocapdb.core.outputs`): PNG frames into a
temporary folder that replaces ``--out`` whole once complete (an earlier render's frames folder is
replaced, a folder holding anything else refused); a PNG or MP4 file through a temporary name and a
rename, replacing only a PNG or MP4 file. Both are checked before any drawing.
"""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2
import numpy as np

from mocapdb.core.outputs import OutputFile, OutputFiles, output_file, output_folder
from mocapdb.render.results import RenderError

MP4_NAME = "render.mp4"
FRAME_FILES = OutputFiles("render", ("frame_*.png",), "frame_*.png")
PNG_FILE = OutputFile("render", "a PNG picture", b"\x89PNG\r\n\x1a\n")
MP4_FILE = OutputFile("render", "an MP4 video", b"ftyp", offset=4)


class VideoFrames:
    """Frames of a video file by index (sequential reads, a seek when going back or far ahead)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.is_file():
            raise RenderError(f"{path}: no such video file (--video)")
        self.cap = cv2.VideoCapture(str(self.path))
        if not self.cap.isOpened():
            raise RenderError(f"{path}: OpenCV cannot open this video (--video)")
        count = int(self.cap.get(cv2.CAP_PROP_FRAME_COUNT))
        self.count = count if count > 0 else None
        self.size = (int(self.cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(self.cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))
        self.next = 0

    def get(self, index: int) -> np.ndarray | None:
        if index < self.next or index > self.next + 60:
            self.cap.set(cv2.CAP_PROP_POS_FRAMES, index)
            self.next = index
        frame = None
        while self.next <= index:
            ok, frame = self.cap.read()
            self.next += 1
            if not ok:
                return None
        return frame

    def close(self) -> None:
        self.cap.release()


def write_png(path: str | Path, img: np.ndarray) -> Path:
    """Write ``img`` as the PNG file ``path`` atomically, replacing only a PNG (:func:`output_file`)."""
    path = Path(path)
    ok, data = cv2.imencode(".png", img)
    if not ok:
        raise RenderError(f"{path}: OpenCV cannot encode the picture as PNG")
    with output_file(path, PNG_FILE) as tmp:
        tmp.write_bytes(data.tobytes())
    return path


def mp4_path(out: str | Path) -> Path:
    """The video file of ``render --mp4 --out OUT``: OUT if it ends ``.mp4``, else OUT/render.mp4."""
    out = Path(out)
    return out if out.suffix.lower() == ".mp4" else out / MP4_NAME


@contextmanager
def frame_sink(out: Path, mp4: bool, fps: float, size: tuple[int, int]
                ) -> Iterator[Callable[[int, np.ndarray], object]]:
    """``write(index, image)`` for the frames: PNG files in a folder that replaces ``out`` whole, or
    one MP4 (:func:`mp4_path`) at ``fps`` Hz of frames ``size`` px; either only when the block ends
    normally."""
    if not mp4:
        with output_folder(out, FRAME_FILES) as tmp:
            yield lambda index, img: write_png(tmp / f"frame_{index:06d}.png", img)
        return
    with output_file(mp4_path(out), MP4_FILE) as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter.fourcc(*"mp4v"), fps, size)
        try:
            if not writer.isOpened():
                raise RenderError(f"{mp4_path(out)}: OpenCV cannot write an MP4 (mp4v) video here")
            yield lambda index, img: writer.write(img)
        finally:
            writer.release()
