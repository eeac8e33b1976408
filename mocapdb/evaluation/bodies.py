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
_LEGS = [MEASURED_BONE_NAMES.index("thigh"), MEASURED_BONE_NAMES.index("shank")]
UNIVERSAL_LEG_M = float(universal_bone_lengths_m()[_LEGS].sum())


@dataclass(frozen=True)
class Body:
    """A sampled person: stature (metres) and bone-length factors against the source's proportions."""

    height_m: float
    factors: np.ndarray  # [8] MEASURED_BONE_NAMES order, 1 = the source's proportion

    def bone_lengths_m(self, source_lengths_m: np.ndarray) -> np.ndarray:
        """This body's bone lengths ``[8]`` for a source whose mean lengths are ``source_lengths_m [8]``."""
        return source_lengths_m * (self.height_m / stature_m(source_lengths_m)) * self.factors


def sample_body(rng: np.random.Generator) -> Body:
    """One body from the documented distribution (module docstring)."""
    height = float(rng.uniform(*HEIGHT_RANGE_M))
    return Body(height, np.exp(rng.multivariate_normal(np.zeros(len(MEASURED_BONE_NAMES)), PROPORTION_COVARIANCE)))


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
