"""The one motion type: a body on the universal rig over frames, as arrays.

A :class:`Motion` is what every part of mocapdb passes around: the builder's clips, the engine's
tracks, the whole-take fit, stereo's people and every file written from them. Stateless operations
on it are in :mod:`mocapdb.core.motion_ops`; the formats' writers take it
(:func:`mocapdb.core.outputs.motion_bvh`, :func:`mocapdb.core.exports.write_motion`).
:class:`FrameRecorder` builds one frame by frame, appending into arrays that grow.

Coordinate frames (:data:`COORDINATE_FRAMES`; ``data_specs/stream_output.md``), all right-handed, metres:

* ``"world"``: y up, the floor at y = 0 (clips, BVH files, stereo's levelled world);
* ``"view"``: x to the image's right, y up, z towards the camera, the origin at the camera (the engine);
* ``"camera"``: camera-aligned, the view frame with z negated (the JSON stream's joints and roots).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mocapdb.core.hand_rig import FINGER_JOINTS
from mocapdb.core.skeleton import (
    END_JOINTS,
    N_RIG_JOINTS,
    UNIVERSAL_HEIGHT_M,
    body_offsets_m,
    pose_from_rotations,
    universal_bone_lengths_m,
)

COORDINATE_FRAMES = ("world", "view", "camera")
N_END_JOINTS = len(END_JOINTS)  # the feet, hands and head (skeleton.END_JOINTS) a humanoid BVH turns


@dataclass
class Motion:
    """A body's motion on the universal rig: local rotations and the root over frames.

    ``rotations [F, R, 4]`` are the rig joints' local rotations (``skeleton.RIG_JOINTS`` order,
    w x y z), the root's relative to ``coordinate_frame``; ``root_m [F, 3]`` the pelvis in it (metres).
    The body is the universal one times ``scale`` (its height / 1.75 m), with the bone proportions
    ``proportions_m [8]`` (``skeleton.MEASURED_BONE_NAMES`` at 1.75 m; None: the universal body's).
    ``end_rotations [F, 5, 4]``: the feet's, hands' and head's local rotations (``skeleton.END_JOINTS``
    order; None: they do not turn); ``finger_rotations [F, 30, 4]``: the humanoid rig's finger joints'
    (``hand_rig.FINGER_JOINTS`` order; None: at rest, straight). ``first_frame``: the index of its first
    frame in the input or the source (frames at ``fps`` Hz).
    """

    rotations: np.ndarray
    root_m: np.ndarray
    fps: float
    coordinate_frame: str = "world"
    first_frame: int = 0
    scale: float = 1.0
    proportions_m: np.ndarray | None = None
    end_rotations: np.ndarray | None = None
    finger_rotations: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.rotations)
        if self.rotations.shape[1:] != (N_RIG_JOINTS, 4) or self.root_m.shape != (n, 3):
            raise ValueError(f"a motion needs rotations [F, {N_RIG_JOINTS}, 4] and a root [F, 3]: got "
                             f"{self.rotations.shape} and {self.root_m.shape}")
        if self.end_rotations is not None and self.end_rotations.shape != (n, N_END_JOINTS, 4):
            raise ValueError(f"end rotations must be [F, {N_END_JOINTS}, 4]: got {self.end_rotations.shape}")
        if self.finger_rotations is not None and self.finger_rotations.shape != (n, len(FINGER_JOINTS), 4):
            raise ValueError(f"finger rotations must be [F, {len(FINGER_JOINTS)}, 4]: "
                             f"got {self.finger_rotations.shape}")
        if self.coordinate_frame not in COORDINATE_FRAMES:
            raise ValueError(f"unknown coordinate frame {self.coordinate_frame!r}: "
                             f"one of {', '.join(COORDINATE_FRAMES)}")
        if not self.fps > 0 or not self.scale > 0:
            raise ValueError(f"a motion needs a positive frame rate and body scale: got {self.fps} Hz, {self.scale}")

    def __len__(self) -> int:
        return len(self.rotations)

    @property
    def height_m(self) -> float:
        """The body's standing height (metres)."""
        return UNIVERSAL_HEIGHT_M * self.scale

    def offsets_m(self) -> np.ndarray | None:
        """The rig's rest offsets at 1.75 m for the body's proportions (None: the universal body's)."""
        return None if self.proportions_m is None else body_offsets_m(self.proportions_m)

    def bones_m(self) -> np.ndarray:
        """The body's ``MEASURED_BONE_NAMES`` lengths at its height (metres)."""
        at_175 = universal_bone_lengths_m() if self.proportions_m is None else self.proportions_m
        return at_175 * self.scale

    def joints_m(self) -> np.ndarray:
        """Forward kinematics: the 15 keypoints ``[F, 15, 3]`` (``skeleton.KEYPOINTS``) in its coordinate frame."""
        return pose_from_rotations(self.rotations, self.root_m, self.scale, self.offsets_m())

    def window(self, start: int, stop: int) -> Motion:
        """Frames ``start`` to ``stop`` (indices into this motion) as a motion of their own."""
        ends = None if self.end_rotations is None else self.end_rotations[start:stop]
        fingers = None if self.finger_rotations is None else self.finger_rotations[start:stop]
        return replace(self, rotations=self.rotations[start:stop], root_m=self.root_m[start:stop],
                       first_frame=self.first_frame + start, end_rotations=ends, finger_rotations=fingers)

    def times_s(self) -> np.ndarray:
        """Each frame's time (seconds) from the input's or source's frame 0."""
        return (self.first_frame + np.arange(len(self))) / self.fps


class FrameRecorder:
    """Named per-frame arrays that grow as frames are appended (capacity doubling: amortised O(1) a
    frame, no per-frame Python lists). Each name's rows keep the shape and dtype of its first row.

    ``recorder[name]`` is a view of the rows so far; :meth:`snapshot` a recorder whose rows stay as
    they are while this one records on (rows are never rewritten, so the two share their arrays).
    """

    def __init__(self) -> None:
        self._arrays: dict[str, np.ndarray] = {}
        self._count = 0

    @classmethod
    def of(cls, **columns: np.ndarray) -> FrameRecorder:
        """A recorder holding ``columns`` (each ``[F, ...]``, the same F), copied."""
        recorder = cls()
        lengths = {len(values) for values in columns.values()}
        if len(lengths) > 1:
            raise ValueError(f"columns of different lengths: {sorted(lengths)}")
        recorder._arrays = {name: np.array(values) for name, values in columns.items()}
        recorder._count = lengths.pop() if lengths else 0
        return recorder

    def __len__(self) -> int:
        return self._count

    def __contains__(self, name: str) -> bool:
        return name in self._arrays

    def __getitem__(self, name: str) -> np.ndarray:
        return self._arrays[name][:self._count]

    def names(self) -> tuple[str, ...]:
        """The names recorded."""
        return tuple(self._arrays)

    def append(self, **row: np.ndarray | float) -> None:
        """Add one frame: a value for every name recorded so far (the first call names them)."""
        if self._arrays and row.keys() != self._arrays.keys():
            raise ValueError(f"a frame needs {sorted(self._arrays)}: got {sorted(row)}")
        for name, value in row.items():
            value = np.asarray(value)
            if name not in self._arrays:
                self._arrays[name] = np.empty((8,) + value.shape, dtype=value.dtype)
            elif self._count == len(self._arrays[name]):
                grown = np.empty((max(2 * self._count, 8),) + value.shape, dtype=self._arrays[name].dtype)
                grown[:self._count] = self._arrays[name]
                self._arrays[name] = grown
            self._arrays[name][self._count] = value
        self._count += 1

    def last(self) -> dict[str, np.ndarray]:
        """The last frame's values by name (copies)."""
        return {name: values[self._count - 1].copy() for name, values in self._arrays.items()}

    def snapshot(self) -> FrameRecorder:
        """A recorder of the rows so far that later appends to this one leave unchanged. It shares
        their memory; its arrays end at its last row, so an append to it moves it to new arrays."""
        copy = FrameRecorder()
        copy._arrays = {name: values[:self._count] for name, values in self._arrays.items()}
        copy._count = self._count
        return copy
