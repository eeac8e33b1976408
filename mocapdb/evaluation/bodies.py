"""Bodies of other proportions: a clip's own source joints re-posed on a sampled person's bones.

Every shared CMU clip lies on one body, whose proportions are the universal skeleton's; real
people differ from it by 8–15 % per bone. To test the engine on the bodies it will meet, a held-out
clip is rendered from its source skeleton's joints (``Clip.source_m``, before retargeting) with its
bones set to a sampled body (:func:`sample_body`, :func:`reshape_body`): every bone keeps the
source's direction in every frame, and only its length changes. The distribution is a decision
written down in ``data_specs/evaluation_bodies.md``:

* stature uniform in [1.50, 1.95] m;
* at a given stature, each :data:`~mocapdb.core.skeleton.MEASURED_BONE_NAMES` length varies by a
  log-normal factor around the source's own proportion, correlated as in people
  (:mod:`mocapdb.core.anthropometry`, the same distribution the runtime's body estimate takes as
  its prior).

Children (the whole-take world evaluation, :mod:`mocapdb.evaluation.world`): stature in
:data:`CHILD_HEIGHT_RANGE_M` and a child's proportions on top of a sampled body
(:func:`child_proportions`: shorter legs, a larger head, a longer trunk, relative to stature).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mocapdb.core.anthropometry import PROPORTION_COVARIANCE
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    KP,
    MEASURED_BONE_NAMES,
    PELVIS,
    bone_lengths_m,
    stature_m,
    universal_bone_lengths_m,
)

HEIGHT_RANGE_M = (1.50, 1.95)
CHILD_HEIGHT_RANGE_M = (1.0, 1.4)  # about 4-10 years old
# Sitting height / stature (data_specs/evaluation_bodies.md, "Children"): 55-56 % at 6-8.5 years,
# 52-53 % in adults; leg length is stature minus sitting height.
ADULT_SITTING_HEIGHT_RATIO = 0.525
CHILD_SITTING_HEIGHT_RATIO = 0.555
# Statures per head height: 7.5-8 in adults, about 6-7 at 4-10 years.
ADULT_HEADS_PER_STATURE = 7.75
CHILD_HEADS_PER_STATURE = 6.5
CHILD_LEG_FACTOR = (1.0 - CHILD_SITTING_HEIGHT_RATIO) / (1.0 - ADULT_SITTING_HEIGHT_RATIO)  # thigh, shank
CHILD_HEAD_FACTOR = ADULT_HEADS_PER_STATURE / CHILD_HEADS_PER_STATURE                      # neck→nose
_LEGS = [MEASURED_BONE_NAMES.index("thigh"), MEASURED_BONE_NAMES.index("shank")]
_TORSO = MEASURED_BONE_NAMES.index("torso")
_HEAD = MEASURED_BONE_NAMES.index("neck_nose")
UNIVERSAL_LEG_M = float(universal_bone_lengths_m()[_LEGS].sum())


@dataclass(frozen=True)
class Body:
    """A sampled person: stature (metres) and bone-length factors against the source's proportions."""

    height_m: float
    factors: np.ndarray  # [8] MEASURED_BONE_NAMES order, 1 = the source's proportion

    def bone_lengths_m(self, source_lengths_m: np.ndarray) -> np.ndarray:
        """This body's bone lengths ``[8]`` for a source whose mean lengths are ``source_lengths_m [8]``."""
        return source_lengths_m * (self.height_m / stature_m(source_lengths_m)) * self.factors


def sample_body(rng: np.random.Generator, height_range_m: tuple[float, float] = HEIGHT_RANGE_M) -> Body:
    """One body from the documented distribution (module docstring), its stature uniform in
    ``height_range_m`` (metres)."""
    height = float(rng.uniform(*height_range_m))
    return Body(height, np.exp(rng.multivariate_normal(np.zeros(len(MEASURED_BONE_NAMES)), PROPORTION_COVARIANCE)))


def child_proportions(lengths_m: np.ndarray) -> np.ndarray:
    """Bone lengths ``[8]`` (metres) made a child's at the same stature: thigh and shank times
    :data:`CHILD_LEG_FACTOR`, neck→nose times :data:`CHILD_HEAD_FACTOR`, and the torso longer by
    what they give up along the stature chain (``skeleton.stature_m`` unchanged); arms and widths
    keep their share of the stature."""
    source = np.asarray(lengths_m, dtype=np.float64)
    out = source.copy()
    out[_LEGS] *= CHILD_LEG_FACTOR
    out[_HEAD] *= CHILD_HEAD_FACTOR
    out[_TORSO] += source[_LEGS].sum() + source[_HEAD] - out[_LEGS].sum() - out[_HEAD]
    return out


# Bones from the pelvis outwards: (parent keypoint, child keypoint, MEASURED_BONE_NAMES entry, share of it).
_TREE = (
    ("pelvis", "r_hip", "hip_width", 0.5), ("pelvis", "l_hip", "hip_width", 0.5),
    ("r_hip", "r_knee", "thigh", 1.0), ("l_hip", "l_knee", "thigh", 1.0),
    ("r_knee", "r_ankle", "shank", 1.0), ("l_knee", "l_ankle", "shank", 1.0),
    ("pelvis", "neck", "torso", 1.0), ("neck", "head", "neck_nose", 1.0),
    ("neck", "r_shoulder", "shoulder_width", 0.5), ("neck", "l_shoulder", "shoulder_width", 0.5),
    ("r_shoulder", "r_elbow", "upper_arm", 1.0), ("l_shoulder", "l_elbow", "upper_arm", 1.0),
    ("r_elbow", "r_wrist", "forearm", 1.0), ("l_elbow", "l_wrist", "forearm", 1.0),
)


def reshape_body(source_m: np.ndarray, lengths_m: np.ndarray) -> np.ndarray:
    """Source joints ``[F, 15, 3]`` (metres, y up, floor at 0) re-posed with bone lengths
    ``lengths_m [8]``: each bone keeps its direction in every frame; the pelvis path is scaled by
    the ratio of leg lengths about the floor point under its mean (a longer leg takes longer
    strides and stands higher), and the lowest ankle is put ``ANKLE_HEIGHT_M`` × that leg's length
    over the universal leg above the floor."""
    source_m = np.asarray(source_m, dtype=np.float64)
    source_lengths = bone_lengths_m(source_m).mean(axis=0)
    leg_ratio = float(lengths_m[_LEGS].sum() / source_lengths[_LEGS].sum())
    out = np.empty_like(source_m)
    centre = source_m[:, PELVIS].mean(axis=0) * [1.0, 0.0, 1.0]
    out[:, PELVIS] = centre + leg_ratio * (source_m[:, PELVIS] - centre)
    for parent, child, bone, share in _TREE:
        a, b = KP[parent], KP[child]
        direction = source_m[:, b] - source_m[:, a]
        direction /= np.maximum(np.linalg.norm(direction, axis=-1, keepdims=True), 1e-12)
        out[:, b] = out[:, a] + direction * share * lengths_m[MEASURED_BONE_NAMES.index(bone)]
    lowest = out[:, [KP["r_ankle"], KP["l_ankle"]], 1].min()
    out[..., 1] += ANKLE_HEIGHT_M * float(lengths_m[_LEGS].sum()) / UNIVERSAL_LEG_M - lowest
    return out
