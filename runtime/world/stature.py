"""A person's stature, on a log scale: the prior, an observation's likelihood, the posterior.

The prior is :mod:`mocapdb.core.anthropometry`'s mixture of adults and children of 2-17 years, or
one narrow component about a height the user gave (``--subject-height``). An observed stature (the
floor-consistent one of :mod:`mocapdb.runtime.world.fuse`) is blurred by its error and weighed under a
track's three kinds: **on the floor** (:data:`P_ON_FLOOR`: drawn from the prior), **elevated**
(:data:`P_ELEVATED`: the prior's probability of a person at least :data:`ELEVATED_MIN_LOG` smaller,
times a flat density over :data:`HUMAN_STATURE_M`) and **unreliable** (:data:`P_UNRELIABLE`: the
flat density). ``data_specs/world.md`` gives the decisions and their reasons.
"""
from __future__ import annotations

import numpy as np
from scipy.special import ndtr

from mocapdb.core.anthropometry import STATURE_LOG_MEANS, STATURE_LOG_SDS, STATURE_WEIGHTS

HUMAN_STATURE_M = (0.8, 2.3)  # no track is ever made smaller or taller (a 2-year-old to the tallest adults)
P_ON_FLOOR, P_ELEVATED, P_UNRELIABLE = 0.88, 0.10, 0.02  # prior weights of a track's kinds
ELEVATED_MIN_LOG = 0.1  # an elevated person's floor-consistent stature overstates it by this (log) at least:
#                         a step of 15 cm under a camera 1.5 m high
GIVEN_STATURE_SD = 0.01  # of log stature, a height the user gave
FLAT_DENSITY = 1.0 / np.log(HUMAN_STATURE_M[1] / HUMAN_STATURE_M[0])  # a flat density over the human range (log)
_STATURE_GRID = np.linspace(np.log(HUMAN_STATURE_M[0]), np.log(HUMAN_STATURE_M[1]), 400)


def likelihood_table(sd: float, prior: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """``log p`` of an observed log stature of error ``sd`` under a track's three kinds (module
    docstring) and its stature ``prior`` (:func:`stature_prior`), over :data:`_LIKELIHOOD_GRID`."""
    on_floor, smaller = prior_density(_LIKELIHOOD_GRID, sd, prior)
    return np.log(P_ON_FLOOR * on_floor + P_ELEVATED * FLAT_DENSITY * smaller + P_UNRELIABLE * FLAT_DENSITY)


def log_likelihood(log_stature: np.ndarray, table: np.ndarray) -> np.ndarray:
    """``log p(observed log stature)`` of one track (its :func:`likelihood_table`, interpolated); the
    unreliable kind's alone where the floor is not below it (NaN)."""
    values = np.interp(np.nan_to_num(log_stature, nan=_LIKELIHOOD_GRID[0]), _LIKELIHOOD_GRID, table)
    return np.where(np.isnan(log_stature), np.log(P_UNRELIABLE * FLAT_DENSITY), values)


_LIKELIHOOD_GRID = np.arange(np.log(0.02), np.log(100.0), 0.002)  # log stature (metres)


def prior_density(x: np.ndarray, sd: float, prior: tuple[np.ndarray, np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """The stature prior (or the given height) blurred by ``sd`` at log statures ``x``, and its
    probability of a stature below ``x`` by :data:`ELEVATED_MIN_LOG` at least (an elevated person
    is smaller than its floor says: it stands on a step or more)."""
    weights, means, sds = prior
    total = np.sqrt(sds ** 2 + sd ** 2)
    z = (x[..., None] - means) / total
    density = np.sum(weights * np.exp(-0.5 * z ** 2) / (total * np.sqrt(2.0 * np.pi)), axis=-1)
    return density, np.sum(weights * ndtr(z - ELEVATED_MIN_LOG / total), axis=-1)


def stature_prior(given_stature_m: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The stature prior's mixture (weights, log means, log SDs), or the given height's one component."""
    if given_stature_m is None:
        return STATURE_WEIGHTS, STATURE_LOG_MEANS, STATURE_LOG_SDS
    return np.ones(1), np.array([np.log(given_stature_m)]), np.array([GIVEN_STATURE_SD])


def _posterior(observed: float, sd: float, prior: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """The stature posterior on :data:`_STATURE_GRID` (normalised): the ``prior`` (weights, log means,
    log SDs) times the observation ``N(observed, sd)`` (log stature)."""
    weights, means, sds = prior
    x = _STATURE_GRID[:, None]
    density = np.sum(weights * np.exp(-0.5 * ((x - means) / sds) ** 2) / sds, axis=1)  # the prior's, on the grid
    posterior = density * np.exp(-0.5 * ((_STATURE_GRID - observed) / sd) ** 2)
    posterior = posterior if np.any(posterior > 0) else density
    return posterior / posterior.sum()


def posterior_sd(observed: float, sd: float, prior: tuple[np.ndarray, np.ndarray, np.ndarray]) -> float:
    """The SD of log stature of :func:`_posterior`."""
    posterior = _posterior(observed, sd, prior)
    mean = float(np.sum(posterior * _STATURE_GRID))
    return float(np.sqrt(np.sum(posterior * (_STATURE_GRID - mean) ** 2)))


def prior_mode(prior: tuple[np.ndarray, np.ndarray, np.ndarray]) -> float:
    """The stature (metres) a ``prior`` makes most likely."""
    return float(np.exp(_STATURE_GRID[np.argmax(_posterior(0.0, 1e6, prior))]))


PRIOR_SD = posterior_sd(0.0, 1e6, stature_prior(None))  # the prior's own spread (of log stature)
