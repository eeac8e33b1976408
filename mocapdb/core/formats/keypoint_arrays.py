"""Keypoint arrays and the files holding them: a detector's ``[T, P, K, 3]`` array and ``.npy`` and
``.npz`` files (RTMLib positions with scores too), as frames on the universal 14
(:mod:`mocapdb.core.formats.keypoints`); :func:`read_keypoint_file` also takes MMPose prediction
``.json`` files (:func:`mocapdb.core.formats.openpose.read_mmpose_json`).
File forms: ``data_specs/keypoint_formats.md``.
"""
from __future__ import annotations

import math
import os
import zipfile
import zlib
from collections.abc import Iterator
from pathlib import Path
from tokenize import TokenError
from typing import IO

import numpy as np

from mocapdb.core.files import MIB, open_input
from mocapdb.core.formats.keypoints import (
    KeypointError,
    KeypointFrame,
    Person,
    check_fps,
    detect_layout,
    error_source,
    frame_time,
    numeric,
    to_extremities,
    to_universal,
    with_scores,
)
from mocapdb.core.formats.openpose import read_mmpose_json
from mocapdb.core.skeleton import N_KEYPOINTS_2D

MAX_ARRAY_BYTES = 256 * MIB       # a keypoint array: an hour at 60 fps of two people of 25 keypoints, in float64
MAX_ARRAY_FILE_BYTES = MAX_ARRAY_BYTES + MIB  # an .npz file: its arrays, stored or compressed, and the zip's index


def frames_from_arrays(keypoints: np.ndarray, layout: str | None = None,
                       fps: float | None = None) -> Iterator[KeypointFrame]:
    """Frames from a detector's array: ``[T, P, K, 3]`` or one person ``[T, K, 3]`` (x px, y px, confidence).

    ``layout`` None: detected from all people (:func:`detect_layout`). People with no keypoint at
    all (padding) are left out; array slots are not identities, so ``person_id`` is None.
    ``time_s = index / fps`` (seconds) when ``fps`` (Hz) is given. Errors are raised at once.
    """
    arr = numeric(keypoints, "keypoint array")
    if arr.ndim == 3:
        arr = arr[:, None]
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise KeypointError(f"keypoint array of shape {np.shape(keypoints)}, expected [T, K, 3] or [T, P, K, 3]")
    check_fps(fps)
    n_frames, n_people = arr.shape[:2]
    people = arr.reshape((-1,) + arr.shape[2:])
    layout = detect_layout(people) if layout is None else layout
    points, conf = to_universal(people, layout)
    points = points.reshape(n_frames, n_people, N_KEYPOINTS_2D, 2)
    conf = conf.reshape(n_frames, n_people, N_KEYPOINTS_2D)
    extremities = to_extremities(people, layout)
    if extremities is not None:
        extremities = extremities.reshape(n_frames, n_people, -1, 3)
    present = np.any(conf > 0, axis=-1)  # [frames, people]
    return (KeypointFrame(t, frame_time(t, fps), [
        Person(points[t, p], conf[t, p], None, None if extremities is None else extremities[t, p])
        for p in np.flatnonzero(present[t])]) for t in range(n_frames))


_NPY_HEADERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def _read_npy(f: IO[bytes], size: int) -> np.ndarray:
    """The numeric array in ``.npy`` data ``f`` of ``size`` bytes; the header is checked against
    ``size`` before anything is allocated, and object arrays are refused (never unpickled)."""
    try:
        shape, fortran, dtype = _NPY_HEADERS[np.lib.format.read_magic(f)](f)
    except (ValueError, KeyError, SyntaxError, TokenError):
        raise KeypointError("not a .npy array (missing or damaged header)") from None
    if dtype.kind not in "iuf" or dtype.fields is not None or dtype.subdtype is not None:
        raise KeypointError(f"holds {dtype} values, not numbers")
    if min(shape, default=0) < 0:
        raise KeypointError(f"header says shape {shape}, with a negative size")
    count, data_size = math.prod(shape), size - f.tell()
    if count * dtype.itemsize != data_size:
        raise KeypointError(f"header says shape {shape} of {dtype} ({count * dtype.itemsize} bytes) "
                            f"but {data_size} bytes follow it (damaged or truncated)")
    data = f.read(data_size + 1)
    if len(data) != data_size:
        raise KeypointError(f"{len(data)} bytes of data where the header says {data_size} (damaged or truncated)")
    return np.frombuffer(data, dtype, count).reshape(shape, order="F" if fortran else "C")


def _npz_member(zf: zipfile.ZipFile, key: str, name: str) -> np.ndarray:
    """One member's array; its stated uncompressed size is checked before anything is inflated
    (a zip bomb), and no more than that size is ever read."""
    info = zf.getinfo(name)
    with error_source(f"array '{key}'"):
        if info.flag_bits & 0x1:
            raise KeypointError("encrypted")
        if info.file_size > MAX_ARRAY_BYTES:
            raise KeypointError(f"{info.file_size:,} bytes uncompressed, more than a keypoint array may hold "
                                f"({MAX_ARRAY_BYTES:,}; split the take)")
        with zf.open(info) as f:
            return _read_npy(f, info.file_size)


def _npz_arrays(path: Path) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``keypoints`` and (None if absent) ``scores`` arrays of an ``.npz`` file."""
    with open_input(path, MAX_ARRAY_FILE_BYTES, KeypointError, ".npz keypoint file") as file:
        try:
            with zipfile.ZipFile(file) as zf:
                names = {n.removesuffix(".npy"): n for n in zf.namelist() if n.endswith(".npy")}
                if "keypoints" not in names:
                    raise KeypointError("no 'keypoints' array in the .npz file")
                scores = _npz_member(zf, "scores", names["scores"]) if "scores" in names else None
                return _npz_member(zf, "keypoints", names["keypoints"]), scores
        except KeypointError:
            raise
        except (zipfile.BadZipFile, zlib.error, EOFError, NotImplementedError, OSError, OverflowError,
                ValueError) as err:
            raise KeypointError(f"not a readable .npz (zip) file ({err})") from None


def _checked_keypoints(keypoints: np.ndarray, scores: np.ndarray | None) -> np.ndarray:
    """``keypoints`` (with ``scores`` when it holds positions only) as a finite float64
    ``[T, K, 3]`` or ``[T, P, K, 3]`` array, else KeypointError saying what is wrong."""
    if scores is not None and keypoints.shape[-1:] == (2,):
        keypoints = with_scores(keypoints, scores, "scores")
    if keypoints.ndim not in (3, 4) or keypoints.shape[-1] != 3:
        raise KeypointError(f"keypoints of shape {keypoints.shape}, expected [T, K, 3] or [T, P, K, 3] "
                            f"(x, y, confidence), or positions [..., 2] with scores [...] in an .npz")
    if keypoints.size == 0:
        raise KeypointError(f"keypoints of shape {keypoints.shape} hold no values")
    finite = np.isfinite(keypoints)
    if not finite.all():
        first = tuple(int(i) for i in np.unravel_index(np.argmin(finite), finite.shape))
        raise KeypointError(f"{finite.size - np.count_nonzero(finite)} non-finite values (NaN or infinite), "
                            f"the first at index {first}; write a missing keypoint as 0, 0, 0")
    return keypoints.astype(np.float64)


def read_keypoint_array(path: str | Path) -> np.ndarray:
    """A detector's keypoint array ``[T, K, 3]`` or ``[T, P, K, 3]`` (x px, y px, confidence, float64).

    ``.npy`` (``np.save``), or ``.npz`` (``np.savez``) with ``keypoints`` ``[..., 3]``, or RTMLib's
    positions ``keypoints [..., 2]`` with ``scores [...]``. Damaged files, headers that do not match
    the file size, non-numeric (object) arrays, other shapes and NaN or infinite values raise
    KeypointError naming the file; nothing is allocated before the header is checked.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".npz"):
        raise KeypointError(f"{path}: not a .npy or .npz keypoint file")
    if suffix == ".npz":
        with error_source(path):
            return _checked_keypoints(*_npz_arrays(path))
    with open_input(path, MAX_ARRAY_BYTES, KeypointError, ".npy keypoint file") as f, error_source(path):
        return _checked_keypoints(_read_npy(f, os.fstat(f.fileno()).st_size), None)


KEYPOINT_FILE_SUFFIXES = (".npy", ".npz", ".json")


def read_keypoint_file(path: str | Path, layout: str | None = None,
                       fps: float | None = None) -> Iterator[KeypointFrame]:
    """The frames of a keypoint file: a detector array (``.npy``, ``.npz``: :func:`read_keypoint_array`)
    or MMPose predictions (``.json``: :func:`read_mmpose_json`). Read and checked at once, so errors
    (KeypointError naming the file) come before any frame; ``layout`` None: detected."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return iter(read_mmpose_json(path, layout, fps))
    keypoints = read_keypoint_array(path)
    with error_source(path):
        return frames_from_arrays(keypoints, layout, fps)
