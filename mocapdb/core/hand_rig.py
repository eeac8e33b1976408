"""The humanoid rig's fingers: 15 joints per hand under Mixamo's names, their rest offsets from hand
anthropometry, the axes each finger bends and spreads about, their limits and the relaxed pose.

Each finger's three joints (Mixamo's ``…Hand<Finger>1..3``: the thumb's CMC, MCP and IP joints; the other
fingers' MCP, PIP and DIP joints) hang from the hand (``LeftHand``/``RightHand``), each finger ending
in an End Site (``…3_End``, at the fingertip). Rest pose: Mixamo's T-pose hand, palm down, the four
fingers straight along the hand (the forearm's direction), the thumb straight, out towards the front
and a little down. Offsets are given in the **hand basis** ``(u, t, n)``: ``u`` along the hand
(wrist → the index and pinky knuckles' midpoint), ``t`` across it towards the thumb (pinky → index
knuckle) and ``n`` out of the palm (palmar). In the rig (T-pose, facing +z) ``u`` is ±x (the hand's
side), ``t`` is +z and ``n`` is −y on both hands: :func:`hand_basis`.

Lengths, for a 1.75 m body (the BVH scales them with the body): the hand's length (wrist crease to the
middle fingertip) 0.108 × stature (Drillis & Contini 1966, "Body segment parameters", NYU report
1166-03: 18.9 cm); the bones as shares of it (Buchholz, Armstrong & Goldstein 1992, "Anthropometric
data for describing the kinematics of the human hand", Ergonomics 35(3):261–273, Table 2). The knuckles
lie where the middle finger's phalanges leave the rest of the hand's length, the others back by their
metacarpals' ratio to the middle's; their spread across the palm, the thumb's CMC joint and the
thumb's rest direction are this rig's round figures (the knuckle centres 1.7 cm apart).
Contract: ``data_specs/skeleton.md``, "Fingers".
"""
from __future__ import annotations

import numpy as np

FINGER_NAMES = ("Thumb", "Index", "Middle", "Ring", "Pinky")      # Mixamo's, in core.fingers.FINGERS order
SIDE_NAMES = ("Right", "Left")                                    # finger rows: the right hand's 15 first
HAND_LENGTH_OF_STATURE = 0.108                                    # Drillis & Contini 1966
WRIST_TO_FINGERTIP_M = HAND_LENGTH_OF_STATURE * 1.75              # of the 1.75 m universal body: 0.189 m
# Buchholz et al. 1992, Table 2: metacarpal and the three phalanges (thumb: metacarpal, proximal, distal)
# as shares of the hand's length
METACARPAL_SHARE = np.array([0.251, 0.374, 0.373, 0.336, 0.295])
PHALANX_SHARES = np.array([[0.251, 0.196, 0.158],     # thumb: CMC → MCP (its metacarpal), → IP, → tip
                           [0.265, 0.143, 0.097],     # index: MCP → PIP, → DIP, → tip
                           [0.277, 0.170, 0.108],     # middle
                           [0.259, 0.165, 0.107],     # ring
                           [0.206, 0.117, 0.093]])    # pinky
_MIDDLE_KNUCKLE_SHARE = 1.0 - PHALANX_SHARES[2].sum()               # 0.445 of the hand's length
KNUCKLE_ACROSS_M = np.array([0.020, 0.026, 0.008, -0.009, -0.026])  # along t: the thumb's CMC, the four MCPs
THUMB_CMC_UN_M = (0.025, 0.010)                                      # the thumb's CMC along u and n
# Rest directions (hand basis): the fingers along the hand; the thumb 40° towards t, 12° palmar
_THUMB_REST = np.array([np.cos(np.radians(40.0)), np.sin(np.radians(40.0)), np.tan(np.radians(12.0))])
REST_DIRECTIONS = np.vstack([_THUMB_REST / np.linalg.norm(_THUMB_REST), np.tile([1.0, 0.0, 0.0], (4, 1))])


def _orthonormal(vectors: np.ndarray) -> np.ndarray:
    """Gram-Schmidt on the rows of ``vectors [..., 3, 3]``: the first kept, each next made perpendicular."""
    out = np.array(vectors, dtype=np.float64)
    for k in range(3):
        for j in range(k):
            out[..., k, :] -= np.sum(out[..., k, :] * out[..., j, :], axis=-1, keepdims=True) * out[..., j, :]
        out[..., k, :] /= np.linalg.norm(out[..., k, :], axis=-1, keepdims=True)
    return out


# Per finger (hand basis): its rest direction r, the direction a flexion turns it towards (p: the palm; the
# thumb across it, towards the little finger) and the one a spread turns it towards (s: the thumb's side)
_THUMB_AXES = _orthonormal(np.array([REST_DIRECTIONS[0], [0.0, -1.0, 1.0], [0.0, 1.0, 0.0]]))
FINGER_AXES = np.stack([_THUMB_AXES] + [np.eye(3)[[0, 2, 1]]] * 4)   # [5, 3 (r, p, s), 3]
# Each finger's angles (degrees): its first bone's spread (towards s), flexion (towards p) and twist about
# itself, then the flexion of its second and third bones
ANGLES = ("spread", "flex1", "twist", "flex2", "flex3")
# Limits (degrees; negative flexion: extension). Thumb (AAOS ranges and margin): CMC spread and flexion, the
# metacarpal's twist (opposition turns it; the fingers have none), MCP, IP; fingers: MCP spread and flexion,
# PIP, DIP (AAOS: MCP 90, PIP 100, DIP 90)
ANGLE_LIMITS_DEG = np.array([
    [[-20.0, 40.0], [-20.0, 50.0], [-30.0, 60.0], [-10.0, 60.0], [-15.0, 80.0]],
    *[[[-25.0, 25.0], [-30.0, 90.0], [0.0, 0.0], [-5.0, 110.0], [-10.0, 90.0]]] * 4])
# A relaxed hand (our choice: a slight curl, more towards the little finger), in :data:`ANGLES` order
RELAXED_DEG = np.array([[0.0, 5.0, 0.0, 10.0, 10.0], [0.0, 10.0, 0.0, 15.0, 10.0], [0.0, 12.0, 0.0, 18.0, 10.0],
                        [0.0, 14.0, 0.0, 20.0, 10.0], [0.0, 16.0, 0.0, 22.0, 10.0]])


def finger_joint_names(side: str) -> list[str]:
    """The 15 finger joints of one hand (``side``: "Right" or "Left"), thumb first, each finger's 1..3."""
    return [f"{side}Hand{finger}{k}" for finger in FINGER_NAMES for k in (1, 2, 3)]


FINGER_JOINTS: tuple[str, ...] = tuple(n for side in SIDE_NAMES for n in finger_joint_names(side))   # [30]


def hand_basis(side: str) -> np.ndarray:
    """``[3, 3]`` the rig's hand basis of ``side`` ("Right", "Left"): columns ``u, t, n`` (rig axes; left-handed
    on the right hand, so one set of angles means the mirror-image pose on the two hands)."""
    along = -1.0 if side == "Right" else 1.0
    return np.array([[along, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]).T


NodeRow = tuple[str, str, tuple[float, float, float], str | None]   # name, parent, offset (m), joint it turns with


def finger_nodes(side: str) -> tuple[NodeRow, ...]:
    """One hand's finger rows (name, parent, rest offset in metres, the finger joint it turns with, or
    None), depth first as :data:`~mocapdb.core.skeleton.HUMANOID_NODES`' rows."""
    basis = hand_basis(side)
    rows: list[NodeRow] = []
    for f, finger in enumerate(FINGER_NAMES):
        if f == 0:
            base_utn = np.array([THUMB_CMC_UN_M[0], KNUCKLE_ACROSS_M[0], THUMB_CMC_UN_M[1]])
        else:
            along = _MIDDLE_KNUCKLE_SHARE * METACARPAL_SHARE[f] / METACARPAL_SHARE[2] * WRIST_TO_FINGERTIP_M
            base_utn = np.array([along, KNUCKLE_ACROSS_M[f], 0.0])
        steps = [base_utn] + [share * WRIST_TO_FINGERTIP_M * REST_DIRECTIONS[f] for share in PHALANX_SHARES[f]]
        parent = f"{side}Hand"
        for k, step in enumerate(steps):
            name = f"{side}Hand{finger}{k + 1}" if k < 3 else f"{parent}_End"
            x, y, z = (float(v) for v in basis @ step)
            rows.append((name, parent, (x, y, z), name if k < 3 else None))
            parent = name
    return tuple(rows)
