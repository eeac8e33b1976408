"""The detector's own 3D as a second prior beside retrieval (issue 37, item 1): the retrieved
candidates re-ranked by how well their bones point where the detector's world landmarks point, and
the 2D fit pulled towards those directions.

BlazePose's world landmarks (``Person.world_m``: metres, hips-centred, x right and y down along the
image's axes, z away from the camera; ``data_specs/keypoint_formats.md``) are put in the view frame
(x right, y up, z towards the camera), turned from the image's axes onto the ray from the camera
through the hips (the model saw a crop along that ray): :func:`view_joints`.

**Re-ranking** (``EngineConfig.world_prior``): levelled by the track's tilt (the database's camera
looks level, :func:`level`), each candidate (a database frame at one of its yaws) costs
``Σ_b w_b (1 − cos(d_b, e_b)) / B`` over the ``B`` limb, girdle and trunk bones :data:`BONES`:
``d_b`` the candidate's bone direction turned by its yaw, ``e_b`` the world landmarks', ``w_b`` =
``world_prior`` × the smaller 2D confidence of the bone's ends × its agreement with the world
landmarks of the frame before (:func:`temporal_weights`: a bone that flips from one frame to the
next, as a left/right or front/back swap of the model does, counts little). The choice adds this
cost to its own (:meth:`~mocapdb.runtime.pose_pipeline.PosePipeline._choose`).

**The fit** (``RefineParams.world``): the bones :data:`FIT_BONES` (between two of the 14 keypoints)
in the view frame, with the same kind of weights, become the refinement's world term
(:class:`~mocapdb.runtime.refine.WorldBones`); the recording keeps them for the whole take's re-fit.
"""
from __future__ import annotations

import functools

import numpy as np
from numba import njit

from mocapdb.core.geometry import yaw_matrix
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import BONE_LENGTHS_M, KP
from mocapdb.runtime.world.body_size import TILT_SD_DEG

BONES = tuple((KP[a], KP[b]) for a, b in (
    ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"),
    ("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
    ("r_shoulder", "l_shoulder"), ("r_hip", "l_hip"), ("pelvis", "neck")))
_FROM, _TO = np.array([b[0] for b in BONES]), np.array([b[1] for b in BONES])
# The bones the 2D fit turns towards them: between two of the 14 keypoints (the fit's residuals are
# on keypoints): the limbs, the girdles and the trunk's sides.
FIT_BONES = BONES[:-1] + ((KP["r_hip"], KP["r_shoulder"]), (KP["l_hip"], KP["l_shoulder"]))
FIT_START, FIT_END = np.array([b[0] for b in FIT_BONES]), np.array([b[1] for b in FIT_BONES])
NO_FIT_BONES = np.zeros((len(FIT_BONES), 4))   # a frame's recorded world bones when it has none (weights 0)
VIEW_FROM_IMAGE_AXES = np.array([1.0, -1.0, -1.0])   # (x right, y down, z away) → view (y up, z towards)
Y_AXIS, Z_AXIS = np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
FLIP_COS = 0.5      # a bone turned by more than 60° since the frame before counts (almost) nothing


def unit(vectors: np.ndarray) -> np.ndarray:
    """``vectors [..., 3]`` normalised (NaN where zero or not finite)."""
    norm = np.linalg.norm(vectors, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(norm > 1e-9, vectors / norm, np.nan)


def database_bones(positions_m: np.ndarray) -> np.ndarray:
    """Every database frame's bone directions ``[F, B, 3]`` (unit, the database's upright frame,
    before any yaw) from its keypoints ``[F, 15, 3]``."""
    return unit(positions_m[:, _TO] - positions_m[:, _FROM]).astype(np.float32)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation ``[3, 3]`` taking the unit vector ``a`` to the unit vector ``b``: ``I + [v]× +
    [v]×² (1 − c) / |v|²``, ``v = a × b``, ``c = a · b`` (the identity where ``|v| < 1e-9``), written out in
    floats (a few times a frame per person: NumPy's calls on 3-vectors cost ten times the arithmetic)."""
    ax, ay, az = (float(v) for v in a)
    bx, by, bz = (float(v) for v in b)
    x, y, z = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    s2 = x * x + y * y + z * z
    if s2 < 1e-18:
        return np.eye(3)
    f = (1.0 - (ax * bx + ay * by + az * bz)) / s2
    return np.array([[1.0 - f * (y * y + z * z), -z + f * x * y, y + f * x * z],
                     [z + f * x * y, 1.0 - f * (x * x + z * z), -x + f * y * z],
                     [-y + f * x * z, x + f * y * z, 1.0 - f * (x * x + y * y)]])


def view_joints(world_m: np.ndarray, points_px: np.ndarray, confidence: np.ndarray, focal_px: float,
                center_px: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The world landmarks ``[14, 3]`` (image axes, hips-centred) as 15 joints ``[15, 3]`` in the view
    frame (the pelvis the hips' mid-point), turned onto the ray through the keypoints' hips, and their
    confidences ``[15]`` (the keypoints' ``confidence [14]``, 0: missing; the pelvis: the smaller
    hip's). ``points_px [14, 2]``; the camera's focal and principal point (px)."""
    joints = np.vstack([world_m, 0.5 * (world_m[KP["r_hip"]] + world_m[KP["l_hip"]])])
    conf = np.append(confidence, min(confidence[KP["r_hip"]], confidence[KP["l_hip"]]))
    hips = [k for k in (KP["r_hip"], KP["l_hip"]) if confidence[k] > 0]
    if hips:
        centre = points_px[hips].mean(axis=0)
        ray = np.array([(centre[0] - center_px[0]) / focal_px, (centre[1] - center_px[1]) / focal_px, 1.0])
        joints = joints @ rotation_between(Z_AXIS, ray / np.linalg.norm(ray)).T
    return joints * VIEW_FROM_IMAGE_AXES, conf


def bone_directions(joints: np.ndarray, conf: np.ndarray, bones: tuple[tuple[int, int], ...] = BONES
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Unit directions ``[B, 3]`` of ``bones`` (start, end among ``joints [15, 3]``, metres) and their
    confidences ``[B]`` (the smaller of the ends' ``conf``, its dtype); a missing direction (ends under
    1e-9 m apart, or not finite): 0 and 0. Four times a person-frame: a kernel (:func:`_bone_directions`)."""
    start, end = _bone_ends(bones)
    directions, weights = np.empty((len(start), 3)), np.empty(len(start), conf.dtype)
    _bone_directions(np.ascontiguousarray(joints, dtype=np.float64), np.ascontiguousarray(conf), start, end,
                     directions, weights)
    return directions, weights


@functools.cache
def _bone_ends(bones: tuple[tuple[int, int], ...]) -> tuple[np.ndarray, np.ndarray]:
    """The start and end joints ``[B]`` of ``bones``."""
    return np.array([b[0] for b in bones]), np.array([b[1] for b in bones])


@njit(cache=True, error_model="numpy")   # x / 0: inf or NaN, as NumPy
def _bone_directions(joints: np.ndarray, conf: np.ndarray, start: np.ndarray, end: np.ndarray,
                     directions: np.ndarray, weights: np.ndarray) -> None:
    """:func:`bone_directions` into ``directions [B, 3]`` and ``weights [B]``, as :func:`unit` computes it
    (the norm summed x, y, z in order, then divided)."""
    for b in range(len(start)):
        d = joints[end[b]] - joints[start[b]]
        norm = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        u = d / norm
        if norm > 1e-9 and np.isfinite(u[0]) and np.isfinite(u[1]) and np.isfinite(u[2]):
            directions[b] = u
            a, c = conf[start[b]], conf[end[b]]
            weights[b] = a if (c > a or np.isnan(a)) else c   # np.minimum's: NaN if either is
        else:
            directions[b] = 0.0
            weights[b] = 0.0


def level(joints: np.ndarray, up_view: np.ndarray) -> np.ndarray:
    """View-frame ``joints [..., 3]`` turned so the world's up as seen, ``up_view [3]``, points up."""
    return joints @ rotation_between(up_view / np.linalg.norm(up_view), Y_AXIS).T


def world_bones(world_m: np.ndarray, points_px: np.ndarray, confidence: np.ndarray, up_view: np.ndarray,
                focal_px: float, center_px: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The world landmarks' :data:`BONES` ``[B, 3]`` in the levelled view frame (module docstring) and
    their confidences ``[B]`` (:func:`view_joints`, :func:`level`, :func:`bone_directions`); the track's
    up ``up_view [3]`` (view frame)."""
    joints, conf = view_joints(world_m, points_px, confidence, focal_px, center_px)
    return bone_directions(level(joints, up_view), conf)


def temporal_weights(bones: np.ndarray, previous: np.ndarray | None) -> np.ndarray:
    """Per bone, how far this frame's world bone ``[B, 3]`` agrees with the frame before's (1: the
    same; falling to 0 as it turns past :data:`FLIP_COS`); all 1 without a frame before."""
    if previous is None:
        return np.ones(len(bones))
    cos = np.sum(bones * previous, axis=-1)
    return np.clip((cos - FLIP_COS) / (1.0 - FLIP_COS), 0.0, 1.0) ** 0.5


def weighted_bones(joints: np.ndarray, conf: np.ndarray, previous: np.ndarray | None,
                   bones: tuple[tuple[int, int], ...] = BONES) -> tuple[np.ndarray, np.ndarray]:
    """``bones``' directions ``[B, 3]`` among ``joints [15, 3]`` and their weights ``[B]``: the ends'
    confidence (``conf [15]``) × the agreement with the same bones of ``previous [15, 3]`` (the frame
    before's joints in the same frame, or None)."""
    directions, weights = bone_directions(joints, conf, bones)
    before = None if previous is None else bone_directions(previous, np.ones(len(previous)), bones)[0]
    return directions, weights * temporal_weights(directions, before)


def candidate_costs(db_bones: np.ndarray, frames: np.ndarray, yaws_deg: np.ndarray, bones: np.ndarray,
                    weights: np.ndarray) -> np.ndarray:
    """Each candidate's disagreement ``[N]`` with the world bones ``[B, 3]``, ``Σ_b w_b (1 − cos_b) / B``
    for the ``weights [B]``: database frames ``frames [N]`` turned by ``yaws_deg [N]``."""
    turned = np.einsum("nab,nkb->nka", yaw_matrix(yaws_deg), db_bones[frames].astype(np.float64))
    cos = np.nan_to_num(np.einsum("nka,ka->nk", turned, bones), nan=1.0)
    return ((1.0 - cos) @ weights) / len(weights)


# The body rebuilt from its recorded world bones at the universal lengths (:func:`body_joints`): the
# FIT_BONES' indices of the arms, legs, girdles and trunk sides.
_L = BONE_LENGTHS_M
_HIP_TO_SHOULDER_M = float(np.hypot(_L["torso"], _L["half_shoulder_width"] - _L["half_hip_width"]))
_HEAD_ABOVE_SHOULDERS_M = 0.25   # the head's centre above the shoulders' mid-point, along the trunk
LEGS, TRUNK_SIDES, HIP_GIRDLE = (4, 5, 6, 7), (10, 11), 9
# Whole-body mass fractions of the segments (Winter, "Biomechanics and Motor Control of Human
# Movement", table 4.1, after Dempster): trunk, head and neck, thigh, shank and foot, upper arm,
# forearm and hand (each limb's twice).
MASS_TRUNK, MASS_HEAD, MASS_THIGH, MASS_SHANK_FOOT, MASS_UPPER_ARM, MASS_FOREARM_HAND = (
    0.497, 0.081, 0.100, 0.061, 0.028, 0.022)
SUPPORT_BLEND_M = 0.05   # an ankle this much lower than the other carries all the weight; level ankles share it
MIN_VERTICAL_FRAMES = 10   # fewer frames with the legs and trunk seen: no estimate
VERTICAL_WINDOW_S = 2.0    # the stream's up: the median of the body's verticals over this many seconds
BALANCE_PASSES = 3         # the support chosen along the last estimate of the up, this many times


def body_joints(world_bones: np.ndarray) -> dict[str, np.ndarray]:
    """The body ``{name: [F, 3]}`` (pelvis at the origin, metres) rebuilt from recorded world bones
    ``[F, len(FIT_BONES), 4]`` (direction, weight) at the universal lengths: hips, knees, ankles,
    shoulders, elbows, wrists (``r_``/``l_``) and the head's centre. An unseen bone (direction 0)
    puts its end on its start."""
    d = world_bones[..., :3]
    j = {"r_hip": -_L["half_hip_width"] * d[:, HIP_GIRDLE], "l_hip": _L["half_hip_width"] * d[:, HIP_GIRDLE]}
    for side, thigh, shin, trunk, upper, fore in (("r", 4, 5, 10, 0, 1), ("l", 6, 7, 11, 2, 3)):
        j[f"{side}_knee"] = j[f"{side}_hip"] + _L["thigh"] * d[:, thigh]
        j[f"{side}_ankle"] = j[f"{side}_knee"] + _L["shin"] * d[:, shin]
        j[f"{side}_shoulder"] = j[f"{side}_hip"] + _HIP_TO_SHOULDER_M * d[:, trunk]
        j[f"{side}_elbow"] = j[f"{side}_shoulder"] + _L["upper_arm"] * d[:, upper]
        j[f"{side}_wrist"] = j[f"{side}_elbow"] + _L["forearm"] * d[:, fore]
    shoulders = 0.5 * (j["r_shoulder"] + j["l_shoulder"])
    j["head"] = shoulders + _HEAD_ABOVE_SHOULDERS_M * np.nan_to_num(unit(shoulders))
    return j


def centre_of_mass(j: dict[str, np.ndarray]) -> np.ndarray:
    """The whole body's centre of mass ``[F, 3]`` of :func:`body_joints`' ``j``: each segment's
    mass fraction at its mid-point (the trunk's at its four corners' mean; the foot with the shank,
    the hand with the forearm)."""
    trunk = 0.25 * (j["r_hip"] + j["l_hip"] + j["r_shoulder"] + j["l_shoulder"])
    com = MASS_TRUNK * trunk + MASS_HEAD * j["head"]
    for s in ("r", "l"):
        com = com + MASS_THIGH * 0.5 * (j[f"{s}_hip"] + j[f"{s}_knee"])
        com = com + MASS_SHANK_FOOT * 0.5 * (j[f"{s}_knee"] + j[f"{s}_ankle"])
        com = com + MASS_UPPER_ARM * 0.5 * (j[f"{s}_shoulder"] + j[f"{s}_elbow"])
        com = com + MASS_FOREARM_HAND * 0.5 * (j[f"{s}_elbow"] + j[f"{s}_wrist"])
    return com


def balance_verticals(world_bones: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Per frame of ``world_bones [F, len(FIT_BONES), 4]`` (direction, weight) that sees the legs and
    the trunk's sides, the unit direction ``[F', 3]`` from the support to the body's centre of mass:
    a body standing still keeps its centre of mass above what carries it (the lower ankle along
    ``up`` [3], the current estimate; both ankles, weighted, within :data:`SUPPORT_BLEND_M` of level),
    on one leg or two, leaning or not; walking averages it out over its steps."""
    j = body_joints(world_bones[_body_seen(world_bones)])
    return _support_to_mass(j, centre_of_mass(j), up)


def _body_seen(world_bones: np.ndarray) -> np.ndarray:
    """Which frames ``[F]`` of ``world_bones`` see the legs and the trunk's sides."""
    return np.asarray((world_bones[:, list(LEGS + TRUNK_SIDES), 3] > 0).all(axis=1))


def _support_to_mass(j: dict[str, np.ndarray], com: np.ndarray, up: np.ndarray) -> np.ndarray:
    """:func:`balance_verticals` of the rebuilt body ``j`` and its centre of mass ``com [F, 3]``; a
    degenerate frame (no direction) is left out."""
    verticals = unit(com - support_points(j, up))
    return verticals[np.isfinite(verticals).all(axis=1)]


def support_points(j: dict[str, np.ndarray], up: np.ndarray) -> np.ndarray:
    """What carries a body ``j`` (``{name: [F, 3]}``, metres) in each frame ``[F, 3]``: the lower ankle
    along ``up`` [3], both ankles weighted within :data:`SUPPORT_BLEND_M` of level."""
    right_lower = (j["l_ankle"] - j["r_ankle"]) @ up           # > 0: the right ankle is lower
    w = np.clip(0.5 + 0.5 * right_lower / SUPPORT_BLEND_M, 0.0, 1.0)[:, None]
    return w * j["r_ankle"] + (1.0 - w) * j["l_ankle"]


def body_vertical(world_bones: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The world's up as the detector's 3D shows it (view frame, unit) and its error (degrees), from a
    track's recorded world bones ``[F, len(FIT_BONES), 4]`` (direction, weight): the median of
    :func:`balance_verticals` over the frames that see the body, each frame's support chosen along
    the last estimate (first the mid-ankles → shoulders direction; :data:`BALANCE_PASSES` passes),
    the error their RMS angle about it, at least :data:`~mocapdb.runtime.world.body_size.TILT_SD_DEG`.
    None below :data:`MIN_VERTICAL_FRAMES` frames."""
    seen = _body_seen(world_bones)
    if seen.sum() < MIN_VERTICAL_FRAMES:
        return None
    j = body_joints(world_bones[seen])
    com = centre_of_mass(j)
    up = unit(np.median(unit(j["r_shoulder"] + j["l_shoulder"] - j["r_ankle"] - j["l_ankle"]), axis=0))
    for _ in range(BALANCE_PASSES):
        verticals = _support_to_mass(j, com, up)
        if len(verticals) < MIN_VERTICAL_FRAMES:
            return None
        up = unit(np.median(verticals, axis=0))
    spread = float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(verticals @ up, -1.0, 1.0)) ** 2))))
    return up, max(TILT_SD_DEG, spread)


def track_up(rec: TrackRecording) -> tuple[np.ndarray, float]:
    """A track's estimate of the world's up (view frame, unit) and its error (degrees): the body's
    vertical in the detector's 3D where the keypoints carry it (:func:`body_vertical`: the model
    sees the body's lean whatever the database holds), else the fit's tilt estimate
    (:class:`~mocapdb.runtime.world.body_size.CameraTilt`)."""
    bones = rec.column("world_bones")   # empty without the fits (no keep_take)
    vertical = body_vertical(bones) if len(bones) else None
    if vertical is not None:
        return vertical
    up = np.array([0.0, 1.0, 0.0]) if rec.up_view is None else np.asarray(rec.up_view, dtype=np.float64)
    return up / np.linalg.norm(up), TILT_SD_DEG if rec.up_sd_deg is None else rec.up_sd_deg
