"""What a BVH joint's name says: its side (left or right) and the body part it is, from its words.

A name is cut into words at separators (``_ . : | - space``), at case changes (``UpperArm``,
``lShldr``), at digits (``Bip01``) and, for a word that is no word of :data:`VOCABULARY`,
into the fewest words of the vocabulary (``lhumerus`` → ``l humerus``,
``upperarm`` → ``upper arm``). A namespace (up to the last ``:`` or ``|``) is dropped first.
Rules and word lists: ``data_specs/joint_conventions.md``, "Recognition".
"""
from __future__ import annotations

import functools
import re
from dataclasses import dataclass

SIDE_WORDS = {"l": "l", "left": "l", "lf": "l", "lft": "l", "r": "r", "right": "r", "rt": "r", "rgt": "r"}
SIDE_NAMES = {"l": "left", "r": "right"}

# Word runs naming a role's part → (part, strength). A stronger word wins over a weaker one on
# the same chain (Mixamo's clavicle "LeftShoulder" above the upper arm "LeftArm").
PART_PHRASES: dict[tuple[str, ...], tuple[str, int]] = {
    **dict.fromkeys([("upper", "arm"), ("up", "arm"), ("arm",), ("humerus",), ("shldr",)], ("upperarm", 2)),
    ("shoulder",): ("upperarm", 1),
    **dict.fromkeys([("fore", "arm"), ("lower", "arm"), ("low", "arm"), ("lo", "arm"), ("radius",), ("ulna",),
                     ("elbow",)], ("forearm", 2)),
    **dict.fromkeys([("hand",), ("wrist",)], ("hand", 2)),
    **dict.fromkeys([("thigh",), ("up", "leg"), ("upper", "leg"), ("femur",)], ("thigh", 2)),
    ("hip",): ("thigh", 1),
    **dict.fromkeys([("shin",), ("calf",), ("lower", "leg"), ("low", "leg"), ("lo", "leg"), ("leg",), ("tibia",),
                     ("knee",)], ("shin", 2)),
    **dict.fromkeys([("foot",), ("ankle",)], ("foot", 2)),
    ("head",): ("head", 2),
}
# Word runs that make a joint no role even when it also carries a part's word.
NOT_A_ROLE_PHRASES = {("hip", "joint"), ("collar", "bone")}
NOT_A_ROLE_WORDS = frozenset((
    "twist roll share bend helper aux corrective ik fk pole target ctrl control null dummy locator socket "
    "attach prop weapon gun end nub top tip site finger fingers thumb index middle mid ring pinky little "
    "carpal metacarpal toe toes ball heel clavicle collar eye jaw tongue teeth brow lid lip cheek breast "
    "rib ribs").split())
# Other words a glued name may hold (they name no role but must be cut out: "lowerback", "toebase").
OTHER_WORDS = frozenset("spine chest neck pelvis hips root base waist back abdomen thorax bone joint "
                        "upper lower up low lo fore big".split())
VOCABULARY = frozenset(SIDE_WORDS) | {w for p in PART_PHRASES for w in p} | NOT_A_ROLE_WORDS | OTHER_WORDS
_LONGEST_PHRASE = max(len(p) for p in [*PART_PHRASES, *NOT_A_ROLE_PHRASES])
_LONGEST_WORD = max(len(w) for w in VOCABULARY)  # letters; bounds the cuts tried (time linear in a name)
_CASE_WORDS = re.compile(r"[A-Z]+(?=[A-Z][a-z])|[A-Z]?[a-z]+|[A-Z]+|\d+")


@dataclass(frozen=True)
class JointWords:
    """What one joint's name says: ``side`` ``"l"``/``"r"``/None, ``part`` (a role's part, e.g.
    ``"upperarm"``, ``"head"``) or None, its ``strength`` (0 without a part) and the words read."""

    words: tuple[str, ...]
    side: str | None
    part: str | None
    strength: int
    phrase: str  # the words that gave the part ("upper arm"), or why there is none

    def describe(self) -> str:
        """``left + "upper arm"`` style text for the evidence."""
        side = f"{SIDE_NAMES[self.side]} + " if self.side else ""
        return f'{side}"{self.phrase}"'


def split_words(name: str) -> tuple[str, ...]:
    """The lower-case words of a joint name, its namespace dropped (see the module docstring)."""
    bare = re.split(r"[:|]", name)[-1]
    words: list[str] = []
    for piece in re.split(r"[^A-Za-z0-9]+", bare):
        for word in _CASE_WORDS.findall(piece):
            words += _glued(word.lower())
    return tuple(w for w in words if not w.isdigit())


@functools.lru_cache(maxsize=4096)
def _glued(word: str) -> tuple[str, ...]:
    """``word`` cut into the fewest vocabulary words, or left whole when it is one or cannot be cut."""
    if word in VOCABULARY:
        return (word,)
    best: list[tuple[str, ...] | None] = [()] + [None] * len(word)
    for end in range(1, len(word) + 1):
        for start in range(max(end - _LONGEST_WORD, 0), end):
            head, current = best[start], best[end]
            if head is not None and word[start:end] in VOCABULARY and (
                    current is None or len(head) + 1 < len(current)):
                best[end] = (*head, word[start:end])
    return best[-1] or (word,)


def _phrases(words: tuple[str, ...]) -> list[tuple[str, ...]]:
    """The known word runs of ``words``, longest first at each place, left to right."""
    found, i = [], 0
    while i < len(words):
        for n in range(min(_LONGEST_PHRASE, len(words) - i), 0, -1):
            run = words[i:i + n]
            if run in PART_PHRASES or run in NOT_A_ROLE_PHRASES or (n == 1 and run[0] in NOT_A_ROLE_WORDS):
                found.append(run)
                i += n
                break
        else:
            i += 1
    return found


@functools.lru_cache(maxsize=4096)
def read_joint_name(name: str) -> JointWords:
    """The side and part a joint's name says (see the module docstring and the spec)."""
    words = split_words(name)
    sides = {SIDE_WORDS[w] for w in words if w in SIDE_WORDS}
    side = sides.pop() if len(sides) == 1 else None
    phrases = _phrases(words)
    blocking = [p for p in phrases if p not in PART_PHRASES]
    parts = {PART_PHRASES[p] for p in phrases if p in PART_PHRASES}
    if blocking:
        return JointWords(words, side, None, 0, f"not a role: \"{' '.join(blocking[0])}\"")
    if len(parts) != 1:
        why = "no part's word" if not parts else "words of several parts"
        return JointWords(words, side, None, 0, why)
    (part, strength), = parts
    phrase = " ".join(next(p for p in phrases if p in PART_PHRASES))
    return JointWords(words, side, part, strength, phrase)
