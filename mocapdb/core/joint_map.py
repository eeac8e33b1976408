"""Which joints of a BVH rig make the universal skeleton, and where they are in metres, y up.

A rig's joints are matched to 13 *roles* (head, and upper arm, forearm, hand, thigh, shin, foot
on each side) from the words of their names, the hierarchy and the rest pose
(:mod:`mocapdb.core.rig_detect`, ``data_specs/joint_conventions.md``), for any exporter's
spelling; the named conventions of the spec (CMU ASF/AMC, CMU cgspeed/3ds Max,
MotionBuilder/Mixamo, Character Creator, MakeHuman CMU+) only label the result, and mocapdb's
own universal rig is read by its exact names.
Nothing is guessed: a role with no candidate or several gives :class:`JointMapError`, and a
``--joint-map`` TOML file can name any role's joint. The length unit and the up axis are
detected from the body (leg length; head above the feet) unless given.
"""
from __future__ import annotations

import re
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mocapdb.core.errors import MocapdbError
from mocapdb.core.files import MIB, read_input_text
from mocapdb.core.formats.bvh import POSITION_MODE_TEXT, Bvh, forward_kinematics
from mocapdb.core.rig_detect import (
    LIMBS,
    ROLES,
    check_sides,
    check_structure,
    found_so_far,
    place_roles,
    rest_positions,
)
from mocapdb.core.skeleton import KEYPOINTS, N_POINTS
from mocapdb.core.units import UNITS, UP_AXES

# Keypoints that are a joint's position; neck, pelvis and head (nose) are derived.
KEYPOINT_ROLES = {
    "r_shoulder": "r_upperarm", "r_elbow": "r_forearm", "r_wrist": "r_hand",
    "l_shoulder": "l_upperarm", "l_elbow": "l_forearm", "l_wrist": "l_hand",
    "r_hip": "r_thigh", "r_knee": "r_shin", "r_ankle": "r_foot",
    "l_hip": "l_thigh", "l_knee": "l_shin", "l_ankle": "l_foot"}
ROLE_COLUMN = {role: k for k, role in enumerate(ROLES)}  # a role's column in _role_kinematics' arrays

# Metres per file unit. "cmu" is the CMU ASF unit (1/0.45 inch) that cgspeed-style CMU BVH files keep.
# Plausible leg length (hip → knee → ankle), metres. The window spans a factor 2, less than the
# smallest ratio between two units (cmu/in = 2.22), so at most one unit fits.
LEG_LENGTH_RANGE_M = (0.6, 1.2)
MAX_JOINT_MAP_BYTES = MIB  # a joint map names a few dozen joints
UP_AXIS_MIN_COSINE = 0.8  # the body's median up direction must be this close to a world axis
NOSE_FORWARD_M = 0.10     # nose ahead of the head joint, along the head's rest forward
NOSE_UP_M = 0.02          # and above it, along the head's rest up

# Proper rotations taking each up axis to +y (never a mirror: every determinant is +1).
_TO_Y_UP = {
    "y": np.eye(3),
    "-y": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),
    "z": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "x": np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]]),
    "-x": np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 1]]),
}


def _convention(sides: tuple[str, str], head: tuple[str, ...], upperarm: tuple[str, ...],
                forearm: tuple[str, ...], hand: tuple[str, ...], thigh: tuple[str, ...],
                shin: tuple[str, ...], foot: tuple[str, ...]) -> dict[str, tuple[str, ...]]:
    """Role → the lower-case names a convention gives it; ``{s}`` is the (left, right) side token."""
    table = {"head": head}
    parts = {"upperarm": upperarm, "forearm": forearm, "hand": hand, "thigh": thigh, "shin": shin, "foot": foot}
    for side, token in zip("lr", sides):
        for part, names in parts.items():
            table[f"{side}_{part}"] = tuple(n.format(s=token) for n in names)
    return table


UNIVERSAL_CONVENTION = "mocapdb_universal"
UNIVERSAL_NOSE = "neck_end"  # the universal rig's neck End Site is the nose (``mocapdb.core.skeleton``)

CONVENTIONS: dict[str, dict[str, tuple[str, ...]]] = {
    "cmu_asf": _convention(("l", "r"), ("head",), ("{s}humerus",), ("{s}radius",),
                           ("{s}wrist", "{s}hand"), ("{s}femur",), ("{s}tibia",), ("{s}foot",)),
    "cmu_cgspeed": _convention(("left", "right"), ("head",), ("{s}shoulder",), ("{s}elbow",),
                               ("{s}wrist",), ("{s}hip",), ("{s}knee",), ("{s}ankle",)),
    "motionbuilder_mixamo": _convention(("left", "right"), ("head",), ("{s}arm",), ("{s}forearm",),
                                        ("{s}hand",), ("{s}upleg",), ("{s}leg",), ("{s}foot",)),
    "character_creator": _convention(("l", "r"), ("cc_base_head",), ("cc_base_{s}_upperarm",),
                                     ("cc_base_{s}_forearm",), ("cc_base_{s}_hand",), ("cc_base_{s}_thigh",),
                                     ("cc_base_{s}_calf",), ("cc_base_{s}_foot",)),
    "makehuman_cmu": _convention(("l", "r"), ("head",), ("{s}shldr",), ("{s}forearm",), ("{s}hand",),
                                 ("{s}thigh",), ("{s}shin",), ("{s}foot",)),
    # mocapdb's own rig (``motion_bvh``: `mocapdb stereo`, `track_*.bvh`): the nose, wrists and
    # ankles are End Sites, and the head role is the nose End Site itself.
    UNIVERSAL_CONVENTION: _convention(("l", "r"), (UNIVERSAL_NOSE,), ("{s}_shoulder",), ("{s}_elbow",),
                                      ("{s}_elbow_end",), ("{s}_hip",), ("{s}_knee",), ("{s}_knee_end",)),
}

_MAP_HINT = ("Name the joints yourself with --joint-map FILE.toml, for example:\n"
             "  [joints]\n  l_hand = \"SourceJointName\"")


class JointMapError(MocapdbError, ValueError):
    """A rig whose joints cannot be mapped onto the roles, or a bad joint-map file."""


@dataclass
class JointMapping:
    """The detected (or given) source joint of every role, and the evidence."""

    convention: str
    joints: dict[str, str]  # role -> source joint name
    why: dict[str, str] = field(default_factory=dict)  # role -> what chose its joint
    notes: list[str] = field(default_factory=list)     # the structure and sides as checked


@dataclass
class JointMapFile:
    """A ``--joint-map`` TOML file: role overrides and optional unit and up axis."""

    joints: dict[str, str]
    up_axis: str | None = None
    unit: str | None = None


def _normalized_name(name: str) -> str:
    """Joint name without a namespace prefix (``mixamorig:``, ``Armature|``), lower case."""
    return re.split(r"[:|]", name)[-1].lower()


def _fixed_joints(bvh: Bvh, overrides: dict[str, str]) -> dict[str, int]:
    """Override role → joint index; unknown roles or joints raise :class:`JointMapError`."""
    _check_roles(overrides, "joint map")
    missing = [f"{r} = {n!r}" for r, n in overrides.items() if n not in bvh.names]
    if missing:
        raise JointMapError(f"{bvh.source}: the joint map names joints that are not in the file: "
                            f"{', '.join(missing)}; the file's joints are: {', '.join(bvh.names)}")
    return {r: bvh.index(n) for r, n in overrides.items()}


def _check_roles(roles: Sequence[str] | dict[str, str], where: str) -> None:
    unknown = [r for r in roles if r not in ROLES]
    if unknown:
        raise JointMapError(f"{where}: unknown role(s) {', '.join(map(repr, unknown))}; "
                            f"valid roles: {', '.join(ROLES)}")


def _universal_joints(bvh: Bvh) -> dict[str, int]:
    """mocapdb's own rig (its End Sites are roles): every role's joint when each name is there once."""
    normal = [_normalized_name(n) for n in bvh.names]
    table = CONVENTIONS[UNIVERSAL_CONVENTION]
    hits = {r: [j for j, n in enumerate(normal) if n == table[r][0]] for r in ROLES}
    return {r: js[0] for r, js in hits.items() if len(js) == 1} if all(len(js) == 1 for js in hits.values()) else {}


def detect_mapping(bvh: Bvh, overrides: dict[str, str] | None = None) -> JointMapping:
    """Map every role onto a source joint from its name's words, the hierarchy and the rest pose
    (:mod:`mocapdb.core.rig_detect`); ``overrides`` (role → joint name) fix some roles.

    Raises :class:`JointMapError` naming every role with no candidate or several (and those
    candidates), a hierarchy that is no humanoid's, or sides the rest pose contradicts, with
    what was found.
    """
    overrides = overrides or {}
    fixed = _fixed_joints(bvh, overrides)
    own = {} if overrides else _universal_joints(bvh)
    reading = place_roles(bvh, own or fixed)
    if own:
        reading.why = dict.fromkeys(ROLES, "mocapdb's own rig (motion_bvh)")
    if not reading.problems:
        check_structure(bvh, reading.placed, reading)
    if not reading.problems:
        check_sides(bvh, reading.placed, set(fixed), reading)
    if reading.problems:
        raise JointMapError(f"{bvh.source}: cannot map the rig onto the universal skeleton:\n  "
                            + "\n  ".join(reading.problems) + f"\nfound: {found_so_far(bvh, reading)}\n"
                            + _MAP_HINT)
    joints = {r: bvh.names[reading.placed[r]] for r in ROLES}
    return JointMapping(_label(joints, set(fixed)), joints, reading.why, reading.notes)


def _styles(joints: dict[str, str], chain: tuple[str, ...]) -> list[str]:
    """The named conventions whose names the chain's joints carry."""
    return [c for c, table in CONVENTIONS.items()
            if all(_normalized_name(joints[r]) in table[r] for r in chain)]


def _label(joints: dict[str, str], fixed: set[str]) -> str:
    """The named convention every detected limb's names belong to (or the mixture; else the
    ``detected (left upper arm, left thigh)`` names), noting a joint map."""
    detected = [[r for r in chain if r not in fixed] for chain in LIMBS]
    styles = [_styles(joints, tuple(roles)) for roles in detected if roles]
    if not styles:
        return "joint map"
    common = [c for c in CONVENTIONS if all(c in s for s in styles)]
    if common:
        label = common[0]
    elif all(styles):
        label = "mixed: " + " + ".join(dict.fromkeys(s[0] for s in styles))
    else:
        label = f"detected ({joints['l_upperarm']}, {joints['l_thigh']})"
    return f"{label} + joint map" if fixed else label


def load_joint_map_file(path: str | Path) -> JointMapFile:
    """Read a joint-map TOML file (``[joints]`` role = "Joint", optional ``unit``, ``up_axis``)."""
    path = Path(path)
    text = read_input_text(path, MAX_JOINT_MAP_BYTES, JointMapError, "joint map (TOML)")
    try:
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise JointMapError(f"{path}: not a valid TOML joint map ({exc})") from None
    unknown = [k for k in data if k not in ("joints", "unit", "up_axis")]
    if unknown:
        raise JointMapError(f"{path}: unknown key(s) {', '.join(unknown)}; valid: [joints], unit, up_axis")
    joints = data.get("joints", {})
    if not isinstance(joints, dict) or not all(isinstance(v, str) for v in joints.values()):
        raise JointMapError(f"{path}: [joints] must be a table of role = \"SourceJointName\" strings")
    _check_roles(joints, str(path))
    unit, up_axis = data.get("unit"), data.get("up_axis")
    if unit is not None and unit not in UNITS:
        raise JointMapError(f"{path}: unit {unit!r} is not one of {', '.join(UNITS)}")
    if up_axis is not None and up_axis not in UP_AXES:
        raise JointMapError(f"{path}: up_axis {up_axis!r} is not one of {', '.join(UP_AXES)}")
    return JointMapFile(dict(joints), up_axis, unit)


def _indexes(bvh: Bvh, mapping: JointMapping) -> dict[str, int]:
    missing = [n for n in mapping.joints.values() if n not in bvh.names]
    if missing or set(mapping.joints) != set(ROLES):
        raise JointMapError(f"{bvh.source}: mapping does not fit this file (joints {missing}, roles "
                            f"{sorted(mapping.joints)})")
    return {r: bvh.index(n) for r, n in mapping.joints.items()}


def leg_length(bvh: Bvh, mapping: JointMapping) -> float:
    """Rest-pose thigh→shin plus shin→foot distance, mean of both legs, in file units."""
    rest, idx = rest_positions(bvh), _indexes(bvh, mapping)
    legs = [np.linalg.norm(rest[idx[f"{s}_shin"]] - rest[idx[f"{s}_thigh"]])
            + np.linalg.norm(rest[idx[f"{s}_foot"]] - rest[idx[f"{s}_shin"]]) for s in "lr"]
    return float(np.mean(legs))


def detect_unit(bvh: Bvh, mapping: JointMapping) -> str:
    """The unit of :data:`UNITS` that makes the leg length plausible for a person."""
    length = leg_length(bvh, mapping)
    lo, hi = LEG_LENGTH_RANGE_M
    fits = [u for u, metres in UNITS.items() if lo <= length * metres <= hi]
    if not fits:
        raise JointMapError(f"{bvh.source}: the legs are {length:.4g} file units long (hip to ankle), which "
                            f"is no plausible {lo}-{hi} m in any of {', '.join(UNITS)}; give unit = ... "
                            "in a --joint-map file")
    return fits[0]


def detect_up_axis(positions: np.ndarray, upper: Sequence[int], lower: Sequence[int]) -> str:
    """Signed world axis (``"x"`` … ``"-z"``) from the ``lower`` joints (ankles) to the ``upper`` (shoulders).

    ``positions [F, J, 3]``; the median over frames of the unit direction must lie within
    ``acos(UP_AXIS_MIN_COSINE)`` of an axis, else :class:`JointMapError`.
    """
    up = positions[:, list(upper)].mean(axis=1) - positions[:, list(lower)].mean(axis=1)
    up /= np.maximum(np.linalg.norm(up, axis=-1, keepdims=True), 1e-12)
    median = np.median(up, axis=0)
    k = int(np.argmax(np.abs(median)))
    if abs(median[k]) < UP_AXIS_MIN_COSINE * np.linalg.norm(median):
        raise JointMapError(f"the body's up direction {np.round(median, 2).tolist()} is near no world axis; "
                            "give up_axis = ... in a --joint-map file")
    return ("-" if median[k] < 0 else "") + "xyz"[k]


def _nose_offset(bvh: Bvh, idx: dict[str, int], metres_per_unit: float) -> np.ndarray:
    """The nose relative to the head joint, in the head joint's local frame (file units).

    From the rest pose (where every global rotation is identity, so world = head-local):
    up = mid-hips → mid-shoulders, forward = normalize((left − right shoulder) × up).
    """
    rest = rest_positions(bvh)
    left_minus_right = rest[idx["l_upperarm"]] - rest[idx["r_upperarm"]]
    up = (rest[idx["l_upperarm"]] + rest[idx["r_upperarm"]] - rest[idx["l_thigh"]] - rest[idx["r_thigh"]]) / 2
    forward = np.cross(left_minus_right, up)
    if np.linalg.norm(forward) <= 1e-6 * np.linalg.norm(left_minus_right) * np.linalg.norm(up):
        raise JointMapError(f"{bvh.source}: the rest pose has no torso front (shoulders in line with the spine)")
    forward /= np.linalg.norm(forward)
    up /= np.linalg.norm(up)
    return (NOSE_FORWARD_M * forward + NOSE_UP_M * up) / metres_per_unit


def _check_choice(value: str, choices: Sequence[str] | dict[str, float], what: str) -> None:
    if value not in choices:
        raise JointMapError(f"{what} {value!r} is not one of {', '.join(choices)}")


def _role_kinematics(bvh: Bvh, idx: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Global positions ``[F, 13, 3]`` (file units) and rotations ``[F, 13, 3, 3]`` of the roles'
    joints, columns in :data:`ROLES` order (:data:`ROLE_COLUMN`); only they and their ancestors are
    chained, not the whole rig."""
    return forward_kinematics(bvh, [idx[role] for role in ROLES])


def y_up_rotation(bvh: Bvh, mapping: JointMapping, up_axis: str | None = None) -> np.ndarray:
    """``[3, 3]`` the proper rotation :func:`extract_keypoints` takes the file's axes to y up with
    (``up_axis`` detected when None): a file rotation ``R`` is ``T @ R`` in its keypoints' frame."""
    if up_axis is None:
        up_axis = _body_up_axis(_role_kinematics(bvh, _indexes(bvh, mapping))[0])
    _check_choice(up_axis, UP_AXES, "up axis")
    return _TO_Y_UP[up_axis]


def _body_up_axis(role_positions: np.ndarray) -> str:
    """The up axis from the roles' positions ``[F, 13, 3]`` (:func:`_role_kinematics`)."""
    col = ROLE_COLUMN
    return detect_up_axis(role_positions, [col["r_upperarm"], col["l_upperarm"]], [col["r_foot"], col["l_foot"]])


def extract_keypoints(bvh: Bvh, mapping: JointMapping, unit: str | None = None,
                      up_axis: str | None = None) -> np.ndarray:
    """Universal keypoints ``[F, N_POINTS, 3]`` (KEYPOINTS order), metres, y up, right-handed.

    ``unit`` and ``up_axis`` are detected when ``None``. The detected up axis is turned to +y by a
    proper rotation. The nose is the head joint plus a fixed head-local offset, except on the
    universal rig, whose head role is the nose End Site itself.
    """
    idx = _indexes(bvh, mapping)
    unit = unit or detect_unit(bvh, mapping)
    _check_choice(unit, UNITS, "unit")
    pos, rot = _role_kinematics(bvh, idx)
    up_axis = up_axis or _body_up_axis(pos)
    _check_choice(up_axis, UP_AXES, "up axis")
    col = ROLE_COLUMN
    points = np.empty((bvh.n_frames, N_POINTS, 3))
    for keypoint, role in KEYPOINT_ROLES.items():
        points[:, KEYPOINTS.index(keypoint)] = pos[:, col[role]]
    points[:, KEYPOINTS.index("neck")] = (pos[:, col["r_upperarm"]] + pos[:, col["l_upperarm"]]) / 2
    points[:, KEYPOINTS.index("pelvis")] = (pos[:, col["r_thigh"]] + pos[:, col["l_thigh"]]) / 2
    points[:, KEYPOINTS.index("head")] = pos[:, col["head"]]
    if _normalized_name(mapping.joints["head"]) != UNIVERSAL_NOSE:
        points[:, KEYPOINTS.index("head")] += rot[:, col["head"]] @ _nose_offset(bvh, idx, UNITS[unit])
    return (points * UNITS[unit]) @ _TO_Y_UP[up_axis].T


def describe(bvh: Bvh, mapping: JointMapping, unit: str | None = None, up_axis: str | None = None) -> str:
    """Human-readable summary for ``mocapdb inspect``: file, timing, joints and how their position
    channels are read, convention, unit, up axis, roles."""
    idx = _indexes(bvh, mapping)
    unit_how = "given" if unit else "detected"
    unit = unit or detect_unit(bvh, mapping)
    _check_choice(unit, UNITS, "unit")
    axis_how = "given" if up_axis else "detected"
    up_axis = up_axis or _body_up_axis(_role_kinematics(bvh, idx)[0])
    _check_choice(up_axis, UP_AXES, "up axis")
    lines = [f"file:        {bvh.source}",
             f"frames:      {bvh.n_frames} at {bvh.fps:.2f} fps ({bvh.n_frames * bvh.frame_time:.2f} s)",
             f"joints:      {len(bvh.names)} ({int(bvh.end_site.sum())} of them end sites)",
             f"non-root position channels: {POSITION_MODE_TEXT[bvh.position_mode]}",
             f"convention:  {mapping.convention}",
             f"unit:        {unit} ({unit_how})",
             f"up axis:     {up_axis} ({axis_how})",
             f"leg length:  {leg_length(bvh, mapping) * UNITS[unit]:.3f} m (hip to ankle, rest pose)",
             "roles:"]
    width = max(len(n) for n in mapping.joints.values())
    lines += [f"  {role:<11} {mapping.joints[role]:<{width}}  {mapping.why.get(role, '')}".rstrip()
              for role in ROLES]
    return "\n".join(lines + mapping.notes)
