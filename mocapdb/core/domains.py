"""The domain of every number a user gives mocapdb, declared once (data_specs/option_domains.md).

A :class:`Domain` is the set of values one option or config field accepts: finite, whole or not,
within bounds that make physical sense. The command line uses it as the option's argparse
``type`` (a bad value is one line naming the option and exit 2, before any work); the Python API's
config classes call :meth:`Domain.check` on the same object, so both refuse the same values.
:class:`ImageSizeArg` and :class:`NumberListArg` do the same for ``WxH`` sizes and comma lists.

A leaf of the core layer: it imports only the standard library and :mod:`mocapdb.core.errors`.
"""
from __future__ import annotations

import argparse
import math
import numbers
from dataclasses import dataclass, replace
from typing import Any, Literal, cast, overload

from mocapdb.core.errors import UsageError


class DomainError(UsageError):
    """A value outside its domain; the message names the option or field and the domain."""


@dataclass(frozen=True)
class Domain:
    """Finite numbers from ``low`` to ``high`` (``low`` itself excluded when ``low_open``);
    whole numbers only when ``integer``. ``what`` says what the value is, with its unit."""

    what: str
    low: float
    high: float
    integer: bool = False
    low_open: bool = False
    zero_means: str | None = None  # what 0 means when it is accepted, e.g. "no limit"
    default: Any = None  # the value (int or float) when none is given: the parser's and the config's

    def describe(self) -> str:
        """``a frame rate in hertz, from 1 to 1000``: the domain in words."""
        low = _number_text(self.low)
        bounds = f"above {low} and at most" if self.low_open else f"from {low} to"
        note = f"; 0: {self.zero_means}" if self.zero_means else ""
        return f"{self.what}, {bounds} {_number_text(self.high)}{note}"

    def accepts(self, value: object) -> bool:
        """Whether ``value`` (a number, not a bool) lies in the domain."""
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            return False
        if self.integer and not isinstance(value, numbers.Integral):
            return False
        if not isinstance(value, numbers.Integral) and not math.isfinite(value):  # a huge int is finite
            return False
        number = cast(float, value)  # any Real orders as a float does; typeshed's numbers.Real has no __gt__
        above = number > self.low if self.low_open else number >= self.low
        return above and number <= self.high

    def check(self, value, name: str):
        """``value`` when the domain holds it, else DomainError naming ``name``."""
        if not self.accepts(value):
            raise DomainError(f"{name} {value!r}: must be {self.describe()}")
        return value

    def check_optional(self, value, name: str):
        """:meth:`check`, with None (not given) let through."""
        return value if value is None else self.check(value, name)

    def __call__(self, text: str) -> int | float:
        """The argparse ``type``: the text as a number of the domain, else ArgumentTypeError
        (which argparse prints after the option's name, exiting with 2)."""
        value = _parse_number(text, self.integer)
        if value is None or not self.accepts(value):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {self.describe()}")
        return value

    @property
    def __name__(self) -> str:  # argparse names a type in some messages
        return self.what


def _number_text(value: float) -> str:
    return f"{value:,.0f}" if float(value).is_integer() and abs(value) >= 10_000 else f"{value:g}"


@overload
def _parse_number(text: str, integer: Literal[True]) -> int | None: ...


@overload
def _parse_number(text: str, integer: bool) -> int | float | None: ...


def _parse_number(text: str, integer: bool) -> int | float | None:
    """``text`` as an int (``integer``) or a float; None when it is not one (no ``1e3`` for an int)."""
    try:
        return int(text, 10) if integer else float(text)
    except ValueError:
        return None


@dataclass(frozen=True)
class ImageSizeArg:
    """The ``WIDTHxHEIGHT`` argparse type: two whole numbers of :data:`IMAGE_SIDE_PX`."""

    def __call__(self, text: str) -> tuple[int, int]:
        parts = text.lower().split("x")
        parsed = [_parse_number(p.strip(), integer=True) for p in parts] if len(parts) == 2 else [None]
        sides = [s for s in parsed if s is not None]
        if len(sides) != 2:
            raise argparse.ArgumentTypeError(f"{text!r}: must be WIDTHxHEIGHT in pixels, e.g. 1920x1080")
        if not all(IMAGE_SIDE_PX.accepts(s) for s in sides):
            raise argparse.ArgumentTypeError(f"{text!r}: width and height must each be {IMAGE_SIDE_PX.describe()}")
        return sides[0], sides[1]

    @property
    def __name__(self) -> str:
        return "an image size"


@dataclass(frozen=True)
class NumberListArg:
    """A comma-separated list of ``min_items`` to ``max_items`` numbers of ``item``, not all zero."""

    item: Domain
    min_items: int = 1
    max_items: int = 32
    default: Any = None   # the tuple of numbers when none is given: the parser's and the config's

    def check(self, values, name: str) -> tuple[float, ...]:
        """The values as a tuple when they form such a list, else DomainError naming ``name``."""
        values = tuple(values)
        if not self.min_items <= len(values) <= self.max_items:
            raise DomainError(f"{name}: {len(values)} values; give {self.min_items} to {self.max_items}")
        for v in values:
            self.item.check(v, name)
        if not any(values):
            raise DomainError(f"{name}: the values must not all be 0")
        return values

    def __call__(self, text: str) -> tuple[float, ...]:
        values = [_parse_number(v.strip(), self.item.integer) for v in text.split(",")]
        if any(v is None for v in values):
            raise argparse.ArgumentTypeError(f"{text!r}: must be numbers separated by commas, e.g. 0.4,0.3,0.2,0.1")
        try:
            return self.check(values, "the list")
        except DomainError as exc:
            raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None

    @property
    def __name__(self) -> str:
        return "a list of numbers"


@dataclass(frozen=True)
class PerTrackArg:
    """``VALUE`` (every person) or ``ID=VALUE`` (the track of that id): the argparse type of an
    option a user may give per person; the value of domain ``value``. Gives (id or None, value)."""

    value: Domain

    def __call__(self, text: str) -> tuple[int | None, int | float]:
        track_text, _, value_text = text.rpartition("=")
        track = _parse_number(track_text.strip(), integer=True) if "=" in text else None
        if "=" in text and (track is None or not TRACK_ID.accepts(track)):
            raise argparse.ArgumentTypeError(f"{text!r}: must be VALUE or TRACK=VALUE, TRACK {TRACK_ID.describe()}")
        return track, self.value(value_text.strip())

    @property
    def __name__(self) -> str:
        return f"{self.value.what}, or TRACK={self.value.what}"


# --- the camera and the take ---------------------------------------------------------------
FPS_HZ = Domain("a frame rate in hertz", 1, 1000)
FOCAL_PX = Domain("a focal length in pixels", 10, 100_000)
FOV_DEG = Domain("a horizontal field of view in degrees", 1, 179)
FOCAL_35MM = Domain("a 35 mm-equivalent focal length in millimetres", 1, 2000)
IMAGE_SIDE_PX = Domain("a whole number of pixels", 16, 32768, integer=True)
PIXEL_COORDINATE = Domain("a pixel coordinate", 0, 32768)
IMAGE_SIZE = ImageSizeArg()
CAMERA_HEIGHT_M = Domain("a camera height above the floor in metres", 0.1, 50)
CAMERA_DISTANCE_M = Domain("a camera-to-subject distance in metres", 0.5, 100)
BASELINE_M = Domain("a distance between the two cameras in metres", 0.01, 1000)
SUBJECT_HEIGHT_M = Domain("a standing height in metres", 0.5, 2.5)
TRACK_ID = Domain("a track id", 0, 1_000_000_000, integer=True)
CAMERA_INDEX = Domain("a camera index", 0, 255, integer=True)

# --- the database build --------------------------------------------------------------------
YAW_STEP_DEG = Domain("a yaw step in degrees", 0.01, 360, default=12.0)
CLUSTERS = Domain("a number of k-means clusters", 1, 1_000_000, integer=True, default=500)
DIMS = Domain("a number of embedding dimensions", 1, 100, integer=True, default=5)
LANDMARKS = Domain("a number of MDS landmarks", 2, 10_000_000, integer=True, default=2000)
SEED = Domain("a random seed", 0, 2**32 - 1, integer=True)
WORKERS = Domain("a number of worker processes", 1, 256, integer=True)
MEMORY_LIMIT_MB = Domain("a memory limit in megabytes", 64, 100_000_000, integer=True)

# --- retrieval, refinement and filters -----------------------------------------------------
CLUSTERS_SEARCHED = Domain("a number of clusters searched", 1, 10_000, integer=True)
PER_CLUSTER = Domain("a number of projections per cluster", 1, 10_000, integer=True, default=10)
SUBCLUSTERS_SEARCHED = Domain("a number of sub-clusters searched per cluster", 1, 100_000, integer=True)
GRID_DESCENTS = Domain("a number of candidates refined by grid descent", 0, 1000, integer=True,
                       zero_means="none, the clustered search's candidates only", default=3)
WINDOW_WEIGHT = Domain("a weight", 0, 1000)
WINDOW_WEIGHTS = NumberListArg(WINDOW_WEIGHT, min_items=1, max_items=32, default=(0.4, 0.3, 0.2, 0.1))
WEIGHT_2D = Domain("a weight", 0, 1000, default=0.5)
CUTOFF_HZ = Domain("a cut-off frequency in hertz", 0, 1000, low_open=True)
BETA = Domain("a 1€ speed coefficient", 0, 1000)
SMOOTHING_HZ = Domain("a cut-off frequency in hertz", 0, 1000, zero_means="no smoothing", default=4.0)
LAG_FRAMES = Domain("a number of frames", 0, 600, integer=True, zero_means="causal, no lag", default=0)

# --- limits of a run -----------------------------------------------------------------------
MAX_TRACKS = Domain("a number of tracks", 0, 10_000, integer=True, zero_means="no limit", default=32)
MAX_NEW_TRACKS_PER_MIN = Domain("a number of tracks per minute", 0, 1_000_000, integer=True, zero_means="no limit",
                                default=120)
MAX_BVH_FILES = Domain("a number of files", 0, 1_000_000, integer=True, zero_means="no limit", default=1000)
MIN_TRACK_S = Domain("a duration in seconds", 0, 86_400, default=0.5)
BVH_PART_MIN = Domain("a duration in minutes", 0, 1440, low_open=True, default=10.0)
IDLE_TIMEOUT_S = Domain("a duration in seconds", 0, 1_000_000, low_open=True)
CLIENT_TIMEOUT_S = Domain("a duration in seconds", 0, 86_400, low_open=True, default=30.0)
MAX_CLIENTS = Domain("a number of clients", 1, 1024, integer=True, default=16)
MAX_RATE_HZ = Domain("a number of messages per second", 0, 1_000_000, zero_means="no limit", default=1000.0)
VIEW_PORT = Domain("a TCP port", 0, 65_535, integer=True, zero_means="any free port", default=0)
BUFFER_MESSAGES = Domain("a number of messages", 1, 10_000, integer=True, default=2)

# --- detection -----------------------------------------------------------------------------
DETECT_EVERY = Domain("a number of frames", 1, 10_000, integer=True)
MAX_PEOPLE = Domain("a number of people", 1, 1000, integer=True)
CONF = Domain("a score", 0, 1)
IOU = Domain("an overlap ratio (IoU)", 0, 1, low_open=True)
MODEL_INPUT_PX = Domain("a model input side in pixels", 32, 4096, integer=True)
MODEL_EVERY = Domain("a number of frames", 1, 100, integer=True, default=1)

# --- evaluation and pictures ---------------------------------------------------------------
MAX_CLIPS = Domain("a number of clips", 1, 100_000, integer=True, default=8)
MAX_FRAMES = Domain("a number of frames", 1, 10_000_000, integer=True, default=240)
RENDER_SCALE = Domain("a scale factor", 0, 10, low_open=True, default=0.5)
CONTACT_FRAMES = Domain("a number of frames", 1, 1000, integer=True)


# The database's virtual camera and frame rate (`mocapdb build`, BuildConfig): the shared domains
# with the builder's defaults (the same domains elsewhere have none of their own).
DATABASE_FPS_HZ = replace(FPS_HZ, default=24.0)
DATABASE_FOCAL_PX = replace(FOCAL_PX, default=1000.0)
DATABASE_CAMERA_HEIGHT_M = replace(CAMERA_HEIGHT_M, default=1.5)
DATABASE_CAMERA_DISTANCE_M = replace(CAMERA_DISTANCE_M, default=4.0)
FRAMES_EVERY = replace(DETECT_EVERY, default=1)   # `detect --every`: every frame unless told
INPUT_FPS_HZ = replace(FPS_HZ, default=30.0)     # input frames that carry no time, nothing else saying (a warning)
RENDER_FOCAL_PX = replace(FOCAL_PX, default=1000.0)  # `render` of a result whose header records no focal
# The 1€ filters on joint rotations: after the fit to the image (the default) and without it (--no-refine)
REFINED_MIN_CUTOFF_HZ = replace(CUTOFF_HZ, default=8.0)
REFINED_BETA = replace(BETA, default=2.0)
RETRIEVED_MIN_CUTOFF_HZ = replace(CUTOFF_HZ, default=1.0)
RETRIEVED_BETA = replace(BETA, default=0.3)
