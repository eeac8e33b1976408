"""The errors a user can cause (bad files, bad options); the CLI prints them without a traceback."""
from runtime.output import OutputFolderError
from runtime.session import InputError
from runtime.streams import StreamSpecError

from .builder import BuildError
from .bvh import BvhError
from .cameras import CalibrationError
from .database import DatabaseError
from .detect import DetectError
from .joint_map import JointMapError
from .keypoints import KeypointError
from .stereo import StereoError
from .trc import TrcError


class UsageError(ValueError):
    """A command-line value that cannot be used."""


USER_ERRORS: tuple[type[Exception], ...] = (BuildError, BvhError, CalibrationError, DatabaseError, DetectError,
                                           InputError, JointMapError, KeypointError, OutputFolderError, StereoError,
                                           StreamSpecError, TrcError, UsageError, OSError)
