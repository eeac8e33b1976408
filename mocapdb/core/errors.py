"""The errors a user can cause (bad files, bad options); the CLI prints them without a traceback."""
from mocapdb.core.outputs import OutputFolderError
from mocapdb.runtime.session import InputError
from mocapdb.runtime.streams import StreamSpecError

from mocapdb.builder.pipeline import BuildError
from mocapdb.core.formats.bvh import BvhError
from mocapdb.core.cameras import CalibrationError
from mocapdb.core.formats.database import DatabaseError
from mocapdb.detect.model import DetectError
from mocapdb.core.joint_map import JointMapError
from mocapdb.core.formats.keypoints import KeypointError
from mocapdb.stereo.ellipsoid import StereoError
from mocapdb.core.formats.trc import TrcError


class UsageError(ValueError):
    """A command-line value that cannot be used."""


USER_ERRORS: tuple[type[Exception], ...] = (BuildError, BvhError, CalibrationError, DatabaseError, DetectError,
                                           InputError, JointMapError, KeypointError, OutputFolderError, StereoError,
                                           StreamSpecError, TrcError, UsageError, OSError)
