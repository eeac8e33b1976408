"""Find the humanoid in a BVH hierarchy: the joint of every role, from names, topology and poses.

Each joint's name is read for a side and a part (:mod:`mocapdb.core.rig_words`). Every limb is a
chain parent → descendant (upper arm → forearm → hand, thigh → shin → foot) of joints whose names
say its side and parts; among the chains that fit, the one with the strongest words wins, then
the one highest in the hierarchy (a wrist above a hand, a split bone's first half). The head is
the highest joint named as a head outside the limbs. Then the topology is checked (the legs meet
at a pelvis, the arms at a chest that does not hold the legs, the head hangs from the chest) and
the sides against the poses (left limbs on the character's left, given its facing from the
toes or the face, in frames of the clip: a rig's offsets alone need not be a pose). Nothing is
guessed: every doubt about a placement is a problem, named; the sides the names give stand
unless the poses clearly contradict them. Rules: ``data_specs/joint_conventions.md``,
"Recognition".
"""
from __future__ import annotations

import itertools
import re
from dataclasses import dataclass, field, replace

import numpy as np

from mocapdb.core.formats.bvh import Bvh, forward_kinematics
from mocapdb.core.rig_words import PART_PHRASES, SIDE_NAMES, JointWords, read_joint_name

ROLES: tuple[str, ...] = (
    "head", "r_upperarm", "r_forearm", "r_hand", "l_upperarm", "l_forearm", "l_hand",
    "r_thigh", "r_shin", "r_foot", "l_thigh", "l_shin", "l_foot")
# Each chain runs parent → descendant in the hierarchy; limbs first (the head is sought outside them).
LIMBS: tuple[tuple[str, ...], ...] = (
    ("r_upperarm", "r_forearm", "r_hand"), ("l_upperarm", "l_forearm", "l_hand"),
    ("r_thigh", "r_shin", "r_foot"), ("l_thigh", "l_shin", "l_foot"))
CHAINS: tuple[tuple[str, ...], ...] = (("head",), *LIMBS)
PART_TEXT = {"upperarm": "upper arm", "forearm": "forearm", "hand": "hand", "thigh": "thigh", "shin": "shin",
             "foot": "foot", "head": "head"}
MIN_SIDE_COSINE = 0.5    # left − right within 60° of the character's left (or of the other pair's): the
                         # poses agree with the names; within 60° of its right: they contradict them
MIN_FACING_SHARE = 0.25  # a facing cue's horizontal part, at least this share of its length
SIDE_FRAMES = 60         # frames (spread over the clip) in which the sides are checked
MAX_ROLE_CANDIDATES = 32  # joints whose names read as one role (real rigs: 1-3); more is refused, since the
                          # chain search pairs them (time up to its cube), and a joint map can name the joint


@dataclass
class RigReading:
    """The joint of each role found so far, why, and what stops the mapping (``problems``)."""

    placed: dict[str, int] = field(default_factory=dict)
    why: dict[str, str] = field(default_factory=dict)      # role → the evidence for its joint
    notes: list[str] = field(default_factory=list)         # structure and sides, as checked
    problems: list[str] = field(default_factory=list)


def is_ancestor(bvh: Bvh, a: int, b: int) -> bool:
    """Whether joint ``a`` is a proper ancestor of joint ``b`` (O(1): the rig's subtree bounds)."""
    rank, end = bvh.subtree_bounds
    return bool(rank[a] < rank[b] < end[a])


def rest_positions(bvh: Bvh) -> np.ndarray:
    """Joint positions ``[J, 3]`` (file units) with every rotation identity and every joint at its
    ``OFFSET`` (position channels zero, or equal to the OFFSET where they replace it)."""
    pos = np.zeros_like(bvh.offsets)
    for j, p in enumerate(bvh.parents):
        pos[j] = bvh.offsets[j] + (pos[p] if p >= 0 else 0.0)
    return pos


def _role_words(role: str) -> tuple[str | None, str]:
    """A role's side (None for the head) and part: ``"l_hand"`` → ``("l", "hand")``."""
    return (None, "head") if role == "head" else (role[0], role[2:])


def _role_text(role: str) -> str:
    side, part = _role_words(role)
    words = sorted(" ".join(p) for p, (q, _) in PART_PHRASES.items() if q == part)
    return f"{SIDE_NAMES[side] + ' ' if side else ''}{PART_TEXT[part]} ({', '.join(words)})"


def _candidates(words: list[JointWords], role: str, fixed: dict[str, int]) -> list[int]:
    if role in fixed:
        return [fixed[role]]
    side, part = _role_words(role)
    return [j for j, w in enumerate(words) if w.part == part and w.side == side]


def _bare(name: str) -> str:
    return re.split(r"[:|]", name)[-1].lower()


def _score(words: list[JointWords], combo: tuple[int, ...]) -> int:
    return sum(words[j].strength for j in combo)


def _above(bvh: Bvh, a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    """Every joint of placement ``a`` is the same as ``b``'s or above it."""
    return all(x == y or is_ancestor(bvh, x, y) for x, y in zip(a, b))


def _highest(bvh: Bvh, top: list[tuple[int, ...]]) -> tuple[int, ...] | None:
    """The placement of ``top`` above or equal to every other, joint by joint, or None: at each place
    the joint first in depth-first order is the only one that can be above all (time linear in ``top``)."""
    rank = bvh.subtree_bounds[0]
    first = tuple(min({c[i] for c in top}, key=lambda j: rank[j]) for i in range(len(top[0])))
    return first if first in top and all(_above(bvh, first, c) for c in top) else None


def _chain_placements(bvh: Bvh, options: list[list[int]]) -> list[tuple[int, ...]]:
    """Every pick of one joint per role from ``options`` that runs parent → descendant."""
    combos: list[tuple[int, ...]] = [(j,) for j in options[0]]
    for later in options[1:]:  # each joint a proper ancestor of the next
        combos = [c + (j,) for c in combos for j in later if is_ancestor(bvh, c[-1], j)]
    return combos


def _place_chain(bvh: Bvh, words: list[JointWords], chain: tuple[str, ...], fixed: dict[str, int],
                 reading: RigReading, allowed: set[int] | None = None) -> None:
    """Place ``chain`` (see the module docstring) into ``reading``, or add why it cannot be."""
    options = [[j for j in _candidates(words, r, fixed) if allowed is None or j in allowed] for r in chain]
    crowded = [f"{r}: {len(found)} joints' names read as a {_role_text(r)}; at most {MAX_ROLE_CANDIDATES} are "
               "compared" for r, found in zip(chain, options) if len(found) > MAX_ROLE_CANDIDATES]
    combos = [] if crowded else _chain_placements(bvh, options)
    if not combos:
        reading.problems += crowded or _explain_unplaced(bvh, chain, options)
        return
    best = max(_score(words, c) for c in combos)
    top = [c for c in combos if _score(words, c) == best]
    chosen = _highest(bvh, top)
    twins = [i for i in range(len(chain)) if len({_bare(bvh.names[c[i]]) for c in top}) < len({c[i] for c in top})]
    if chosen is None or twins:
        for i, role in enumerate(chain):
            names = sorted({bvh.names[c[i]] for c in top})
            if len(names) > 1:
                reading.problems.append(f"{role}: ambiguous, candidates {', '.join(names)}")
        return
    for i, role in enumerate(chain):
        j = chosen[i]
        reading.placed[role] = j
        reading.why[role] = "named by the joint map" if role in fixed else (
            words[j].describe() + _passed_over(bvh, words, [c[i] for c in combos], j))


def _passed_over(bvh: Bvh, words: list[JointWords], joints: list[int], chosen: int) -> str:
    """The other joints that could have taken the role, and why they did not."""
    others = sorted(set(joints) - {chosen})
    reasons = [f"{bvh.names[j]} ({'weaker word' if words[j].strength < words[chosen].strength else 'lower'})"
               for j in others]
    return f"; over {', '.join(reasons)}" if reasons else ""


def _explain_unplaced(bvh: Bvh, chain: tuple[str, ...], options: list[list[int]]) -> list[str]:
    missing = [f"{r}: no joint's name reads as a {_role_text(r)}" for r, found in zip(chain, options) if not found]
    if missing:
        return missing
    names = ["/".join(bvh.names[j] for j in found) for found in options]
    return [f"{' → '.join(chain)}: {', '.join(names)} are not a parent→descendant chain"]


def place_roles(bvh: Bvh, fixed: dict[str, int]) -> RigReading:
    """Every role's joint from the names and the hierarchy (``fixed`` roles given), with the
    evidence; ``problems`` lists each role that has no placement or several."""
    words = [read_joint_name(n) for n in bvh.names]
    reading = RigReading()
    for chain in LIMBS:
        _place_chain(bvh, words, chain, fixed, reading)
    tops = [reading.placed[c[0]] for c in LIMBS if c[0] in reading.placed]
    inside = np.zeros(len(bvh.names), dtype=bool)
    for top in tops:
        inside |= bvh.subtree(top)
    outside = set(np.flatnonzero(~inside).tolist())
    _place_chain(bvh, words, ("head",), fixed, reading, allowed=None if "head" in fixed else outside)
    return reading


def found_so_far(bvh: Bvh, reading: RigReading) -> str:
    """What was found, chain by chain, ``?`` where a role has no joint (for error messages)."""
    def joint(role: str) -> str:
        return bvh.names[reading.placed[role]] if role in reading.placed else "?"

    whats = ("head", "right arm", "left arm", "right leg", "left leg")
    return "; ".join(f"{what} {' → '.join(map(joint, chain))}" for chain, what in zip(CHAINS, whats))


def _common_ancestor(bvh: Bvh, a: int, b: int) -> int:
    """The lowest joint that is ``a`` or ``b`` or an ancestor of both."""
    above = {a}
    while a >= 0:
        a = int(bvh.parents[a])
        above.add(a)
    while b not in above:
        b = int(bvh.parents[b])
    return b


def check_structure(bvh: Bvh, placed: dict[str, int], reading: RigReading) -> None:
    """The limbs separate, the legs meeting at a pelvis and the arms at a chest that does not hold
    the legs, the head hanging from the chest: a note, or problems."""
    tops = {chain[0]: placed[chain[0]] for chain in CHAINS}
    for (role_a, a), (role_b, b) in itertools.permutations(tops.items(), 2):
        if role_a != "head" and (a == b or is_ancestor(bvh, a, b)):
            reading.problems.append(f"{role_b} ({bvh.names[b]}) lies inside the {role_a} chain ({bvh.names[a]}); "
                                    "the limbs must be separate chains, the head outside them")
    if reading.problems:
        return
    pelvis = _common_ancestor(bvh, placed["l_thigh"], placed["r_thigh"])
    chest = _common_ancestor(bvh, placed["l_upperarm"], placed["r_upperarm"])
    if is_ancestor(bvh, chest, pelvis):
        reading.problems.append(f"the legs meet at {bvh.names[pelvis]}, below where the arms meet "
                                f"({bvh.names[chest]}): not a humanoid's hierarchy")
    elif not is_ancestor(bvh, chest, placed["head"]):
        reading.problems.append(f"the head ({bvh.names[placed['head']]}) does not hang from the chest "
                                f"({bvh.names[chest]}, where the arms meet)")
    else:
        reading.notes.append(f"structure: legs meet at {bvh.names[pelvis]} (pelvis), arms at {bvh.names[chest]} "
                             f"(chest), the head {bvh.names[placed['head']]} hangs from the chest")


def _descendants(bvh: Bvh, joint: int) -> list[int]:
    below = bvh.subtree(joint)
    below[joint] = False
    return np.flatnonzero(below).tolist()


def _posed(bvh: Bvh) -> np.ndarray:
    """Joint positions ``[F, J, 3]`` (file units) in up to :data:`SIDE_FRAMES` frames spread over the clip."""
    frames = np.unique(np.linspace(0, bvh.n_frames - 1, min(SIDE_FRAMES, bvh.n_frames)).round().astype(int))
    return forward_kinematics(replace(bvh, motion=bvh.motion[frames]))[0]


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _facing(bvh: Bvh, pos: np.ndarray, placed: dict[str, int], up: np.ndarray) -> tuple[np.ndarray | None, str]:
    """The character's forward in each frame ``[F, 3]`` (NaN where unknown), from the toes (the feet's
    descendants) or else the face (the head's), and which; ``None`` when neither points clearly
    ahead in most frames."""
    for cue, roles in (("the toes", ("l_foot", "r_foot")), ("the face", ("head",))):
        below = [_descendants(bvh, placed[r]) for r in roles]
        if not all(below):
            continue
        steps = np.stack([pos[:, b].mean(axis=1) - pos[:, placed[r]] for r, b in zip(roles, below)])
        flat = steps - up * np.sum(steps * up, axis=-1, keepdims=True)
        clear = np.linalg.norm(flat, axis=-1) > MIN_FACING_SHARE * np.linalg.norm(steps, axis=-1)
        if clear.any(axis=0).mean() > 0.5:
            ahead = np.sum(np.where(clear[..., None], _unit(flat), 0.0), axis=0)
            return np.where(clear.any(axis=0)[:, None], _unit(ahead), np.nan), cue
    return None, ""


def _side_cosine(pos: np.ndarray, placed: dict[str, int], part: str, axis: np.ndarray) -> float:
    """Median over frames of the cosine between left − right ``part`` and ``axis`` ``[F, 3]``."""
    across = _unit(pos[:, placed[f"l_{part}"]] - pos[:, placed[f"r_{part}"]])
    return float(np.nanmedian(np.sum(across * _unit(axis), axis=-1)))


def _clip_up(pos: np.ndarray, placed: dict[str, int]) -> np.ndarray:
    """The clip's up ``[3]``: the median over frames of mid feet → mid upper arms. The legs keep it near
    the vertical when the trunk leans (each frame's hips → shoulders leans with the trunk and turns
    toes pointing down into the facing)."""
    top = pos[:, [placed["l_upperarm"], placed["r_upperarm"]]].mean(axis=1)
    feet = pos[:, [placed["l_foot"], placed["r_foot"]]].mean(axis=1)
    return _unit(np.median(_unit(top - feet), axis=0))


def _side_note(what: str, cosine: float) -> str:
    if cosine >= MIN_SIDE_COSINE:
        return f"left {what} on the character's left (cosine {cosine:.2f})"
    return f"left {what} from its name, the poses cannot tell (cosine {cosine:.2f})"


def _check_arms_against_legs(pos: np.ndarray, placed: dict[str, int], reading: RigReading) -> None:
    """With no facing: a problem when the left arm and the left leg lie clearly on opposite sides."""
    cosine = _side_cosine(pos, placed, "upperarm", pos[:, placed["l_thigh"]] - pos[:, placed["r_thigh"]])
    if cosine <= -MIN_SIDE_COSINE:
        reading.problems.append(f"the poses put the left arm and the left leg on opposite sides "
                                f"(cosine {cosine:.2f}): the names of one pair are swapped")
    else:
        checked = "so only checked that" if cosine >= MIN_SIDE_COSINE else "and the poses cannot tell whether"
        reading.notes.append(f"sides: from the names; no toes or face show the facing, {checked} the left arm "
                             f"and the left leg lie on the same side (cosine {cosine:.2f})")


def check_sides(bvh: Bvh, placed: dict[str, int], trusted: set[str], reading: RigReading) -> None:
    """Left limbs on the character's left in the clip's poses (pairs with a ``trusted`` top are not
    checked). The names placed every limb unambiguously, so they stand unless the poses clearly
    contradict them: a problem for a named left clearly on the right (cosine at most
    −:data:`MIN_SIDE_COSINE`), a note otherwise, saying where the poses cannot tell."""
    pairs = [p for p in ("upperarm", "thigh") if not {f"l_{p}", f"r_{p}"} & trusted]
    if not pairs:
        return
    pos = _posed(bvh)
    up = _clip_up(pos, placed)
    forward, cue = _facing(bvh, pos, placed, up)
    if forward is None:
        _check_arms_against_legs(pos, placed, reading)
        return
    what = {"upperarm": "arm", "thigh": "leg"}
    cosines = {p: _side_cosine(pos, placed, p, np.cross(up, forward)) for p in pairs}
    wrong = [f"the {what[p]} named left lies on the character's right (cosine {c:.2f})" for p, c in cosines.items()
             if c <= -MIN_SIDE_COSINE]
    if wrong:
        reading.problems.append(f"left and right do not match the poses (facing from {cue}): " + "; ".join(wrong))
    else:
        reading.notes.append(f"sides: facing from {cue}; " + ", ".join(_side_note(what[p], c)
                                                                      for p, c in cosines.items()))
