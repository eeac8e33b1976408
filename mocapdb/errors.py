"""The errors a user can cause (bad files, bad options); the CLI prints them without a traceback."""
from runtime.streams import StreamSpecError

from .builder import BuildError
from .bvh import BvhError
from .database import DatabaseError
from .detect import DetectError
from .joint_map import JointMapError
from .keypoints import KeypointError


class UsageError(ValueError):
    """A command-line value that cannot be used."""


USER_ERRORS: tuple[type[Exception], ...] = (BuildError, BvhError, DatabaseError, DetectError, JointMapError, KeypointError,
                                           StreamSpecError, UsageError, OSError)
