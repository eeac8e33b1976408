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


# Standing height over ages (``data_specs/world.md``, "Stature prior"): the prior every
# whole-take size estimate takes. Children 2-17 years: the 50th percentile of the CDC 2000 growth
# charts (stature-for-age, boys and girls) at each whole year, a log-SD of CHILD_STATURE_SD (their
# 5th-95th percentiles span about ±8 %); adults: the project's adult prior (1.75 m, STATURE_SD).
CHILD_STATURE_MEDIAN_M = {  # age (years): (boys, girls)
    2: (0.866, 0.852), 3: (0.953, 0.941), 4: (1.025, 1.016), 5: (1.092, 1.080), 6: (1.155, 1.150),
    7: (1.219, 1.210), 8: (1.280, 1.270), 9: (1.333, 1.330), 10: (1.384, 1.383), 11: (1.435, 1.448),
    12: (1.491, 1.515), 13: (1.562, 1.571), 14: (1.638, 1.604), 15: (1.701, 1.618), 16: (1.734, 1.625),
    17: (1.752, 1.629),
}
CHILD_STATURE_SD = 0.045  # of log stature at one age and sex
CHILD_SHARE = 0.25        # the prior's weight on children (2-17) against adults: a family or a school
ADULT_STATURE_M = 1.75    # the adult component's median (the universal skeleton's height)


def _stature_mixture() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stature prior as a Gaussian mixture in log stature: weights, means, SDs ``[C]``."""
    children = np.log([m for pair in CHILD_STATURE_MEDIAN_M.values() for m in pair])
    weights = np.concatenate([[1.0 - CHILD_SHARE], np.full(len(children), CHILD_SHARE / len(children))])
    means = np.concatenate([[np.log(ADULT_STATURE_M)], children])
    sds = np.concatenate([[STATURE_SD], np.full(len(children), CHILD_STATURE_SD)])
    return weights, means, sds


STATURE_WEIGHTS, STATURE_LOG_MEANS, STATURE_LOG_SDS = _stature_mixture()
