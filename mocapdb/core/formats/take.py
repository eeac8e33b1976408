"""The take description: what `mocapdb detect` knows of a take, written beside its keypoints.

``take.json`` (``data_specs/take_description.md``) holds the keypoints' frame rate, the image size,
the frame count, the source and the model, and the camera's focal length when it is known. Every
command that reads such a folder (:func:`resolve_camera`) takes them from it, so nothing has to be
typed again; an option given explicitly wins when it agrees, and one that contradicts the file is an
error naming both.
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TypedDict, TypeVar

import numpy as np

from mocapdb.core import domains as D
from mocapdb.core.errors import MocapdbError, UsageError
from mocapdb.core.files import read_sidecar, write_atomic
from mocapdb.core.formats.keypoint_layouts import LAYOUTS

TAKE_FILE = "take.json"
TAKE_FORMAT = "mocapdb-take"
TAKE_VERSION = 1
MAX_SIDE_PX = 65536          # no camera makes larger images
MAX_FPS = 10000.0
MAX_TAKE_BYTES = 1_000_000   # a take description is a few hundred bytes: more is read as broken
CODEC_BLOCK_PX = 16          # video codecs code whole 16-px blocks: a 1080-line video is 1088 lines, cropped
IMAGE_MARGIN = 0.1           # keypoints may lie this fraction of the image size outside it (detectors extrapolate)
# the video sizes (width, height) px an image size is taken from when only the keypoints tell it, smallest first
STANDARD_SIZES = ((640, 480), (1280, 720), (1920, 1080), (2560, 1440), (3840, 2160))
LOG = logging.getLogger(__name__)


class CameraDefaults(TypedDict):
    fps: float
    image_size: tuple[int, int]


# when nothing says otherwise (the focal: below)
DEFAULTS: CameraDefaults = {"fps": D.INPUT_FPS_HZ.default, "image_size": (1920, 1080)}
FULL_FRAME_DIAGONAL_MM = 43.27  # a 36 × 24 mm frame: what "35 mm-equivalent" focal lengths refer to
DEFAULT_FOCAL_35MM = 26.0       # a typical phone main camera (24–28 mm equivalent), when nothing is given


def focal_from_35mm(focal_35mm: float, image_size: tuple[int, int]) -> float:
    """Focal length in pixels of a 35 mm-equivalent focal length (mm) for an image (width, height) px:
    the same angle across the diagonal as on a 36 × 24 mm frame."""
    return focal_35mm * math.hypot(*image_size) / FULL_FRAME_DIAGONAL_MM


def focal_from_fov(fov_deg: float, image_size: tuple[int, int]) -> float:
    """Focal length in pixels of a horizontal field of view (degrees) across an image (width, height) px."""
    return image_size[0] / 2.0 / math.tan(math.radians(fov_deg) / 2.0)


def default_focal_px(image_size: tuple[int, int]) -> float:
    """The focal length assumed when nothing gives one: :data:`DEFAULT_FOCAL_35MM` for the image."""
    return focal_from_35mm(DEFAULT_FOCAL_35MM, image_size)


def beyond_image(size: tuple[int, int], points_px: np.ndarray) -> np.ndarray:
    """``[N]`` whether each point ``[N, 2]`` (x, y px) lies outside an image of ``size`` (width, height) px
    by more than :data:`IMAGE_MARGIN` of it (a NaN point does not)."""
    width, height = size
    points_px = np.asarray(points_px, dtype=np.float64)
    return ((points_px < -IMAGE_MARGIN * min(width, height)).any(axis=-1)
            | (points_px[..., 0] > (1 + IMAGE_MARGIN) * width) | (points_px[..., 1] > (1 + IMAGE_MARGIN) * height))


def holds_keypoints(size: tuple[int, int], low: tuple[float, float], high: tuple[float, float]) -> bool:
    """Whether an image of ``size`` (width, height) px holds keypoints from ``low`` to ``high`` (the
    smallest and largest x, y, px), each side allowed :data:`IMAGE_MARGIN` outside it."""
    return not beyond_image(size, np.array([low, high])).any()


def standard_size_holding(low: tuple[float, float], high: tuple[float, float]) -> tuple[int, int] | None:
    """The smallest of :data:`STANDARD_SIZES` (landscape before portrait) that holds keypoints from
    ``low`` to ``high`` (px, :func:`holds_keypoints`); None when none does."""
    for width, height in STANDARD_SIZES:
        for size in ((width, height), (height, width)):
            if holds_keypoints(size, low, high):
                return size
    return None


class TakeError(MocapdbError, ValueError):
    """A take description that cannot be used (names the file and the field)."""


@dataclass(frozen=True)
class TakeInfo:
    """One take: keypoints' frame rate (Hz), image (width, height) in pixels, frames written, the
    source video or camera, the model, the focal length in pixels (None: unknown) and the keypoint
    layout of the files (a name of ``keypoint_layouts.LAYOUTS``; None: told by the files)."""

    fps: float | None
    image_size: tuple[int, int] | None
    frames: int | None
    source: str
    model: str | None = None
    focal_px: float | None = None
    layout: str | None = None

    def __post_init__(self) -> None:
        _check_fps(self.fps, "fps")
        _check_size(self.image_size, "image_size")
        if self.focal_px is not None and not (math.isfinite(self.focal_px) and 0 < self.focal_px <= 1e6):
            raise ValueError(f"focal_px must be a positive number of pixels, not {self.focal_px!r}")
        if self.frames is not None and (isinstance(self.frames, bool) or not isinstance(self.frames, int)
                                        or self.frames < 0):
            raise ValueError(f"frames must be a count, not {self.frames!r}")
        if self.layout is not None and (not isinstance(self.layout, str) or self.layout not in LAYOUTS):
            raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, not {self.layout!r}")


def _check_fps(fps: object, name: str) -> None:
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, (int, float))
                            or not (math.isfinite(fps) and 0 < fps <= MAX_FPS)):
        raise ValueError(f"{name} must be a frame rate in (0, {MAX_FPS:g}] Hz, not {fps!r}")


def _check_size(size: object, name: str) -> None:
    if size is None:
        return
    if (not isinstance(size, (tuple, list)) or len(size) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_SIDE_PX for v in size)):
        raise ValueError(f"{name} must be [width, height] in pixels (1 to {MAX_SIDE_PX}), not {size!r}")


def write_take(folder: str | Path, info: TakeInfo) -> Path:
    """``folder/take.json`` (atomically); returns its path."""
    path = Path(folder) / TAKE_FILE
    body = {"format": TAKE_FORMAT, "version": TAKE_VERSION, **asdict(info)}
    body["image_size"] = list(info.image_size) if info.image_size else None
    write_atomic(path, json.dumps(body, indent=2) + "\n")
    return path


def read_take(folder: str | Path) -> TakeInfo | None:
    """The take description in ``folder`` (None when there is none); TakeError when it is broken."""
    found = read_sidecar(folder, TAKE_FILE, MAX_TAKE_BYTES, TakeError, "take description", TAKE_FORMAT, TAKE_VERSION)
    if found is None:
        return None
    path, body = found
    size = body.get("image_size")
    try:
        return TakeInfo(fps=body.get("fps"), image_size=tuple(size) if isinstance(size, list) else size,
                        frames=body.get("frames"), source=str(body.get("source", "")), model=body.get("model"),
                        focal_px=body.get("focal_px"), layout=body.get("layout"))
    except ValueError as exc:
        raise TakeError(f"{path}: {exc}") from None


@dataclass(frozen=True)
class CameraSettings:
    """The frame rate (Hz), image size (px) and focal length (px) a run uses, and where each came
    from: ``"given"`` (an option), ``"read"`` (the take description) or ``"default"``."""

    fps: float
    image_size: tuple[int, int]
    focal_px: float
    sources: dict[str, str]


def resolve_camera(take: TakeInfo | None, take_path: str, fps: float | None = None,
                   image_size: tuple[int, int] | None = None, focal_px: float | None = None,
                   given_as: dict[str, str] | None = None) -> CameraSettings:
    """Each of fps, image size and focal: the option when given, else the take description's, else
    :data:`DEFAULTS` (the focal: :func:`default_focal_px` of the image). An option that contradicts
    the description is a UsageError naming both, but for image sizes that differ by less than a
    codec block (:data:`CODEC_BLOCK_PX`: a warning, the given size is used); ``given_as`` names where
    a given value came from when it is no option (``{"image_size": "cam_01's size in calib.toml"}``;
    default: the option)."""
    origins = given_as or {}
    sources: dict[str, str] = {}
    fps_hz = _resolve("fps", fps, None if take is None else take.fps, take_path, origins, sources)
    if fps_hz is None:
        fps_hz, sources["fps"] = DEFAULTS["fps"], "default"
    size = _resolve("image_size", image_size, None if take is None else take.image_size, take_path, origins, sources)
    if size is None:
        size, sources["image_size"] = DEFAULTS["image_size"], "default"
    width, height = size  # a pair, a list if the TakeInfo was made with one: a tuple below
    focal = _resolve("focal_px", focal_px, None if take is None else take.focal_px, take_path, origins, sources)
    if focal is None:
        focal, sources["focal_px"] = default_focal_px((width, height)), "default"
    return CameraSettings(float(fps_hz), (width, height), float(focal), sources)


Setting = TypeVar("Setting", float, tuple[int, int])  # a frame rate or focal length, or an image size


def _resolve(name: str, value: Setting | None, known: Setting | None, take_path: str, origins: dict[str, str],
             sources: dict[str, str]) -> Setting | None:
    """The given ``value`` (checked against the take description's ``known``), else ``known``, its source
    noted in ``sources``; None when neither is there."""
    origin = origins.get(name)
    if value is not None and known is not None and _codec_padding(value, known):
        LOG.warning("%s %s and %s (%s) differ by less than a codec block (%d px): the same image, padded "
                    "or cropped by the video codec; using %s", origin or _option(name), _text(value), take_path,
                    _text(known), CODEC_BLOCK_PX, _text(value))
    elif value is not None and known is not None and not _agree(value, known):
        fix = "correct one of them" if origin else "leave the option out or correct it"
        raise UsageError(f"{origin or _option(name)} {_text(value)} contradicts {take_path}, which says "
                         f"{_text(known)}: {fix}")
    if value is not None:
        sources[name] = "given"
        return value
    if known is not None:
        sources[name] = "read"
    return known


def _codec_padding(a: Setting, b: Setting) -> bool:
    """Two image sizes (px) that differ, each side by less than :data:`CODEC_BLOCK_PX`."""
    return isinstance(a, tuple) and tuple(a) != tuple(b) and all(abs(x - y) < CODEC_BLOCK_PX for x, y in zip(a, b))


def _agree(a: Setting, b: Setting) -> bool:
    if isinstance(a, tuple):
        return tuple(a) == tuple(b)
    return math.isclose(float(a), float(b), rel_tol=1e-3)


def _option(name: str) -> str:
    return {"fps": "--fps", "image_size": "--image-size", "focal_px": "--focal"}[name]


def _text(value: Setting) -> str:
    return f"{value[0]}x{value[1]}" if isinstance(value, tuple) else f"{float(value):g}"
