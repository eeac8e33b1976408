"""How people's bones vary at a given stature: the prior of every body estimate and the
distribution the evaluation samples bodies from (``data_specs/evaluation_bodies.md``).

Per :data:`~mocapdb.core.skeleton.MEASURED_BONE_NAMES` bone, ``log(length / (stature-scaled
reference length))`` is normal with standard deviation :data:`PROPORTION_SD` and correlations
:data:`PROPORTION_CORRELATION`: thigh and shank, upper arm and forearm go together, arms with legs,
hip with shoulder breadth; the torso goes against the legs (at one stature a longer trunk leaves
shorter legs). Left and right bones are one bone.
"""
from __future__ import annotations

import numpy as np

from mocapdb.core.skeleton import MEASURED_BONE_NAMES

STATURE_SD = 0.054  # of log(stature / 1.75 m): adults' heights vary by about 9.5 cm (1 SD)
PROPORTION_SD = {"thigh": 0.045, "shank": 0.045, "upper_arm": 0.045, "forearm": 0.05,
                 "hip_width": 0.07, "shoulder_width": 0.06, "torso": 0.04, "neck_nose": 0.07}
_PAIRS = {("thigh", "shank"): 0.6, ("upper_arm", "forearm"): 0.6,
          ("thigh", "upper_arm"): 0.4, ("thigh", "forearm"): 0.3, ("shank", "upper_arm"): 0.3,
          ("shank", "forearm"): 0.4, ("hip_width", "shoulder_width"): 0.5,
          ("torso", "thigh"): -0.5, ("torso", "shank"): -0.5}


def _correlation() -> np.ndarray:
    n = len(MEASURED_BONE_NAMES)
    corr = np.eye(n)
    for (a, b), rho in _PAIRS.items():
        i, j = MEASURED_BONE_NAMES.index(a), MEASURED_BONE_NAMES.index(b)
        corr[i, j] = corr[j, i] = rho
    return corr


PROPORTION_CORRELATION = _correlation()
PROPORTION_SD_ARRAY = np.array([PROPORTION_SD[name] for name in MEASURED_BONE_NAMES])
PROPORTION_COVARIANCE = PROPORTION_CORRELATION * np.outer(PROPORTION_SD_ARRAY, PROPORTION_SD_ARRAY)
