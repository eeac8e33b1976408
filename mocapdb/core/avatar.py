"""A stream pose as a Unity humanoid avatar's: the bones of Unity's ``HumanBodyBones`` that the VMC
protocol and VRChat's OSC trackers name, in Unity's left-handed, y-up frame (contract:
``data_specs/avatar_protocols.md``).

The avatar is the humanoid rig of BVH export (:data:`~mocapdb.core.skeleton.HUMANOID_NODES`, its
bones at this person's proportions and height) under Unity's names. Its rest pose is a T-pose facing
Unity's +z, the identity of every local rotation (as in a VRM-normalised model).

Frames:

- **levelled**: the view frame turned by the smallest rotation that takes the world's up (``up_view``)
  to +y, so the avatar stands upright however the camera is pitched or rolled;
- **Unity world**: the levelled frame with x negated (a change of handedness, not a mirror image: a
  person facing the camera gives an avatar facing +z, their right hand at +x as an avatar's is), y
  measured from the floor (``up · p = floor_offset_m``), the origin moved to ``origin_m``.

A point ``p`` (view frame) is ``S L p − (0, floor, 0) − origin`` with ``S = diag(−1, 1, 1)``, ``L``
the levelling; a global rotation ``G`` (rest → view) is ``S L G S``; a local rotation ``R`` is
``S R S``: the quaternion ``(w, x, y, z)`` becomes ``(w, x, −y, −z)``.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from mocapdb.core.geometry import matrix_to_euler, matrix_to_quat, quat_mul
from mocapdb.core.hand_rig import FINGER_JOINTS, FINGER_NAMES, SIDE_NAMES
from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose, _rig_table
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    END_JOINTS,
    KP,
    RIG_JOINTS,
    UNIVERSAL_HEIGHT_M,
    rig_globals_into,
    swing_matrices,
)

__all__ = ["ROOT_QUAT", "UNITY_BONES", "UNITY_FINGER_BONES", "VIEW_UP", "AvatarPose", "ankle_floor_m", "avatar_pose",
           "level_rotation", "unity_euler_deg", "unity_points"]

# Unity's name for each humanoid rig bone (Mixamo's names; the ``_End`` sites are no bones)
_UNITY_NAME = {"Hips": "Hips", "Spine": "Spine", "Spine1": "Chest", "Neck": "Neck", "Head": "Head",
               **{f"{side}{mixamo}": f"{side}{unity}" for side in ("Left", "Right") for mixamo, unity in (
                   ("UpLeg", "UpperLeg"), ("Leg", "LowerLeg"), ("Foot", "Foot"), ("ToeBase", "Toes"),
                   ("Shoulder", "Shoulder"), ("Arm", "UpperArm"), ("ForeArm", "LowerArm"), ("Hand", "Hand"))}}
# Unity's name for each finger joint (Mixamo's names; Unity's little finger is Mixamo's pinky)
_UNITY_FINGER = {f"{side}Hand{mixamo}{k}": f"{side}{unity}{phalanx}" for side in SIDE_NAMES
                 for mixamo, unity in zip(FINGER_NAMES, ("Thumb", "Index", "Middle", "Ring", "Little"))
                 for k, phalanx in ((1, "Proximal"), (2, "Intermediate"), (3, "Distal"))}


@dataclass(frozen=True)
class _Table:
    """The avatar's humanoid rig (``fingers``: with the finger joints) as bones: its table
    (:func:`~mocapdb.core.outputs._rig_table`), the nodes that are bones (the body's, then the fingers' in
    :data:`~mocapdb.core.hand_rig.FINGER_JOINTS` order), each node's row in the stacked rotations (rig, end
    joints, fingers; -1: none of its own), the bones that turn and their rows."""

    parents: np.ndarray
    names: tuple[str, ...]
    bone_nodes: np.ndarray
    node_joint: np.ndarray
    turning: np.ndarray
    rows: np.ndarray


@lru_cache(maxsize=2)
def _table(fingers: bool) -> _Table:
    names, parents, _, sources, end_site = _rig_table("humanoid", fingers=fingers)
    body = [i for i in np.flatnonzero(~end_site) if names[i] not in FINGER_JOINTS]
    bone_nodes = np.array(body + [names.index(n) for n in FINGER_JOINTS if n in names])
    stacked = list(RIG_JOINTS) + list(END_JOINTS) + list(FINGER_JOINTS)
    node_joint = np.array([-1 if s is None else stacked.index(s) for s in sources])
    turning = np.flatnonzero(node_joint[bone_nodes] >= 0)
    return _Table(parents, tuple(names), bone_nodes, node_joint, turning, node_joint[bone_nodes[turning]])


_BODY_NAMES = [_table(False).names[i] for i in _table(False).bone_nodes]
UNITY_BONES: tuple[str, ...] = tuple(_UNITY_NAME[str(n)] for n in _BODY_NAMES)     # parents before children
# Unity's finger bones (HumanBodyBones), in FINGER_JOINTS order: the right hand's 15, then the left's
UNITY_FINGER_BONES: tuple[str, ...] = tuple(_UNITY_FINGER[n] for n in FINGER_JOINTS)
_REST_ENDS = np.tile([1.0, 0.0, 0.0, 0.0], (len(END_JOINTS), 1))   # end joints not estimated: not turned
_FLOOR_PLANE = np.array([1.0, 0.0, 1.0])                      # a point's projection on the floor (y = 0)
_MIRROR = np.array([-1.0, 1.0, 1.0])                         # S: levelled (right-handed) ↔ Unity (left-handed)
_QUAT_MIRROR = np.array([1.0, 1.0, -1.0, -1.0])              # S R S on a quaternion (w, x, y, z)
VIEW_UP = np.array([0.0, 1.0, 0.0])                          # the up assumed when none was estimated
ROOT_QUAT = np.array([1.0, 0.0, 0.0, 0.0])                   # the root transform's rotation: identity, always


@dataclass(frozen=True)
class AvatarPose:
    """One person's avatar in the Unity world frame (metres; quaternions ``(w, x, y, z)``), bones in
    :data:`UNITY_BONES` order, then :data:`UNITY_FINGER_BONES`' where the pose has finger rotations.
    The root transform stands on the floor under the pelvis with rotation :data:`ROOT_QUAT`; every bone's local
    position is its T-pose offset from its parent on this body
    (the Hips': from the root, so its height is the pelvis's above the floor) and its local rotation is
    relative to the T-pose."""

    root_m: np.ndarray       # [3] the root transform's position: the pelvis's floor point (y = 0)
    local_m: np.ndarray      # [B, 3] local positions
    local_quats: np.ndarray  # [B, 4] local rotations
    world_m: np.ndarray      # [B, 3] bone positions (the joint each bone turns about)
    world_rot: np.ndarray    # [B, 3, 3] global rotations (identity in the T-pose)
    blend_shapes: np.ndarray | None = None   # [3] the face's (PersonPose.blend_shapes); None: no faces

    def is_finite(self) -> bool:
        """Whether every value is a finite number."""
        arrays = (self.root_m, self.local_m, self.local_quats, self.world_m, self.world_rot)
        return all(bool(np.isfinite(a).all()) for a in arrays)


def level_rotation(up_view: np.ndarray) -> np.ndarray:
    """``[3, 3]`` the smallest rotation taking ``up_view`` (unit, view frame) to +y."""
    return _levelling(tuple(float(u) for u in up_view))[0]


@lru_cache(maxsize=16)
def _levelling(up_view: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`level_rotation` as a matrix and a quaternion; an up seen again costs nothing."""
    level = swing_matrices(np.array(up_view), VIEW_UP)
    return level, matrix_to_quat(level)


def unity_points(points_view: np.ndarray, up_view: np.ndarray, floor_offset_m: float,
                 origin_m: np.ndarray | None = None) -> np.ndarray:
    """Points ``[..., 3]`` (view frame, metres) in the Unity world frame: levelled, x negated, y above
    the floor ``up_view · p = floor_offset_m``, less ``origin_m`` ([3], a Unity floor point)."""
    out = np.asarray(points_view, dtype=np.float64) @ (level_rotation(up_view).T * _MIRROR)
    out[..., 1] -= floor_offset_m
    return out if origin_m is None else out - origin_m


def ankle_floor_m(pose: PersonPose, up_view: np.ndarray) -> float:
    """This frame's guess at the floor, ``up_view · p`` (view frame, metres) of the floor under the lower
    ankle: its height less the ankle's own above the floor (:data:`ANKLE_HEIGHT_M` at the body's scale)."""
    ankles_view = pose.joints_m[[KP["r_ankle"], KP["l_ankle"]]] * CAMERA_FROM_VIEW
    return float(np.min(ankles_view @ up_view)) - ANKLE_HEIGHT_M * pose.height_m / UNIVERSAL_HEIGHT_M


@lru_cache(maxsize=8)
def _rest_offsets_m(proportions: tuple[float, ...] | None, fingers: bool) -> np.ndarray:
    """The humanoid rig's rest offsets ``[N, 3]`` (metres, 1.75 m stature) for bone lengths ``proportions``
    (``fingers``: with the finger joints)."""
    return _rig_table("humanoid", None if proportions is None else np.array(proportions), fingers)[2]


def avatar_pose(pose: PersonPose, up_view: np.ndarray, floor_offset_m: float,
                origin_m: np.ndarray | None = None) -> AvatarPose:
    """The avatar of ``pose`` standing on the floor ``up_view · p = floor_offset_m`` (view frame,
    metres; ``up_view`` unit), positions less ``origin_m`` ([3], Unity world; None: the origin is the
    floor point under the camera)."""
    scale = pose.height_m / UNIVERSAL_HEIGHT_M
    proportions = None if pose.bones_m is None else tuple(float(b) for b in pose.bones_m / scale)
    rotations = [pose.quaternions, _REST_ENDS if pose.end_quaternions is None else pose.end_quaternions]
    fingers = pose.finger_quaternions is not None
    if pose.finger_quaternions is not None:
        rotations.append(pose.finger_quaternions)
    offsets, table = _rest_offsets_m(proportions, fingers), _table(fingers)
    n = len(table.names)
    g_rot, g_pos = np.empty((n, 3, 3)), np.empty((n, 3))
    pelvis_view = pose.root_m * CAMERA_FROM_VIEW
    quats = np.ascontiguousarray(np.vstack(rotations), dtype=np.float64)
    rig_globals_into(quats, pelvis_view, scale, table.parents, offsets, table.node_joint, np.empty((3, 3)), g_rot,
                     g_pos)
    bones = table.bone_nodes
    level, level_quat = _levelling(tuple(float(u) for u in up_view))
    world_rot = (_MIRROR[:, None] * level) @ g_rot[bones] * _MIRROR   # S L G S
    world_m = unity_points(g_pos[bones], up_view, floor_offset_m, origin_m)
    local_m = offsets[bones] * (scale * _MIRROR)
    local_m[0] = (0.0, world_m[0, 1], 0.0)
    local_quats = np.tile(ROOT_QUAT, (len(bones), 1))
    local_quats[table.turning] = quats[table.rows]
    local_quats[0] = quat_mul(level_quat, local_quats[0])
    local_quats *= _QUAT_MIRROR
    return AvatarPose(world_m[0] * _FLOOR_PLANE, local_m, local_quats, world_m, world_rot, pose.blend_shapes)


def unity_euler_deg(rotations: np.ndarray) -> np.ndarray:
    """Unity's Euler angles ``[..., 3]`` (x, y, z, degrees) of rotation matrices ``[..., 3, 3]``: turned
    about z, then x, then y (world axes), ``R = Ry Rx Rz``."""
    yxz = matrix_to_euler(rotations, "YXZ")
    return yxz[..., [1, 0, 2]]
