"""The truth of the head, hands and feet: their global rotations from a held-out clip's own rig, and
the face, hand and foot points a detector would give, attached to them (``data_specs/evaluation_bodies.md``,
"Head, hands and feet").

The shared CMU clips are retargeted onto one Character Creator rig (``CC_Base_*`` joints), which
carries the head, the hands with their finger bases and the feet with their toes. Per frame each end
segment's frame is read off it in the humanoid rig's convention (x the subject's left, y up, z forwards
at rest; :data:`~mocapdb.core.skeleton.END_JOINTS` order):

* **head**: the rig's head bone frame, which is that convention already (its eyes lie 3.3 cm either
  side along x, 8.2 cm up and 8.2 cm forwards of the head joint);
* **hand**: along the hand from the wrist to the mid-point of the index and little-finger bases (the
  humanoid's hand bone: −x for the right hand, +x for the left), the index side forwards (+z), the
  back of the hand up (T-pose, palms down);
* **foot**: the ankle → toe base direction as on a flat foot (the rig's own slope of it, measured on
  the clip's frames where both the ankle and the toe base are at their lowest, turned up: a flat
  foot facing forwards is the identity), the foot bone's lateral axis as x.

The clip's frames are chosen exactly as :func:`mocapdb.core.clips.process_clip` and
:func:`mocapdb.evaluation.loso.sample_truths` choose them (longest continuous run, resampled, the
middle frames): the rotations line up with :attr:`~mocapdb.evaluation.heldout.Truth.source_m`.

The points (:func:`end_points`) are fixed layouts in those frames (:data:`FACE_M`, :data:`HAND_M`,
:data:`FOOT_M`: adult anthropometry, scaled with the body's stature), placed at the re-posed body's
nose, wrists and ankles, in :data:`~mocapdb.core.formats.keypoint_layouts.EXTREMITIES` order (the rows
BlazePose gives: heels, foot tips, index and little-finger knuckles, eyes, ears, mouth corners).
"""
from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from mocapdb.core.clips import continuous_runs
from mocapdb.core.formats.bvh import Bvh, forward_kinematics, read_bvh
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.geometry import frame_from_axes
from mocapdb.core.joint_map import detect_mapping, detect_unit, extract_keypoints, y_up_rotation
from mocapdb.core.motion_ops import resample
from mocapdb.core.skeleton import END_JOINTS, KP, UNIVERSAL_HEIGHT_M
from mocapdb.core.units import UNITS
from mocapdb.evaluation.loso import middle_frames
from mocapdb.runtime.mesh_head import HEAD_VERTICES, MESH_BREADTH_M, NOSE

SIDES = (("R", "r"), ("L", "l"))
FLAT_FOOT_M = 0.02   # a foot is flat where its ankle and toe base are both this close to their lowest
# Points of a 1.75 m adult in each end's frame (metres; x left, y up, z forwards). Face: origin between
# the ears (tragion); bitragion breadth about 14.5 cm, interpupillary distance about 6.2 cm, mouth width
# about 5.2 cm (Farkas' adult means, rounded); nose tip 11 cm ahead of the tragion and 2 cm below it.
FACE_M = {"nose": (0.0, -0.02, 0.11), "r_eye": (-0.031, 0.025, 0.08), "l_eye": (0.031, 0.025, 0.08),
          "r_ear": (-0.0725, 0.0, 0.0), "l_ear": (0.0725, 0.0, 0.0),
          "r_mouth": (-0.026, -0.06, 0.085), "l_mouth": (0.026, -0.06, 0.085)}
# Right hand from the wrist (the left mirrored in x): the index knuckle 8.5 cm along the hand and 2.5 cm
# to the index side, the little finger's 7.5 cm along and 2 cm to the other.
HAND_M = {"index": (-0.085, 0.0, 0.025), "pinky": (-0.075, 0.0, -0.02)}
# Either foot from the ankle: the heel point 3 cm below the ankle and 5.5 cm behind it, the foot's tip on
# its axis 21 cm further, 12 deg lower (the heel-to-toe length and slope a detector's points have on a
# standing foot: skeleton.HEEL_TO_TOE_M and HEEL_TO_TOE_SLOPE_DEG, from the balancing take)
_TIP = 0.21 * np.array([0.0, -np.sin(np.radians(12.0)), np.cos(np.radians(12.0))])
FOOT_M = {"heel": (0.0, -0.03, -0.055), "big_toe": tuple(np.array([0.0, -0.03, -0.055]) + _TIP)}


@dataclass(frozen=True)
class EndTruth:
    """A clip's end rotations ``[F, 5, 3, 3]`` (END_JOINTS order; the clip's y-up world, the frame of
    its ``source_m``): columns the end's x (left), y (up), z (forwards) axes."""

    name: str
    rotations: np.ndarray
    # [F, 2, 21, 3] the right then the left hand's 21 points (the hand landmark model's order: wrist, thumb
    # CMC-MCP-IP-tip, index, middle, ring, pinky MCP-PIP-DIP-tip) in the hand's own frame (metres of a
    # 1.75 m adult: the rig's hand scaled so the index knuckle is as far from the wrist as in HAND_M)
    hand_points_m: np.ndarray | None = None


def _cc(name: str) -> str:
    return f"CC_Base_{name}"


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def frame_from(forward: np.ndarray, left: np.ndarray) -> np.ndarray:
    """``[..., 3, 3]`` right-handed frames with z along ``forward [..., 3]`` and x along ``left`` made
    perpendicular to it (columns x, y, z)."""
    return frame_from_axes(forward, left)[..., [1, 2, 0]]   # columns (z, x, z × x = y) reordered


def _hand_frames(positions: np.ndarray, names: list[str], side: str) -> np.ndarray:
    """``[F, 3, 3]`` one hand's frames from the rig's joint positions ``[F, K, 3]``."""
    wrist, index, pinky = (positions[:, names.index(_cc(f"{side}_{j}"))] for j in ("Hand", "Index1", "Pinky1"))
    along = _unit(0.5 * (index + pinky) - wrist)
    index_side = index - pinky
    x = -along if side == "R" else along
    return frame_from(np.cross(x, np.cross(index_side, x)), x)


def _foot_frames(positions: np.ndarray, rotations: np.ndarray, names: list[str], side: str,
                 metres: float) -> np.ndarray:
    """``[F, 3, 3]`` one foot's frames: ankle → toe base turned up by its slope on the clip's flat frames."""
    ankle, ball = (positions[:, names.index(_cc(f"{side}_{j}"))] for j in ("Foot", "ToeBase"))
    left = -rotations[:, names.index(_cc(f"{side}_Foot")), :, 0]          # the rig's foot x is the subject's right
    step = _unit(ball - ankle)
    heights = np.stack([ankle[:, 1], ball[:, 1]]) * metres
    flat = (heights - heights.min(axis=1, keepdims=True) <= FLAT_FOOT_M).all(axis=0)
    slope = float(np.median(np.arcsin(np.clip(-step[flat, 1], -1.0, 1.0)))) if flat.any() else 0.0
    down = frame_from(step, left)                                          # z along ankle → toe base
    c, s = np.cos(slope), np.sin(slope)
    turn_up = np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])     # the sloping z back to level
    return down @ turn_up


def end_frames_of(bvh: Bvh, up: np.ndarray, metres: float) -> np.ndarray:
    """``[F, 5, 3, 3]`` the end frames (module docstring) of every frame of a CC_Base rig ``bvh`` whose
    axes ``up`` turns to y up (:func:`~mocapdb.core.joint_map.y_up_rotation`), ``metres`` a file unit."""
    names = [_cc(f"{s}_{j}") for s, _ in SIDES for j in ("Foot", "ToeBase", "Hand", "Index1", "Pinky1")]
    names.append(_cc("Head"))
    missing = [n for n in names if n not in bvh.names]
    if missing:
        raise ValueError(f"{bvh.source}: no {', '.join(missing)}: the end truth reads Character Creator rigs")
    positions, rotations = forward_kinematics(bvh, [bvh.index(n) for n in names])
    positions, rotations = positions @ up.T, up @ rotations
    feet = [_foot_frames(positions, rotations, names, s, metres) for s, _ in SIDES]
    hands = [_hand_frames(positions, names, s) for s, _ in SIDES]
    return np.stack(feet + hands + [rotations[:, -1]], axis=1)


FINGER_BONES = ("Thumb", "Index", "Mid", "Ring", "Pinky")   # the CC rig's, in core.fingers.FINGERS order
# The distal bone's length as a share of the one before it (hand_rig.PHALANX_SHARES: the thumb's distal /
# proximal phalanx, the fingers' distal / middle): the CC rig's last finger joints end in zero-length sites
TIP_SHARES = (0.158 / 0.196, 0.097 / 0.143, 0.108 / 0.170, 0.107 / 0.165, 0.093 / 0.117)


def hand_points_of(bvh: Bvh, up: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """``[F, 2, 21, 3]`` each hand's 21 points (:class:`EndTruth`, file units) of a CC_Base rig ``bvh`` in the
    hand frames ``frames [F, 5, 3, 3]`` (:func:`end_frames_of`; ``up`` as there). Each fingertip continues its
    last joint's bone (that joint's rest offset, turned by it) by :data:`TIP_SHARES`."""
    hands = []
    for h, (side, _) in enumerate(SIDES):
        chains = [[_cc(f"{side}_{bone}{k}") for k in (1, 2, 3)] for bone in FINGER_BONES]
        names = [_cc(f"{side}_Hand")] + [n for chain in chains for n in chain]
        positions, rotations = forward_kinematics(bvh, [bvh.index(n) for n in names])
        joints = positions[:, 1:].reshape(len(positions), 5, 3, 3)
        last = rotations[:, 3::3]                                                  # [F, 5, 3, 3] each finger's 3rd
        offsets = np.array([bvh.offsets[bvh.index(chain[2])] for chain in chains]) * np.array(TIP_SHARES)[:, None]
        tips = joints[:, :, 2] + np.einsum("gfij,fj->gfi", last, offsets)
        points = np.concatenate([positions[:, :1], np.concatenate([joints, tips[:, :, None]], axis=2)
                                .reshape(len(positions), 20, 3)], axis=1) @ up.T
        local = np.einsum("fji,fkj->fki", frames[:, 2 + h], points - points[:, :1])
        hands.append(local)
    out = np.stack(hands, axis=1)
    index_length = np.median(np.linalg.norm(out[:, :, 5], axis=-1))
    return out * (np.linalg.norm(HAND_M["index"]) / index_length)


def orthonormal(m: np.ndarray) -> np.ndarray:
    """The nearest rotations ``[..., 3, 3]`` to matrices ``m`` (polar decomposition)."""
    u, _, vt = np.linalg.svd(m)
    return u @ vt


def load_end_truth(path: Path, fps: float, max_frames: int) -> EndTruth:
    """A clip's end rotations at ``fps`` Hz over the frames ``sample_truths`` takes of it (module docstring)."""
    bvh = read_bvh(path)
    mapping = detect_mapping(bvh)
    runs = continuous_runs(extract_keypoints(bvh, mapping), bvh.fps)
    if not runs:
        raise ValueError(f"{path}: no continuous run")
    run = max(runs, key=lambda r: r.stop - r.start)
    up = y_up_rotation(bvh, mapping)
    frames = end_frames_of(bvh, up, UNITS[detect_unit(bvh, mapping)])
    hands = resample(hand_points_of(bvh, up, frames)[run], bvh.fps, fps)
    resampled = orthonormal(resample(frames[run], bvh.fps, fps))
    kept = middle_frames(len(resampled), max_frames)
    return EndTruth(path.stem, resampled[kept], hands[kept])


def _layout(points: Mapping[str, tuple[float, ...]], mirror: bool) -> np.ndarray:
    out = np.array(list(points.values()))
    return out * [-1.0, 1.0, 1.0] if mirror else out


def end_points(positions_m: np.ndarray, rotations: np.ndarray, stature_m: float) -> np.ndarray:
    """``[F, 14, 3]`` the EXTREMITIES points (world, metres) of a body ``positions_m [F, 15, 3]`` whose
    ends turn by ``rotations [F, 5, 3, 3]`` (:class:`EndTruth`), its layouts scaled to ``stature_m``."""
    s = stature_m / UNIVERSAL_HEIGHT_M
    out = np.full((len(positions_m), len(EXTREMITIES), 3), np.nan)
    head = END_JOINTS.index("head")
    face = _layout(FACE_M, False) * s
    placed = positions_m[:, KP["head"], None] + np.einsum("fij,kj->fki", rotations[:, head], face - face[0])
    for k, name in enumerate(list(FACE_M)[1:], start=1):
        out[:, EXTREMITIES.index(name)] = placed[:, k]
    for side, short in SIDES:
        mirror = side == "L"
        for end, anchor, points, rows in ((f"{short}_hand", f"{short}_wrist", HAND_M, ("index", "pinky")),
                                          (f"{short}_foot", f"{short}_ankle", FOOT_M, ("heel", "big_toe"))):
            local = _layout(points, mirror) * s
            world = positions_m[:, KP[anchor], None] + np.einsum("fij,kj->fki", rotations[:, END_JOINTS.index(end)],
                                                                 local)
            for k, row in enumerate(rows):
                out[:, EXTREMITIES.index(f"{short}_{row}")] = world[:, k]
    return out


@cache
def face_shape() -> np.ndarray:
    """``[N_HEAD, 3]`` a real face's rigid head vertices (``runtime/mesh_head.HEAD_VERTICES``) in the head
    frame, in units of its breadth: ``face_shape.json`` (the face landmark model's mesh of
    ``data/sample_faces/sergey.jpg``)."""
    stored = json.loads((Path(__file__).parent / "face_shape.json").read_text())
    if tuple(stored["vertices"]) != HEAD_VERTICES:
        raise ValueError("face_shape.json was made for other head vertices than mesh_head.HEAD_VERTICES")
    return np.array(stored["shape"])


def face_mesh_points(positions_m: np.ndarray, rotations: np.ndarray, stature_m: float) -> np.ndarray:
    """``[F, N_HEAD, 3]`` the face mesh's head vertices (world, metres) of a body ``positions_m [F, 15, 3]``
    whose head turns by ``rotations [F, 5, 3, 3]`` (:class:`EndTruth`): :func:`face_shape` at the mesh's
    breadth for ``stature_m``, its nose tip at the body's nose, its frame the head's."""
    shape = face_shape() * MESH_BREADTH_M * stature_m / UNIVERSAL_HEIGHT_M
    head = rotations[:, END_JOINTS.index("head")]
    return positions_m[:, KP["head"], None] + np.einsum("fij,kj->fki", head, shape - shape[NOSE])
