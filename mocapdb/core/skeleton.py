"""The universal skeleton: 14 OpenPose body keypoints plus the pelvis, on one rig with fixed bones.

Every database pose, runtime output and stereo capture lives on this skeleton (contract:
``data_specs/skeleton.md``). Rest pose: a 175 cm adult in T-pose facing +z, y up, x to the
subject's left, metres, pelvis (mid-hip) at the origin.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapdb.core.geometry import frame_from_axes, matrix_to_quat
from mocapdb.core.hand_rig import finger_nodes
from mocapdb.core.kernels import mat3_mul_into, quat_to_matrix_into
from mocapdb.core.keypoint_order import KEYPOINTS, KP, N_KEYPOINTS_2D  # noqa: F401 - the order, re-exported

# Lines drawn between the 14 keypoints in pictures of a pose (pairs of KEYPOINTS indices).
DRAWING_LINES: tuple[tuple[int, int], ...] = tuple(
    (KEYPOINTS.index(a), KEYPOINTS.index(b)) for a, b in (
        ("head", "neck"), ("neck", "r_shoulder"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"),
        ("neck", "l_shoulder"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
        ("r_shoulder", "r_hip"), ("l_shoulder", "l_hip"), ("r_hip", "l_hip"), ("r_hip", "r_knee"),
        ("r_knee", "r_ankle"), ("l_hip", "l_knee"), ("l_knee", "l_ankle")))
N_POINTS = len(KEYPOINTS)
PELVIS = KEYPOINTS.index("pelvis")
# Left/right keypoint pairs; the mirror image of a pose swaps them (head, neck, pelvis stay).
MIRROR_PAIRS: tuple[tuple[str, str], ...] = tuple(
    (f"r_{part}", f"l_{part}") for part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"))
_OPPOSITE = {a: b for pair in MIRROR_PAIRS for a, b in (pair, pair[::-1])}
MIRROR_SOURCE = np.array(  # each keypoint's mirror partner (itself: head, neck, pelvis)
    [KP[_OPPOSITE.get(name, name)] for name in KEYPOINTS])

# Bone lengths of the universal skeleton, metres (175 cm adult; ankle 8 cm above the floor).
BONE_LENGTHS_M = {
    "half_hip_width": 0.10,
    "thigh": 0.43,
    "shin": 0.42,
    "torso": 0.52,          # pelvis (mid-hip) to neck (mid-shoulder)
    "half_shoulder_width": 0.19,
    "upper_arm": 0.29,
    "forearm": 0.26,
}
UNIVERSAL_HEIGHT_M = 1.75  # standing height of the universal skeleton (its bones scale with a subject's)
NOSE_OFFSET_M = np.array([0.0, 0.19, 0.08])  # neck → nose in the rest pose
ANKLE_HEIGHT_M = 0.08                         # ankle joint above the floor when standing

# The body's measurable bones (what a person's own skeleton is made of), each the mean over the
# keypoint pairs listed (left and right sides as one bone). Metres, universal lengths in
# :func:`universal_bone_lengths_m`.
MEASURED_BONES: dict[str, tuple[tuple[str, str], ...]] = {
    "thigh": (("r_hip", "r_knee"), ("l_hip", "l_knee")),
    "shank": (("r_knee", "r_ankle"), ("l_knee", "l_ankle")),
    "upper_arm": (("r_shoulder", "r_elbow"), ("l_shoulder", "l_elbow")),
    "forearm": (("r_elbow", "r_wrist"), ("l_elbow", "l_wrist")),
    "hip_width": (("r_hip", "l_hip"),),
    "shoulder_width": (("r_shoulder", "l_shoulder"),),
    "torso": (("pelvis", "neck"),),
    "neck_nose": (("neck", "head"),),
}
MEASURED_BONE_NAMES: tuple[str, ...] = tuple(MEASURED_BONES)

_B = BONE_LENGTHS_M
# Rig nodes in BVH order: (name, parent, rest offset from parent in metres, keypoint or None).
# Nodes whose name is not a rotation joint are End Sites (the leaves nose, wrists, ankles).
RIG_NODES: tuple[tuple[str, str | None, tuple[float, float, float], str | None], ...] = (
    ("pelvis", None, (0.0, 0.0, 0.0), "pelvis"),
    ("r_hip", "pelvis", (-_B["half_hip_width"], 0.0, 0.0), "r_hip"),
    ("r_knee", "r_hip", (0.0, -_B["thigh"], 0.0), "r_knee"),
    ("r_ankle", "r_knee", (0.0, -_B["shin"], 0.0), "r_ankle"),
    ("l_hip", "pelvis", (_B["half_hip_width"], 0.0, 0.0), "l_hip"),
    ("l_knee", "l_hip", (0.0, -_B["thigh"], 0.0), "l_knee"),
    ("l_ankle", "l_knee", (0.0, -_B["shin"], 0.0), "l_ankle"),
    ("spine", "pelvis", (0.0, 0.0, 0.0), None),
    ("neck", "spine", (0.0, _B["torso"], 0.0), "neck"),
    ("head", "neck", tuple(NOSE_OFFSET_M), "head"),
    ("r_shoulder", "spine", (-_B["half_shoulder_width"], _B["torso"], 0.0), "r_shoulder"),
    ("r_elbow", "r_shoulder", (-_B["upper_arm"], 0.0, 0.0), "r_elbow"),
    ("r_wrist", "r_elbow", (-_B["forearm"], 0.0, 0.0), "r_wrist"),
    ("l_shoulder", "spine", (_B["half_shoulder_width"], _B["torso"], 0.0), "l_shoulder"),
    ("l_elbow", "l_shoulder", (_B["upper_arm"], 0.0, 0.0), "l_elbow"),
    ("l_wrist", "l_elbow", (_B["forearm"], 0.0, 0.0), "l_wrist"),
)
END_SITES = ("r_ankle", "l_ankle", "head", "r_wrist", "l_wrist")
NODE_NAMES = tuple(n[0] for n in RIG_NODES)
NODE_PARENTS = np.array([-1 if n[1] is None else NODE_NAMES.index(n[1]) for n in RIG_NODES])
NODE_OFFSETS_M = np.array([n[2] for n in RIG_NODES])
# Rotation joints (those that are not End Sites), in BVH order: the rows of stored quaternions.
RIG_JOINTS: tuple[str, ...] = tuple(n for n in NODE_NAMES if n not in END_SITES)
N_RIG_JOINTS = len(RIG_JOINTS)
NODE_OF_POINT = np.array([NODE_NAMES.index(next(n[0] for n in RIG_NODES if n[3] == kp)) for kp in KEYPOINTS])
JOINT_NODE = np.array([NODE_NAMES.index(j) for j in RIG_JOINTS])
NODE_JOINT = np.array([RIG_JOINTS.index(n) if n in RIG_JOINTS else -1 for n in NODE_NAMES])
# The measured bone (MEASURED_BONES) whose length sets each rig node's rest offset, per axis (x, y, z);
# None: a length no camera measures, kept in proportion to the body. Offsets of a person's own body:
# :func:`body_offsets_m`.
NODE_BONE_AXES: dict[str, tuple[str | None, str | None, str | None]] = {
    **{f"{s}_hip": ("hip_width", None, None) for s in "rl"},
    **{f"{s}_knee": (None, "thigh", None) for s in "rl"},
    **{f"{s}_ankle": (None, "shank", None) for s in "rl"},
    "neck": (None, "torso", None), "head": (None, "neck_nose", "neck_nose"),
    **{f"{s}_shoulder": ("shoulder_width", "torso", None) for s in "rl"},
    **{f"{s}_elbow": ("upper_arm", None, None) for s in "rl"},
    **{f"{s}_wrist": ("forearm", None, None) for s in "rl"},
}

# The humanoid rig of BVH export (``--rig humanoid``): the universal rig with the bones character
# set-ups expect (head, clavicles, hands, feet, toes) under the names auto-mappers recognise
# (Unity Humanoid, HumanIK, Blender: Mixamo's). Rows: (name, parent, rest offset from the parent in
# metres, universal rig joint or end joint (:data:`END_JOINTS`) whose rotation it carries, or None:
# identity). The added joints move no universal joint: every universal joint stays exactly where
# the universal rig puts it; the feet and hands turn only where a layout gives heels, toes and
# knuckles (``runtime.take.end_rotations``), the head where it gives face points (``runtime.head_pose``;
# its rotation relative to the neck: data_specs/head.md); names ending in "_End" are End Sites (named as
# mocapdb reads them back: parent + "_End"). Hand, foot and head-base lengths are not measured: fixed proportions.
END_JOINTS: tuple[str, ...] = ("r_foot", "l_foot", "r_hand", "l_hand", "head")  # at the ankles, wrists, skull base
HAND_LENGTH_M = 0.08      # wrist → end of the hand bone (the index and pinky knuckles), along the forearm
# Heel keypoint → big-toe keypoint of a standing foot: length and downward slope (the heel keypoint
# sits higher on the heel than the toe's on the toe): the bundled balancing take's 4-camera
# triangulation, medians over each planted foot (right, left: 20.2 and 20.7 cm; 14.8° and 10.0°)
HEEL_TO_TOE_M = 0.21
HEEL_TO_TOE_SLOPE_DEG = 12.0
FOOT_FORWARD_M = 0.14     # ankle → ball of the foot, forwards (+z at rest)
TOE_LENGTH_M = 0.05
HEAD_BASE_M = 0.10        # neck → head joint (skull base), up; the head bone ends at the nose
CLAVICLE_M = 0.04         # spine-top → clavicle joint, outwards of the shoulder line
# The face points after the nose (the extremities' names: keypoint_layouts.EXTREMITIES)
FACE_NAMES = ("r_eye", "l_eye", "r_ear", "l_ear", "r_mouth", "l_mouth")
# The face model of a 1.75 m adult (metres; head frame: x left, y up, z forwards; origin between the
# ears), rows: nose, then FACE_NAMES. Rounded adult means of craniofacial anthropometry, not fitted to
# any take: bitragion breadth about 15 cm (ears ±7.5 cm); interpupillary distance about 6.3 cm (eyes
# ±3.2 cm), the pupils about 2 cm above the ear-eye (Frankfort) plane and 8.5 cm ahead of the tragion;
# the nose tip 10.5 cm ahead of the tragion and 1.5 cm below it; mouth width about 5 cm (corners
# ±2.5 cm), 5.5 cm below the tragion and 8 cm ahead of it.
FACE_MODEL_M = np.array([
    [0.0, -0.015, 0.105],
    [-0.032, 0.02, 0.085], [0.032, 0.02, 0.085],
    [-0.075, 0.0, 0.0], [0.075, 0.0, 0.0],
    [-0.025, -0.055, 0.08], [0.025, -0.055, 0.08]])
_HALF_TORSO = _B["torso"] / 2
_ANKLE_TO_BALL = (0.0, -ANKLE_HEIGHT_M + 0.02, FOOT_FORWARD_M)


def _humanoid_leg(x: float) -> tuple:
    """One leg's rows (``x`` = -1 right, +1 left: the side's sign of x in the universal rig)."""
    name, short = ("Right", "r") if x < 0 else ("Left", "l")
    b = _B
    return (
        (f"{name}UpLeg", "Hips", (x * b["half_hip_width"], 0.0, 0.0), f"{short}_hip"),
        (f"{name}Leg", f"{name}UpLeg", (0.0, -b["thigh"], 0.0), f"{short}_knee"),
        (f"{name}Foot", f"{name}Leg", (0.0, -b["shin"], 0.0), f"{short}_foot"),
        (f"{name}ToeBase", f"{name}Foot", _ANKLE_TO_BALL, None),
        (f"{name}ToeBase_End", f"{name}ToeBase", (0.0, 0.0, TOE_LENGTH_M), None),
    )


def _humanoid_arm(x: float) -> tuple:
    """One arm's rows, clavicle to hand (``x`` as in :func:`_humanoid_leg`)."""
    name, short = ("Right", "r") if x < 0 else ("Left", "l")
    b = _B
    return (
        (f"{name}Shoulder", "Spine1", (x * CLAVICLE_M, _HALF_TORSO, 0.0), None),
        (f"{name}Arm", f"{name}Shoulder", (x * (b["half_shoulder_width"] - CLAVICLE_M), 0.0, 0.0), f"{short}_shoulder"),
        (f"{name}ForeArm", f"{name}Arm", (x * b["upper_arm"], 0.0, 0.0), f"{short}_elbow"),
        (f"{name}Hand", f"{name}ForeArm", (x * b["forearm"], 0.0, 0.0), f"{short}_hand"),
        (f"{name}Hand_End", f"{name}Hand", (x * HAND_LENGTH_M, 0.0, 0.0), None),
    )


# Rows in depth-first order (as a BVH file lists them), legs first like the universal rig.
HUMANOID_NODES: tuple[tuple[str, str | None, tuple[float, float, float], str | None], ...] = (
    ("Hips", None, (0.0, 0.0, 0.0), "pelvis"),
    *_humanoid_leg(-1.0),
    *_humanoid_leg(1.0),
    ("Spine", "Hips", (0.0, 0.0, 0.0), "spine"),
    ("Spine1", "Spine", (0.0, _HALF_TORSO, 0.0), None),
    ("Neck", "Spine1", (0.0, _HALF_TORSO, 0.0), "neck"),
    ("Head", "Neck", (0.0, HEAD_BASE_M, 0.0), "head"),
    ("Head_End", "Head", (0.0, float(NOSE_OFFSET_M[1]) - HEAD_BASE_M, float(NOSE_OFFSET_M[2])), None),
    *_humanoid_arm(-1.0),
    *_humanoid_arm(1.0),
)
# The humanoid rig of BVH files: each hand's End Site replaced by its 15 finger joints (core.hand_rig)
HUMANOID_NODES_WITH_FINGERS: tuple[tuple[str, str | None, tuple[float, float, float], str | None], ...] = tuple(
    row for node in HUMANOID_NODES
    for row in (finger_nodes(str(node[1])[:-len("Hand")]) if node[0].endswith("Hand_End") else (node,)))
# The humanoid node at each universal keypoint (the nose is the head bone's end).
HUMANOID_NODE_OF_KEYPOINT = {
    "pelvis": "Hips", "neck": "Neck", "head": "Head_End",
    **{f"{s}_{part}": f"{n}{bone}" for s, n in (("r", "Right"), ("l", "Left")) for part, bone in (
        ("hip", "UpLeg"), ("knee", "Leg"), ("ankle", "Foot"), ("shoulder", "Arm"), ("elbow", "ForeArm"),
        ("wrist", "Hand"))},
}

HUMANOID_BONE_AXES: dict[str, tuple[str | None, str | None, str | None]] = {
    **{f"{n}UpLeg": ("hip_width", None, None) for n in ("Right", "Left")},
    **{f"{n}Leg": (None, "thigh", None) for n in ("Right", "Left")},
    **{f"{n}Foot": (None, "shank", None) for n in ("Right", "Left")},
    "Spine1": (None, "torso", None), "Neck": (None, "torso", None),
    "Head": (None, "neck_nose", None), "Head_End": (None, "neck_nose", "neck_nose"),
    **{f"{n}Shoulder": ("shoulder_width", "torso", None) for n in ("Right", "Left")},
    **{f"{n}Arm": ("shoulder_width", None, None) for n in ("Right", "Left")},
    **{f"{n}ForeArm": ("upper_arm", None, None) for n in ("Right", "Left")},
    **{f"{n}Hand": ("forearm", None, None) for n in ("Right", "Left")},
}

# How each rotation joint's global frame is found from keypoints: the bone it drives (primary,
# from→to keypoints) and a secondary direction fixing the twist, with their rest directions.
# Secondary "bend": the next bone's direction (limb plane), falling back on the parent frame.
_X, _Y, _Z = np.eye(3)
_FRAME_RULES = {
    "pelvis": (("r_hip", "l_hip"), _X, ("pelvis", "neck"), _Y),
    "spine": (("pelvis", "neck"), _Y, ("r_shoulder", "l_shoulder"), _X),
    "neck": (("neck", "head"), NOSE_OFFSET_M / np.linalg.norm(NOSE_OFFSET_M), ("r_shoulder", "l_shoulder"), _X),
    "r_hip": (("r_hip", "r_knee"), -_Y, ("r_knee", "r_ankle"), -_Z),
    "l_hip": (("l_hip", "l_knee"), -_Y, ("l_knee", "l_ankle"), -_Z),
    "r_shoulder": (("r_shoulder", "r_elbow"), -_X, ("r_elbow", "r_wrist"), _Z),
    "l_shoulder": (("l_shoulder", "l_elbow"), _X, ("l_elbow", "l_wrist"), _Z),
}
_LIMB_JOINTS = ("r_hip", "l_hip", "r_shoulder", "l_shoulder")
_HINGE_JOINTS = {"r_knee": ("r_knee", "r_ankle"), "l_knee": ("l_knee", "l_ankle"),
                 "r_elbow": ("r_elbow", "r_wrist"), "l_elbow": ("l_elbow", "l_wrist")}
FALLBACK_WEIGHT = 0.2  # weight of the parent-derived twist against the limb plane (see retarget)


def rest_positions_m() -> np.ndarray:
    """Keypoint positions ``[15, 3]`` of the rest pose (metres, pelvis at the origin)."""
    identity = np.zeros((1, N_RIG_JOINTS, 4))
    identity[..., 0] = 1.0
    return pose_from_rotations(identity, np.zeros((1, 3)))[0]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def swing_matrices(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotations ``[..., 3, 3]`` taking unit vectors ``a [..., 3]`` to unit vectors ``b [..., 3]``
    (broadcast); opposite vectors: a half turn about an axis perpendicular to ``a``."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    out = np.empty(a.shape + (3,))
    _swings_into(np.ascontiguousarray(a.reshape(-1, 3)), np.ascontiguousarray(b.reshape(-1, 3)),
                 out.reshape(-1, 3, 3))
    return out


@njit(cache=True)
def _swings_into(a, b, out) -> None:
    """``out [N, 3, 3]`` of :func:`swing_matrices` for ``a, b [N, 3]``: ``I + [v]× + [v]×² / (1 + c)``,
    ``v = a × b``, ``c = a · b``; for ``c < −1 + 1e-9`` the half turn ``2 p pᵀ − I`` about
    ``p = a × (x or y)``, normalised."""
    k = np.empty((3, 3))
    for n in range(a.shape[0]):
        x, y, z = a[n, 0], a[n, 1], a[n, 2]
        v0, v1, v2 = y * b[n, 2] - z * b[n, 1], z * b[n, 0] - x * b[n, 2], x * b[n, 1] - y * b[n, 0]
        c = x * b[n, 0] + y * b[n, 1] + z * b[n, 2]
        r = out[n]
        if c < -1 + 1e-9:
            p = np.array([0.0, z, -y]) if abs(x) < 0.9 else np.array([-z, 0.0, x])   # a × x, a × y
            p /= max(np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]), 1e-12)
            for i in range(3):
                for j in range(3):
                    r[i, j] = 2.0 * p[i] * p[j] - (1.0 if i == j else 0.0)
            continue
        k[0, 0], k[0, 1], k[0, 2] = 0.0, -v2, v1
        k[1, 0], k[1, 1], k[1, 2] = v2, 0.0, -v0
        k[2, 0], k[2, 1], k[2, 2] = -v1, v0, 0.0
        denominator = max(1.0 + c, 1e-12)
        for i in range(3):
            for j in range(3):
                square = k[i, 0] * k[0, j] + k[i, 1] * k[1, j] + k[i, 2] * k[2, j]
                r[i, j] = (1.0 if i == j else 0.0) + k[i, j] + square / denominator


def _point(points: np.ndarray, name: str) -> np.ndarray:
    return points[:, KP[name]]


def _direction(points: np.ndarray, pair: tuple[str, str]) -> np.ndarray:
    return _unit(_point(points, pair[1]) - _point(points, pair[0]))


def _global_rotations(points: np.ndarray) -> dict[str, np.ndarray]:
    """Global rotation ``[F, 3, 3]`` of each rotation joint (relative to the rest pose)."""
    glob: dict[str, np.ndarray] = {}
    for joint in ("pelvis", "spine", "neck"):
        prim_pair, prim_rest, sec_pair, sec_rest = _FRAME_RULES[joint]
        pose = frame_from_axes(_direction(points, prim_pair), _direction(points, sec_pair))
        glob[joint] = pose @ frame_from_axes(prim_rest, sec_rest).T
    for joint in _LIMB_JOINTS:
        prim_pair, prim_rest, sec_pair, sec_rest = _FRAME_RULES[joint]
        parent = glob["pelvis" if joint.endswith("hip") else "spine"]
        primary = _direction(points, prim_pair)
        # Twist from the limb plane (the next bone), blended with the parent's frame swung onto
        # the bone so that a straight limb keeps a defined, continuous twist.
        carried = swing_matrices(parent @ prim_rest, primary) @ parent @ sec_rest
        bend = _direction(points, sec_pair)
        secondary = _reject(bend, primary) + FALLBACK_WEIGHT * _unit(_reject(carried, primary))
        glob[joint] = frame_from_axes(primary, secondary) @ frame_from_axes(prim_rest, sec_rest).T
    for joint, pair in _HINGE_JOINTS.items():
        parent_name = RIG_NODES[NODE_NAMES.index(joint)][1]
        if parent_name is None:
            raise ValueError(f"the hinge joint {joint} has no parent in RIG_NODES")
        parent = glob[parent_name]
        rest_dir = _unit(NODE_OFFSETS_M[NODE_NAMES.index(pair[1])])
        glob[joint] = swing_matrices(parent @ rest_dir, _direction(points, pair)) @ parent
    return glob


def head_from_torso(points_m: np.ndarray) -> np.ndarray:
    """The head ``[F, 3]`` where the rest pose puts it on the torso (neck rotation = identity):
    for a head no camera saw. ``points_m [F, 15, 3]`` (metres, y up) needs pelvis, neck, shoulders."""
    prim_pair, prim_rest, sec_pair, sec_rest = _FRAME_RULES["spine"]
    spine = frame_from_axes(_direction(points_m, prim_pair), _direction(points_m, sec_pair)) \
        @ frame_from_axes(prim_rest, sec_rest).T
    return _point(points_m, "neck") + spine @ NOSE_OFFSET_M


def _reject(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return v - np.sum(v * axis, axis=-1, keepdims=True) * axis


def retarget(points_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Fit the universal skeleton to source keypoints.

    ``points_m [F, 15, 3]``: source keypoints (KEYPOINTS order, metres, y up). Returns local
    joint rotations ``[F, N_RIG_JOINTS, 4]`` (quaternions, RIG_JOINTS order) and the universal
    skeleton's keypoints ``[F, 15, 3]``: the pelvis where the source's is, every bone with its
    universal length along the source bone's direction (shoulders follow the torso rigidly).
    """
    glob = _global_rotations(points_m)
    g = np.stack([glob[j] for j in RIG_JOINTS], axis=1)               # [F, R, 3, 3]
    parents = [NODE_PARENTS[NODE_NAMES.index(j)] for j in RIG_JOINTS]
    local = g.copy()
    for r, p in enumerate(parents):
        if p >= 0:
            local[:, r] = np.swapaxes(g[:, RIG_JOINTS.index(NODE_NAMES[p])], -1, -2) @ g[:, r]
    quats = matrix_to_quat(local)
    return quats, pose_from_rotations(quats, _point(points_m, "pelvis"))


def pose_from_rotations(quats: np.ndarray, pelvis_m: np.ndarray, scale: float = 1.0,
                        offsets_m: np.ndarray | None = None) -> np.ndarray:
    """Universal keypoints ``[F, 15, 3]`` from local rotations ``[F, R, 4]`` and pelvis ``[F, 3]``;
    ``scale`` multiplies every bone (a subject's height / :data:`UNIVERSAL_HEIGHT_M`), ``offsets_m``
    (:func:`body_offsets_m`, default the universal body's) are the rest offsets at 1.75 m."""
    quats = np.ascontiguousarray(quats, dtype=np.float64).reshape(-1, N_RIG_JOINTS, 4)
    pelvis = np.ascontiguousarray(pelvis_m, dtype=np.float64).reshape(-1, 3)
    offsets = NODE_OFFSETS_M if offsets_m is None else np.ascontiguousarray(offsets_m, dtype=np.float64)
    return _rig_fk(quats, pelvis, float(scale), NODE_PARENTS, offsets, NODE_JOINT, NODE_OF_POINT)


@njit(cache=True)
def _rig_fk(quats, pelvis, scale, parents, offsets, node_joint, node_of_point):
    """Forward kinematics of the rig, frame by frame (numba: fast for one frame and for many)."""
    n_frames, n_nodes = quats.shape[0], parents.shape[0]
    out = np.empty((n_frames, node_of_point.shape[0], 3))
    g_rot = np.empty((n_nodes, 3, 3))
    g_pos = np.empty((n_nodes, 3))
    local = np.empty((3, 3))
    for f in range(n_frames):
        rig_globals_into(quats[f], pelvis[f], scale, parents, offsets, node_joint, local, g_rot, g_pos)
        for k in range(node_of_point.shape[0]):
            out[f, k] = g_pos[node_of_point[k]]
    return out


@njit(cache=True)
def rig_globals_into(quats, root_m, scale, parents, offsets, node_joint, local, g_rot, g_pos) -> None:
    """Global rotation ``g_rot [N, 3, 3]`` and position ``g_pos [N, 3]`` of every rig node of one pose.

    ``quats [R, 4]`` local rotations, ``root_m [3]`` the root's position, ``scale`` multiplies
    every bone (offsets in metres); ``local [3, 3]`` is scratch space.
    """
    for j in range(parents.shape[0]):
        if node_joint[j] >= 0:
            quat_to_matrix_into(quats[node_joint[j]], local)
        else:
            local[:] = 0.0
            local[0, 0] = local[1, 1] = local[2, 2] = 1.0
        p = parents[j]
        if p < 0:
            g_rot[j] = local
            g_pos[j] = root_m
            continue
        mat3_mul_into(g_rot[p], local, g_rot[j])
        for a in range(3):
            g_pos[j, a] = g_pos[p, a] + scale * (g_rot[p, a, 0] * offsets[j, 0] + g_rot[p, a, 1] * offsets[j, 1]
                                                 + g_rot[p, a, 2] * offsets[j, 2])


_JOINT_PARENT = np.array([-1 if p < 0 else RIG_JOINTS.index(NODE_NAMES[p]) for p in NODE_PARENTS[JOINT_NODE]])


def global_rotations(quats: np.ndarray) -> np.ndarray:
    """Global rotation matrices ``[F, R, 3, 3]`` (:data:`RIG_JOINTS` order; the root's frame) of local
    rotations ``[F, R, 4]``: each joint's parent's global rotation times its own local one."""
    quats = np.ascontiguousarray(quats, dtype=np.float64)
    out = np.empty(quats.shape[:-1] + (3, 3))
    _global_rotations_into(quats, _JOINT_PARENT, out)
    return out


@njit(cache=True)
def _global_rotations_into(quats, parents, out) -> None:
    """``out [F, R, 3, 3]`` of :func:`global_rotations` (numba: one call for one frame or many)."""
    local = np.empty((3, 3))
    for f in range(quats.shape[0]):
        for r in range(parents.shape[0]):
            if parents[r] < 0:
                quat_to_matrix_into(quats[f, r], out[f, r])
            else:
                quat_to_matrix_into(quats[f, r], local)
                mat3_mul_into(out[f, parents[r]], local, out[f, r])


_BONE_PAIRS = [[(KP[a], KP[b]) for a, b in pairs] for pairs in MEASURED_BONES.values()]


def bone_lengths_m(points_m: np.ndarray) -> np.ndarray:
    """Lengths ``[..., 8]`` (:data:`MEASURED_BONE_NAMES` order, metres) of keypoints ``[..., 15, 3]``;
    two-sided bones are the mean of left and right."""
    points_m = np.asarray(points_m, dtype=np.float64)
    return np.stack([np.mean([np.linalg.norm(points_m[..., b, :] - points_m[..., a, :], axis=-1)
                              for a, b in pairs], axis=0) for pairs in _BONE_PAIRS], axis=-1)


def universal_bone_lengths_m() -> np.ndarray:
    """The universal skeleton's :data:`MEASURED_BONE_NAMES` lengths ``[8]`` (metres, 1.75 m body)."""
    return bone_lengths_m(rest_positions_m())


def stature_m(lengths_m: np.ndarray) -> np.ndarray:
    """The standing height (metres) of bodies with bone lengths ``lengths_m [..., 8]``: 1.75 m × their
    ankle-to-nose chain (thigh + shank + torso + neck→nose) over the universal skeleton's."""
    return UNIVERSAL_HEIGHT_M * np.asarray(lengths_m)[..., _STATURE_CHAIN].sum(axis=-1) / _UNIVERSAL_CHAIN_M


def rig_offsets_m(offsets_m: np.ndarray, names: tuple[str, ...] | list[str],
                  bone_axes: dict[str, tuple[str | None, str | None, str | None]],
                  proportions_m: np.ndarray) -> np.ndarray:
    """Rest offsets ``[N, 3]`` of a rig (``offsets_m`` of the universal body, node ``names``) for a
    body with bone lengths ``proportions_m [8]`` at 1.75 m stature: each axis of a node's offset
    scaled by its bone (``bone_axes``) over the universal bone."""
    ratio = np.asarray(proportions_m, dtype=np.float64) / _UNIVERSAL_BONES_M
    factors = np.ones((len(names), 3))
    for i, name in enumerate(names):
        for axis, bone in enumerate(bone_axes.get(name, (None, None, None))):
            if bone is not None:
                factors[i, axis] = ratio[MEASURED_BONE_NAMES.index(bone)]
    return np.ascontiguousarray(offsets_m * factors)


def body_offsets_m(proportions_m: np.ndarray) -> np.ndarray:
    """The universal rig's rest offsets ``[N, 3]`` for a body with bone lengths ``proportions_m [8]``
    (:data:`MEASURED_BONE_NAMES` order, at 1.75 m stature); the universal lengths give
    :data:`NODE_OFFSETS_M`."""
    return rig_offsets_m(NODE_OFFSETS_M, NODE_NAMES, NODE_BONE_AXES, proportions_m)


_UNIVERSAL_BONES_M = universal_bone_lengths_m()
_STATURE_CHAIN = [MEASURED_BONE_NAMES.index(b) for b in ("thigh", "shank", "torso", "neck_nose")]
_UNIVERSAL_CHAIN_M = float(_UNIVERSAL_BONES_M[_STATURE_CHAIN].sum())
