"""Avatar sinks for ``mocapdb live``: one person's pose as OSC over UDP to an avatar program, in the
VMC protocol (VSeeFace, Warudo, VNyan, Unity with EVMC4U; :class:`VmcSink`) or as VRChat's OSC
trackers (:class:`VrchatSink`). Contract: ``data_specs/avatar_protocols.md``; the pose in Unity's
frame: :mod:`mocapdb.core.avatar`.

Choices:

- One person: the track given (``--vmc-track``), else the main one: the track kept while it is in
  the frame; when it is not, the track present with the most frames seen so far, the nearest to the
  camera on a tie (as at the start, when everyone has one frame). A switch starts the floor estimate
  afresh.
- The floor and up: the pose's own (``up_view``, ``floor_offset_m``) when estimated; else the view's
  +y and the lowest :func:`~mocapdb.core.avatar.ankle_floor_m` over the person's last
  :data:`FLOOR_WINDOW_FRAMES` frames.
- The origin: the floor point under the pelvis in the first frame sent, kept for the session, so
  the avatar starts where the receiver puts it and walks as the person walks.
- Sends never block and never raise: the socket is non-blocking and connected (Linux then reports
  a receiver that is not listening, as ICMP port unreachable, on a later send). A frame any of whose
  datagrams failed, and a frame with a value that is not finite (not sent), count one ``sink_dropped``.
- Encoding: each message's address and leading arguments are encoded once by python-osc; per frame
  only the float arguments are packed (big-endian float32, OSC's encoding) behind them, about ten
  times faster than building every message with python-osc.
"""
from __future__ import annotations

import socket
import struct
from abc import abstractmethod
from collections import deque
from collections.abc import Sequence

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder

from mocapdb.core.avatar import (
    ROOT_QUAT,
    UNITY_BONES,
    UNITY_FINGER_BONES,
    VIEW_UP,
    AvatarPose,
    ankle_floor_m,
    avatar_pose,
    unity_euler_deg,
)
from mocapdb.core.face_shapes import BLEND_SHAPES
from mocapdb.core.outputs import PersonPose
from mocapdb.runtime.stream.messages import StreamStats, resolve_address
from mocapdb.runtime.stream.sinks import Sink

__all__ = ["FLOOR_WINDOW_FRAMES", "MAX_BUNDLE_BYTES", "MAX_COUNTED_TRACKS", "VMC_PORT", "VRCHAT_PORT",
           "VRCHAT_TRACKERS", "AvatarSink", "OscFrames", "VmcSink", "VrchatSink"]

VMC_PORT = 39539          # the VMC protocol's usual Marionette (receiver) port
VRCHAT_PORT = 9000        # VRChat's OSC input port
MAX_BUNDLE_BYTES = 1500   # an Ethernet MTU: a bundle never needs IP fragmentation on a LAN
FLOOR_WINDOW_FRAMES = 60  # frames over which the lowest ankle gives the floor when none was estimated
MAX_COUNTED_TRACKS = 256  # tracks whose frames are counted; beyond, those not in the frame are forgotten
ArgValue = str | int
Message = tuple[str, tuple[ArgValue, ...], int]   # address, leading arguments, trailing float arguments


def _message_head(address: str, args: tuple[ArgValue, ...], n_floats: int) -> bytes:
    """An OSC message's bytes up to its ``n_floats`` trailing float32 arguments, encoded by python-osc."""
    builder = OscMessageBuilder(address)
    for arg in args:
        builder.add_arg(arg)
    for _ in range(n_floats):
        builder.add_arg(0.0, OscMessageBuilder.ARG_TYPE_FLOAT)
    dgram = builder.build().dgram
    return dgram[:len(dgram) - 4 * n_floats]


_BUNDLE_HEAD = OscBundleBuilder(IMMEDIATELY).build().dgram   # "#bundle", time tag "immediately": 16 bytes


class OscFrames:
    """Messages of fixed address and leading arguments whose float arguments change per frame, as
    datagrams: OSC bundles of at most ``bundle_bytes`` bytes each (messages in order, a bundle filled
    before the next is started), or with ``bundle_bytes`` None one message per datagram."""

    def __init__(self, messages: Sequence[Message], bundle_bytes: int | None) -> None:
        heads = [_message_head(*m) for m in messages]
        self._ends = np.cumsum([0] + [4 * m[2] for m in messages])   # byte offsets into the packed floats
        if bundle_bytes is None:
            self._heads, self._groups = heads, [[i] for i in range(len(heads))]
            self._bundle_head = b""
            return
        sizes = [len(h) + 4 * m[2] for h, m in zip(heads, messages)]
        self._heads = [struct.pack(">i", size) + head for size, head in zip(sizes, heads)]
        self._groups = _pack([4 + size for size in sizes], bundle_bytes - len(_BUNDLE_HEAD))
        self._bundle_head = _BUNDLE_HEAD

    def datagrams(self, floats: np.ndarray) -> list[bytes]:
        """The datagrams of one frame whose float arguments, message after message, are ``floats``."""
        raw = np.asarray(floats, dtype=">f4").tobytes()
        parts = [head + raw[a:b] for head, a, b in zip(self._heads, self._ends[:-1], self._ends[1:])]
        return [self._bundle_head + b"".join(parts[i] for i in group) for group in self._groups]


def _pack(sizes: list[int], capacity: int) -> list[list[int]]:
    """Consecutive items of ``sizes`` (bytes) grouped so that no group's total exceeds ``capacity``."""
    groups: list[list[int]] = [[]]
    used = 0
    for i, size in enumerate(sizes):
        if size > capacity:
            raise ValueError(f"an OSC message of {size} bytes does not fit a bundle of {capacity}")
        if used + size > capacity:
            groups.append([])
            used = 0
        groups[-1].append(i)
        used += size
    return groups


class _MainTrack:
    """The person an avatar sink follows (see the module notes)."""

    def __init__(self, track: int | None) -> None:
        self.fixed, self.current = track, track
        self._frames: dict[int, int] = {}   # frames seen per track

    def choose(self, people: list[PersonPose]) -> PersonPose | None:
        """The followed person among ``people``, or None when absent."""
        by_track = {p.track: p for p in people}
        if self.fixed is None:
            for t in by_track:
                self._frames[t] = self._frames.get(t, 0) + 1
            if len(self._frames) > MAX_COUNTED_TRACKS:   # forget the tracks gone
                self._frames = {t: self._frames[t] for t in by_track}
            if self.current not in by_track and by_track:
                self.current = max(by_track, key=lambda t: (self._frames[t], -by_track[t].root_m[2]))
        return by_track.get(self.current) if self.current is not None else None


class AvatarSink(Sink):
    """An OSC-over-UDP sink sending one person's avatar per frame (:meth:`write_frame`); the header
    line is not sent. Subclasses give the messages: :meth:`_frame_datagrams`, :meth:`_absent_datagrams`."""

    def __init__(self, host: str, port: int, stats: StreamStats | None = None, track: int | None = None) -> None:
        super().__init__(stats)
        family, address = resolve_address(host, port, socket.SOCK_DGRAM)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        self._sock.setblocking(False)
        self._sock.connect(address)
        self._main = _MainTrack(track)
        self._followed: int | None = None
        self._floors: deque[float] = deque(maxlen=FLOOR_WINDOW_FRAMES)
        self._origin: np.ndarray | None = None

    def _put(self, text: str) -> None:
        """The stream's header line: nothing to send."""

    def write_frame(self, frame_index: int, time_s: float, people: list[PersonPose]) -> None:
        """Sends the followed person's avatar at ``time_s`` (seconds), or what says they are absent."""
        pose = self._main.choose(people)
        if pose is None:
            self._send(self._absent_datagrams(time_s), frame_index)
            return
        avatar = self._avatar(pose)
        if avatar is None:
            self.stats.add(sink_dropped=1)
            return
        self._send(self._frame_datagrams(avatar, time_s), frame_index)

    def _avatar(self, pose: PersonPose) -> AvatarPose | None:
        """The person's avatar on their floor, from the sink's origin; None if not finite."""
        if pose.track != self._followed:
            self._followed = pose.track
            self._floors.clear()
        up = VIEW_UP if pose.up_view is None else pose.up_view
        floor = pose.floor_offset_m
        if floor is None:
            if np.isfinite(guess := ankle_floor_m(pose, up)):
                self._floors.append(guess)
            floor = min(self._floors, default=np.nan)
        avatar = avatar_pose(pose, up, floor, self._origin)
        if not avatar.is_finite():
            return None
        if self._origin is None:
            self._origin = avatar.root_m
            avatar = avatar_pose(pose, up, floor, self._origin)
        return avatar

    def _send(self, datagrams: list[bytes], frame_index: int) -> None:
        """Sends frame ``frame_index``'s ``datagrams``: sent (:meth:`_sent`) when there were some and every
        one went out."""
        failed = False
        for data in datagrams:
            try:
                self._sock.send(data)
            except OSError:   # no receiver (ECONNREFUSED), a full buffer, a network gone
                failed = True
        if failed:
            self.stats.add(sink_dropped=1)
        elif datagrams:
            self._sent(frame_index)

    @abstractmethod
    def _frame_datagrams(self, avatar: AvatarPose, time_s: float) -> list[bytes]:
        """The datagrams of a frame with the person."""

    @abstractmethod
    def _absent_datagrams(self, time_s: float) -> list[bytes]:
        """The datagrams of a frame without the person."""

    def close(self) -> None:
        self._sock.close()


def _xyzw(quats: np.ndarray) -> np.ndarray:
    """Quaternions ``(w, x, y, z)`` as Unity orders them, ``(x, y, z, w)``."""
    return quats[..., [1, 2, 3, 0]]


def _vmc_frame(bones: tuple[str, ...], blend: bool) -> OscFrames:
    """A VMC frame's messages: the root, each of ``bones`` (Unity's names), with ``blend`` each blend shape's
    value and their apply, OK and the time."""
    shapes = [*[("/VMC/Ext/Blend/Val", (name,), 1) for name in BLEND_SHAPES], ("/VMC/Ext/Blend/Apply", (), 0)]
    return OscFrames([("/VMC/Ext/Root/Pos", ("root",), 7), *[("/VMC/Ext/Bone/Pos", (bone,), 7) for bone in bones],
                      *(shapes if blend else []), ("/VMC/Ext/OK", (1,), 0), ("/VMC/Ext/T", (), 1)], MAX_BUNDLE_BYTES)


class VmcSink(AvatarSink):
    """The VMC protocol (Performer → Marionette): per frame ``/VMC/Ext/Root/Pos``, ``/VMC/Ext/Bone/Pos``
    for every bone of :data:`~mocapdb.core.avatar.UNITY_BONES` (then of
    :data:`~mocapdb.core.avatar.UNITY_FINGER_BONES` where the stream has fingers), ``/VMC/Ext/OK 1`` and
    ``/VMC/Ext/T``, in bundles of at most :data:`MAX_BUNDLE_BYTES`; where the stream has blend shapes
    (``live --face``), before OK: ``/VMC/Ext/Blend/Val NAME VALUE`` for each of
    :data:`~mocapdb.core.face_shapes.BLEND_SHAPES` (0, the neutral face, while the face is not seen) and
    ``/VMC/Ext/Blend/Apply``; a frame without the person: ``/VMC/Ext/OK 0`` and ``/VMC/Ext/T``. ``track``:
    the track to send (default: the main one)."""

    def __init__(self, host: str, port: int = VMC_PORT, stats: StreamStats | None = None,
                 track: int | None = None) -> None:
        super().__init__(host, port, stats, track)
        self._frames = {(len(bones), blend): _vmc_frame(bones, blend) for blend in (False, True)
                        for bones in (UNITY_BONES, UNITY_BONES + UNITY_FINGER_BONES)}
        self._absent = OscFrames([("/VMC/Ext/OK", (0,), 0), ("/VMC/Ext/T", (), 1)], MAX_BUNDLE_BYTES)

    def _frame_datagrams(self, avatar: AvatarPose, time_s: float) -> list[bytes]:
        root = np.concatenate([avatar.root_m, _xyzw(ROOT_QUAT)])
        bones = np.hstack([avatar.local_m, _xyzw(avatar.local_quats)])
        shapes = [] if avatar.blend_shapes is None else np.nan_to_num(avatar.blend_shapes, nan=0.0)
        frame = self._frames[len(bones), avatar.blend_shapes is not None]
        return frame.datagrams(np.concatenate([root, bones.ravel(), shapes, [time_s]]))

    def _absent_datagrams(self, time_s: float) -> list[bytes]:
        return self._absent.datagrams(np.array([time_s]))


# VRChat's tracker number → (the bone the tracker sits at, the bone it turns with); "head" aligns the spaces
VRCHAT_TRACKERS: tuple[tuple[str, str, str], ...] = (
    ("1", "Hips", "Hips"), ("2", "Chest", "Chest"), ("3", "LeftFoot", "LeftFoot"), ("4", "RightFoot", "RightFoot"),
    ("5", "LeftLowerLeg", "LeftUpperLeg"), ("6", "RightLowerLeg", "RightUpperLeg"),
    ("7", "LeftLowerArm", "LeftUpperArm"), ("8", "RightLowerArm", "RightUpperArm"), ("head", "Head", "Head"))
_AT = [UNITY_BONES.index(at) for _, at, _ in VRCHAT_TRACKERS]
_TURNS = [UNITY_BONES.index(turns) for _, _, turns in VRCHAT_TRACKERS]


class VrchatSink(AvatarSink):
    """VRChat's OSC trackers (:data:`VRCHAT_TRACKERS`): per frame each tracker's
    ``/tracking/trackers/N/position`` (metres) and ``…/rotation`` (Unity's Euler angles, degrees), one
    message per datagram; nothing while the person is absent."""

    def __init__(self, host: str, port: int = VRCHAT_PORT, stats: StreamStats | None = None) -> None:
        super().__init__(host, port, stats)
        self._frame = OscFrames([(f"/tracking/trackers/{n}/{what}", (), 3)
                                 for n, _, _ in VRCHAT_TRACKERS for what in ("position", "rotation")], None)

    def _frame_datagrams(self, avatar: AvatarPose, time_s: float) -> list[bytes]:
        values = np.hstack([avatar.world_m[_AT], unity_euler_deg(avatar.world_rot[_TURNS])])
        return self._frame.datagrams(values.ravel())

    def _absent_datagrams(self, time_s: float) -> list[bytes]:
        return []
