"""One world per take: the floor, the camera's height and pitch, and every person's size.

One camera fixes each person only up to a scale ``k`` about its centre (a small person near it
makes the image of a tall one further away). The whole-take fit of a track
(:func:`~mocapdb.runtime.take.fit_take`) places its planted ankles at the track's *nominal* size
(the stream's: 1.75 m, or a given height). A floor ``n · p = −h`` (``n`` the world's up in the view
frame, ``h`` the camera's height above the floor) under those contacts fixes ``k = h / d(n)``,
``d(n)`` the floor's distance below the camera under them at the nominal size. So every track
standing on the floor observes its stature as ``log S = log h + log(S₀ / d(n))``: the floor ties
everyone's sizes together, and the camera height, when given, fixes them all.

:func:`estimate_world` searches grids of the camera's pitch and roll (about the tracks' mean up)
and ``log h`` (or ``h`` given). Each track is one of three kinds (Bayesian model comparison):

* **on the floor** (prior weight :data:`P_ON_FLOOR`): its observed stature is drawn from the stature
  prior (:mod:`mocapdb.core.anthropometry`: adults and children of 2-17 years), blurred by the
  observation's error (:func:`observation_sd`); a person whose height is given (``--subject-height``)
  has that instead of the prior;
* **elevated** (:data:`P_ELEVATED`): it stands on something (a box, a step, a roof), so the
  floor-consistent stature overstates it by :data:`ELEVATED_MIN_LOG` at least: the prior's
  probability of a person that much smaller times a flat density over the human range;
* **unreliable** (:data:`P_UNRELIABLE`): contacts that tell nothing (a body cut by the image edge, a
  false detection): the flat density.

The cost sums each track's ``−log`` mixture (weighted by its length up to 1 s:
:func:`evidence_weight`), the flatness of its contacts under each floor (:func:`_unevenness`), its
image's verticals on the roll (:mod:`mocapdb.runtime.world.image_vertical`), the tilt prior
(:func:`~mocapdb.runtime.world.tilt.tilt_cost`: the bodies' own up estimates with a heavy tail) and
the camera height's (:func:`~mocapdb.runtime.world.tilt.height_cost`: how high people film from),
and the room's vertical vanishing point where ``detect`` saw lines (``scene_prior``: each weighted
by its error, the grid centred between the people's up and the scene's). Each piece of evidence
counts once: the contacts vote on the tilt through their flatness only, not also as the prior's
centre or width (a straight walk's contacts lie on a line that the depth's drift along the walk
tilts, 4° away from the camera). The grid's minimum is the world, its
spread (the tilts marginalised) the camera height's uncertainty. Each track on the floor then
takes its floor-consistent stature; any other the prior's mode (or its given height), standing in
the same world where its feet are (above the floor on a box), made smaller where its lowest points
would sink below the floor. No scale is negative, no stature leaves :data:`HUMAN_STATURE_M`.
``data_specs/world.md`` gives the decisions and their reasons. The stature prior and the kinds'
likelihoods are :mod:`mocapdb.runtime.world.stature`; what the summary and ``world.json`` say of the
world, :mod:`mocapdb.runtime.world.summary`. Costs O(T·H·P) for T tilts, H heights and P people (at
most :data:`MAX_FLOOR_POINTS` contacts and :data:`~mocapdb.runtime.world.image_vertical.MAX_PLANES`
image planes each): tens to hundreds of milliseconds per take, whatever its length (``tools/bench_world.py``).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import NamedTuple

import numpy as np

from mocapdb.core.motion_ops import scaled_about_origin
from mocapdb.core.outputs import TrackRecording
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, UNIVERSAL_HEIGHT_M
from mocapdb.runtime.foot_contacts import ANKLES, true_runs
from mocapdb.runtime.take import TakeResult, fit_take
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.world.contact_floor import above_floor, count_steps, lowest_level, spans_floor
from mocapdb.runtime.world.image_vertical import vertical_misfit, vertical_sd_deg
from mocapdb.runtime.world.scene_lines import SceneEvidence, SceneTilt, pitch_roll_deg
from mocapdb.runtime.world.scene_prior import grid_centre, scene_cost_of, scene_share, tilt_source
from mocapdb.runtime.world.stature import (
    FLAT_DENSITY,
    HUMAN_STATURE_M,
    P_ELEVATED,
    P_ON_FLOOR,
    P_UNRELIABLE,
    PRIOR_SD,
    likelihood_table,
    log_likelihood,
    posterior_sd,
    prior_density,
    prior_mode,
    stature_prior,
)
from mocapdb.runtime.world.subject import join_fragments
from mocapdb.runtime.world.tilt import (
    height_cost,
    height_spread_log,
    tilt_cost,
    tilt_prior_sds,
    tilt_spread_deg,
    tilted_normals,
    track_tilt_sd_deg,
)

CONTACT_SD = 0.10            # of log stature, one step's (depth and ankle-height noise), over its steps
BASE_SD = 0.03               # of log stature, what more contacts do not remove (the body's own fit)
TILT_RANGE_DEG = 20.0        # the grid's pitch and roll search about the tracks' mean up, each way
LOG_HEIGHT_STEP = 0.01       # the camera-height grid's step (log metres)
CAMERA_HEIGHT_RANGE_M = (0.1, 60.0)
MIN_FLOOR_DEPTH = 0.05       # a floor less than this × the person's stature below the camera: not under them
MIN_PLANES = 10             # frames seeing the whole body a track needs for its image vertical to count


@dataclass(frozen=True)
class TrackEvidence:
    """What one track tells about the world: its contacts ``[N, 3]`` (planted ankles, view frame,
    metres at its nominal stature ``nominal_stature_m``), its own up estimate and that one's error
    (degrees), its height if the user gave it, how much its likelihood counts (``weight``, 0-1:
    :func:`evidence_weight`) and its lower ankle in every frame ``[F, 3]`` (at the nominal size; where
    it has no contact, the floor must still not be above it), the image's vertical planes ``[N, 3]``
    and their error (degrees; :mod:`~mocapdb.runtime.world.image_vertical`; None: too few frames saw the
    whole body). Derived once: the contacts on its
    lowest level and all its contacts (each at most :data:`MAX_FLOOR_POINTS`, evenly spaced) and
    its log-likelihood table (:func:`log_likelihood`), and its number of steps (distinct contacts:
    the whole-take fit holds a planted ankle at one place for its whole contact)."""

    track: int
    nominal_stature_m: float
    contacts_m: np.ndarray
    up: np.ndarray
    up_sd_deg: float
    given_stature_m: float | None = None
    weight: float = 1.0
    lower_ankles_m: np.ndarray | None = None
    vertical_planes: np.ndarray | None = None
    vertical_sd_deg: float = float("nan")
    floor_points_m: np.ndarray = field(init=False, repr=False)
    contact_sample_m: np.ndarray = field(init=False, repr=False)
    steps: int = field(init=False, repr=False)
    likelihood: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        points = lowest_level(self.contacts_m, self.up) if len(self.contacts_m) else self.contacts_m
        object.__setattr__(self, "floor_points_m", points[::max(len(points) // MAX_FLOOR_POINTS, 1)])
        sample = self.contacts_m[::max(len(self.contacts_m) // MAX_FLOOR_POINTS, 1)]
        object.__setattr__(self, "contact_sample_m", sample)
        object.__setattr__(self, "steps", count_steps(self.contacts_m))
        object.__setattr__(self, "likelihood", likelihood_table(observation_sd(self), self.prior()))

    def prior(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """This track's stature prior (weights, log means, log SDs): its given height's, or the mixture."""
        return stature_prior(self.given_stature_m)


MAX_FLOOR_POINTS = 64  # contacts kept per track for the floor's distance under it (a median)


@dataclass(frozen=True)
class PersonSize:
    """One track in the world: its stature (metres) and that estimate's error (SD of its log: 0.05 ≈
    5 %), ``kind`` ("floor", "elevated", "unreliable", "no contacts"), where the size came from
    (``source``: "floor", "prior", "given"), the factor its nominal size was scaled by, and the height
    of its feet's lowest contacts above the floor (metres; None without contacts)."""

    track: int
    stature_m: float
    stature_log_sd: float
    kind: str
    source: str
    scale_factor: float
    feet_above_floor_m: float | None


@dataclass(frozen=True)
class World:
    """A take's world: the floor ``normal · p = −camera_height_m`` (view frame, metres), the camera
    height's error (SD of its log; 0 when given), every track's :class:`PersonSize` and the pitch's
    and roll's errors (degrees; NaN where no grid was searched)."""

    normal: np.ndarray
    camera_height_m: float
    camera_height_log_sd: float
    camera_height_given: bool
    people: dict[int, PersonSize] = field(default_factory=dict)
    pitch_sd_deg: float = float("nan")   # the pitch's and roll's errors (world_tilt.tilt_spread_deg)
    roll_sd_deg: float = float("nan")
    tilt_from: str = "people"            # what decided the tilt: "people", "scene", "people and scene"
    scene_share: float | None = None     # the scene's share of the tilt's precision (0-1; None: no scene)
    scene: SceneTilt | None = None       # the scene's own up, where its lines showed one

    @property
    def floor_known(self) -> bool:
        """Whether a floor was found (a planted foot somewhere) or given (the camera height)."""
        return self.camera_height_given or bool(np.isfinite(self.camera_height_log_sd))

    @property
    def pitch_deg(self) -> float:
        """The camera's pitch: positive looking down (the floor's normal leans towards the camera)."""
        return float(np.degrees(np.arctan2(self.normal[2], self.normal[1])))

    @property
    def roll_deg(self) -> float:
        """The camera's roll: positive when the world's up leans to the image's left."""
        return float(np.degrees(np.arctan2(-self.normal[0], self.normal[1])))


def fit_takes(recordings: list[TrackRecording], fps: float, params: TakeParams = TakeParams(),
              camera_height_m: float | None = None, subject_heights_m: dict[int | None, float] | None = None
              ) -> list[TrackRecording]:
    """Every track of a take through :func:`~mocapdb.runtime.take.fit_take`, then into one world
    (:func:`fit_world`): what ``reconstruct`` writes."""
    return fit_world(recordings, fps, params, camera_height_m, subject_heights_m)[0]


def fit_world(recordings: list[TrackRecording], fps: float, params: TakeParams = TakeParams(),
              camera_height_m: float | None = None, subject_heights_m: dict[int | None, float] | None = None,
              scene: SceneEvidence | None = None) -> tuple[list[TrackRecording], World]:
    """:func:`fit_takes` with the :class:`World` found. ``camera_height_m``: the camera's height above
    the floor when known; ``subject_heights_m``: track → stature (metres) where known (key None:
    everyone's); ``scene``: the up the room's lines show (:mod:`~mocapdb.runtime.world.scene_lines`)."""
    fits = [fit_take(rec, fps, params) for rec in recordings]
    heights = subject_heights_m or {}
    evidence = [track_evidence(rec, result, fps, heights.get(rec.track, heights.get(None))) for rec, result in fits]
    world = estimate_world(evidence, camera_height_m, scene)
    return [place_in_world(rec, world, fps) for rec, _ in fits], world


class TakeWorld(NamedTuple):
    """What :func:`fit_take_world` found: the input tracks with the fragments of one person joined,
    their whole-take fits placed in the world (same order), the world, and which track each joined
    one went into."""

    recordings: list[TrackRecording]
    fitted: list[TrackRecording]
    world: World
    joined: dict[int, int]


def fit_take_world(recordings: list[TrackRecording], fps: float, params: TakeParams = TakeParams(),
                   camera_height_m: float | None = None, subject_heights_m: dict[int | None, float] | None = None,
                   scene: SceneEvidence | None = None) -> TakeWorld:
    """What ``reconstruct`` and ``live`` fit at the end of a take: the fragments of one person joined
    (:func:`~mocapdb.runtime.world.subject.join_fragments`), then :func:`fit_world` over every track, static
    ones included (a person standing still shows the vertical and the floor as well as one who
    moves)."""
    joined_recordings, joined = join_fragments(recordings, fps)
    fitted, world = fit_world(joined_recordings, fps, params, camera_height_m, subject_heights_m, scene)
    return TakeWorld(joined_recordings, fitted, world, joined)


FULL_WEIGHT_S = 1.0  # a track this long or longer counts as one person's whole evidence


def evidence_weight(duration_s: float) -> float:
    """How much a track's likelihood counts: its share of :data:`FULL_WEIGHT_S` (at most 1). A
    fragment (a person lost and found again, a false detection for half a second) is not a second
    person: its vote on the world counts in proportion to its length."""
    return float(min(max(duration_s / FULL_WEIGHT_S, 0.0), 1.0))


def track_evidence(rec: TrackRecording, result: TakeResult, fps: float, given_stature_m: float | None = None
                   ) -> TrackEvidence:
    """A whole-take fit's :class:`TrackEvidence` (no contacts: an empty ``contacts_m``); ``fps``:
    the take's frame rate (Hz). Its up is the body's own (:attr:`TakeResult.body_up`), not the plane
    through its contacts: they vote through their flatness (:func:`_unevenness`), and its error the
    frames' over its strides (:func:`~mocapdb.runtime.world.tilt.track_tilt_sd_deg`); its image's
    verticals count from :data:`MIN_PLANES` frames."""
    footfalls = sum(len(true_runs(result.planted[:, foot])) for foot in range(result.planted.shape[1]))
    up, up_sd = result.body_up, track_tilt_sd_deg(result.body_up_sd_deg, footfalls)
    motion = rec.motion(fps)
    ankles = motion.joints_m()[:, list(ANKLES)]
    lower = ankles[np.arange(len(ankles)), np.argmin(ankles @ up, axis=1)]
    planes = result.vertical_planes
    if planes is not None and len(planes) < MIN_PLANES:
        planes = None
    planes_sd = float("nan") if planes is None else vertical_sd_deg(planes, up, len(rec) / fps)
    return TrackEvidence(rec.track, motion.height_m, result.planted_ankles_m.reshape(-1, 3), up, up_sd,
                         given_stature_m, evidence_weight(len(rec) / fps), lower[::max(len(lower) // 256, 1)],
                         planes, planes_sd)


def estimate_world(evidence: list[TrackEvidence], camera_height_m: float | None = None,
                   scene: SceneEvidence | None = None) -> World:
    """The take's :class:`World` from every track's evidence and the scene's lines (module docstring)."""
    grounded = [e for e in evidence if len(e.contacts_m) > 0]
    if not grounded:
        seen = None if scene is None else scene.tilt(_mean_up(evidence) if evidence else None)
        return _world_without_contacts(evidence, camera_height_m, seen)
    people_up, sds = _mean_up(grounded), tilt_prior_sds(_tilt_sd_deg(grounded))
    world = _grid_world(grounded, people_up, sds, camera_height_m, None if scene is None else scene.tilt(people_up))
    return _with_people(world, evidence)


def _grid_world(evidence: list[TrackEvidence], people_up: np.ndarray, tilt_sds_deg: tuple[float, float],
                camera_height_m: float | None, scene: SceneTilt | None) -> World:
    """The cost's minimum over camera tilts about the people's up ``people_up`` (pitch and roll SDs
    ``tilt_sds_deg``), or about its blend with the scene's (``scene_prior.grid_centre``), and log camera
    heights (one, when given): tilt grids ever finer about the last one's minimum
    (:data:`TILT_PASSES`), the first on every :data:`COARSE_HEIGHT_STRIDE`-th height, the others on
    every height within a window of the last minimum wide enough for the valley along which a
    height and a pitch trade. The height's and the tilt's spreads are the widest grid's, each
    marginalised over the other (a height traded against a pitch is as uncertain as that pitch).
    With a scene, the widest grid also tells how much of the tilt's precision is the scene's."""
    normal = people_up if scene is None else grid_centre(people_up, tilt_sds_deg, scene)
    shift = np.subtract(pitch_roll_deg(normal), pitch_roll_deg(people_up))   # the grid's centre about the people's up
    given = None if camera_height_m is None else np.array([np.log(camera_height_m)])
    tilt, log_h = np.zeros(2), _LOG_HEIGHTS[::COARSE_HEIGHT_STRIDE] if given is None else given
    tilt_sd, sd, share = (np.nan, np.nan), 0.0, None
    for n, (step, half_width, log_h_window) in enumerate(TILT_PASSES):
        offsets = np.arange(-half_width, half_width + 1e-9, step)
        tilts = tilt + np.stack(np.meshgrid(offsets, offsets, indexing="ij"), axis=-1).reshape(-1, 2)
        cost = _cost(evidence, normal, tilts, tilt_sds_deg, log_h, shift)
        scene_cost = np.zeros((len(tilts), 1)) if scene is None else scene_cost_of(scene, normal, tilts)
        if n == 0:   # the widest grid's spreads, each marginalised over the other
            tilt_sd, sd = tilt_spread_deg(tilts, cost + scene_cost, step), height_spread_log(log_h, cost + scene_cost)
            share = None if scene is None else scene_share(scene, tilt_spread_deg(tilts, cost, step))
        t, h = np.unravel_index(int(np.argmin(cost + scene_cost)), cost.shape)
        tilt = tilts[t]
        if given is None:
            log_h = _LOG_HEIGHTS[np.abs(_LOG_HEIGHTS - log_h[h]) <= log_h_window]
    best = tilted_normals(normal, tilt[None])
    log_h = _LOG_HEIGHTS if given is None else given
    cost = _cost(evidence, normal, tilt[None], tilt_sds_deg, log_h, shift)[0]
    return World(best[0], float(np.exp(log_h[np.argmin(cost)])), sd, given is not None,
                 pitch_sd_deg=tilt_sd[0], roll_sd_deg=tilt_sd[1], tilt_from=tilt_source(share), scene_share=share,
                 scene=scene)


def _cost(evidence: list[TrackEvidence], normal: np.ndarray, tilts_deg: np.ndarray,
          tilt_sds_deg: tuple[float, float], log_h: np.ndarray, shift_deg: np.ndarray) -> np.ndarray:
    """``−log`` posterior ``[T, H]`` over tilts ``[T, 2]`` (pitch, roll; degrees) about ``normal``
    and log camera heights ``log_h [H]``; the tilt prior is about the people's up, ``shift_deg``
    (pitch, roll) from ``normal``. The image's verticals (:mod:`~mocapdb.runtime.world.image_vertical`)
    see each tilt's roll only: a sideways lean of a person off the image's centre would otherwise
    move the pitch several times as far."""
    normals = tilted_normals(normal, tilts_deg)
    rolled = tilted_normals(normal, tilts_deg * [0.0, 1.0])   # the image's verticals vote on the roll alone
    cost = tilt_cost(tilts_deg + shift_deg, tilt_sds_deg)[:, None] + height_cost(log_h, _LOG_RANGE_WIDTH)[None, :]
    for e in evidence:
        cost -= e.weight * log_likelihood(_observed_log_stature(e, normals)[:, None] + log_h[None, :], e.likelihood)
        cost += e.weight * _unevenness(e, normals)[:, None]
        if e.vertical_planes is not None:
            cost += e.weight * vertical_misfit(e.vertical_planes, e.vertical_sd_deg, rolled)[:, None]
    return cost


FLATNESS_SD_M = 0.05  # a contact's height error about its floor, besides its depth's
DEPTH_SD_REL = 0.05   # a contact's depth error, relative (the per-frame depth from the body's image size)


def _unevenness(e: TrackEvidence, normals: np.ndarray) -> np.ndarray:
    """``−log`` likelihood ``[T]`` that a track's contacts lie level under each floor normal ``[T, 3]``:
    each contact's height about their median, a Cauchy error (a step or a platform costs little)
    whose scale is :data:`FLATNESS_SD_M` and its depth's error: that moves a contact along its
    viewing ray, so its height by :data:`DEPTH_SD_REL` × its height below the camera (under the
    track's own up: a scale that grew with the normal's tilt would favour tilted floors). Counted over
    its steps. A walk in depth fixes the floor's pitch, one across its roll. Only contacts spread
    over about a metre count: the depth's noise spreads a standing person's contacts along the
    viewing ray, and a plane containing that ray would fit them best."""
    if len(e.contact_sample_m) < 2 or not spans_floor(e.contacts_m):
        return np.zeros(len(normals))
    heights = e.contact_sample_m @ normals.T                                     # [P, T]
    scale = np.hypot(FLATNESS_SD_M, DEPTH_SD_REL * (e.contact_sample_m @ e.up))[:, None]  # one per contact
    residual = (heights - np.median(heights, axis=0)) / scale
    return np.log1p(0.5 * residual ** 2).mean(axis=0) * e.steps


# Each tilt grid's step and half width (degrees) and the log camera heights searched by the next one
# about this one's minimum: a pitch change of δ moves a person Z metres away by δ Z / h, up to ~0.4 in log.
TILT_PASSES = ((2.0, TILT_RANGE_DEG, 0.5), (0.5, 3.0, 0.15), (0.1, 0.75, 0.15))
COARSE_HEIGHT_STRIDE = 4  # the coarse pass takes every 4th height of the grid
_LOG_HEIGHTS = np.arange(np.log(CAMERA_HEIGHT_RANGE_M[0]), np.log(CAMERA_HEIGHT_RANGE_M[1]), LOG_HEIGHT_STEP)
_LOG_RANGE_WIDTH = float(np.log(CAMERA_HEIGHT_RANGE_M[1] / CAMERA_HEIGHT_RANGE_M[0]))


def _observed_log_stature(e: TrackEvidence, normals: np.ndarray) -> np.ndarray:
    """Per floor normal ``[T, 3]``, ``log(S₀ / d)``: the track's log stature on a floor 1 m below the
    camera (add ``log h``); NaN where that floor is not below its contacts."""
    ankle_m = ANKLE_HEIGHT_M * e.nominal_stature_m / UNIVERSAL_HEIGHT_M
    depth = ankle_m - np.median(e.floor_points_m @ normals.T, axis=0)  # the floor's, below the camera
    ok = depth > MIN_FLOOR_DEPTH * e.nominal_stature_m
    return np.where(ok, np.log(e.nominal_stature_m / np.where(ok, depth, 1.0)), np.nan)


def floor_stature_m(e: TrackEvidence, normal: np.ndarray, camera_height_m: float) -> float:
    """A track's floor-consistent stature (metres) on the floor ``normal · p = −camera_height_m``
    (view frame, unit normal): its contacts put on it; NaN where that floor is not below them."""
    return float(np.exp(_observed_log_stature(e, np.asarray(normal, dtype=np.float64)[None])[0]) * camera_height_m)


def observation_sd(e: TrackEvidence) -> float:
    """The error (SD of log stature) of a track's floor-consistent stature at a known floor:
    :data:`BASE_SD` and :data:`CONTACT_SD` over its steps."""
    return float(np.sqrt(BASE_SD ** 2 + CONTACT_SD ** 2 / max(e.steps, 1)))


def _with_people(world: World, evidence: list[TrackEvidence]) -> World:
    """``world`` with every track's :class:`PersonSize`."""
    return replace(world, people={e.track: person_size(e, world) for e in evidence})


def person_size(e: TrackEvidence, world: World) -> PersonSize:
    """One track's size and kind in ``world`` (the posterior over its kinds at the world's floor and
    height; on the floor: its floor-consistent stature; else the prior's mode or its given height)."""
    if len(e.contacts_m) == 0:
        return _prior_size(e, "no contacts", world)
    observed = np.log(floor_stature_m(e, world.normal, world.camera_height_m))
    sd = observation_sd(e)
    if np.isfinite(observed):
        on_floor, smaller = prior_density(np.array(observed), sd, e.prior())
        kinds = {"floor": P_ON_FLOOR * on_floor, "elevated": P_ELEVATED * FLAT_DENSITY * smaller,
                 "unreliable": P_UNRELIABLE * FLAT_DENSITY}
        kind = max(kinds, key=lambda k: float(kinds[k]))
    else:
        kind = "unreliable"
    if kind != "floor":
        return _prior_size(e, kind, world)
    stature = float(np.clip(np.exp(observed) if e.given_stature_m is None else e.given_stature_m, *HUMAN_STATURE_M))
    spread = float(np.sqrt(sd ** 2 + world.camera_height_log_sd ** 2 + _tilt_log_sd(e, world) ** 2))
    log_sd = posterior_sd(float(observed), spread, e.prior())
    source = "given" if e.given_stature_m is not None else "floor" if spread < PRIOR_SD else "prior"
    return PersonSize(e.track, stature, log_sd, "floor", source, stature / e.nominal_stature_m,
                      _feet_above_floor(e, world, stature / e.nominal_stature_m))


def _tilt_log_sd(e: TrackEvidence, world: World) -> float:
    """How far the world's tilt error moves a track's floor-consistent log stature: its change for 1°
    of pitch and of roll times their reported errors (0 where no tilt grid was searched). A pitch
    error δ moves the floor under a person ``Z`` metres away by ``δ Z``."""
    if not (np.isfinite(world.pitch_sd_deg) and np.isfinite(world.roll_sd_deg)):
        return 0.0
    at = _observed_log_stature(e, tilted_normals(world.normal, np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])))
    per_degree = np.nan_to_num(np.abs(at[1:] - at[0]), nan=0.0)
    return float(np.hypot(per_degree[0] * world.pitch_sd_deg, per_degree[1] * world.roll_sd_deg))


def _prior_size(e: TrackEvidence, kind: str, world: World | None) -> PersonSize:
    """A track whose size the floor does not give: the prior's mode (or its given height), made
    smaller where that would put its lowest point below the floor (never below the human range)."""
    stature, log_sd = prior_mode(e.prior()), posterior_sd(0.0, 1e6, e.prior())
    k = stature / e.nominal_stature_m
    if world is not None and world.floor_known and e.given_stature_m is None:
        touching = _touching_scale(e, world)
        if touching is not None and touching < k:
            k = max(touching, HUMAN_STATURE_M[0] / e.nominal_stature_m)
    feet = None if world is None or not world.floor_known else _feet_above_floor(e, world, k)
    return PersonSize(e.track, k * e.nominal_stature_m, log_sd, kind,
                      "given" if e.given_stature_m is not None else "prior", k, feet)


def _lowest_points(e: TrackEvidence, normal: np.ndarray) -> np.ndarray | None:
    """The points a track stands on (view frame, nominal size): its contacts on their lowest level,
    else its lower ankle in the frames where it is lowest (its 5th percentile), else None."""
    if len(e.contacts_m):
        return lowest_level(e.contacts_m, normal)
    if e.lower_ankles_m is None or not len(e.lower_ankles_m):
        return None
    heights = e.lower_ankles_m @ normal
    return e.lower_ankles_m[heights <= np.quantile(heights, 0.05)]


def _touching_scale(e: TrackEvidence, world: World) -> float | None:
    """The scale about the camera that puts the track's lowest points on the floor (None: they are
    not below the camera)."""
    points = _lowest_points(e, world.normal)
    if points is None:
        return None
    depth = ANKLE_HEIGHT_M * e.nominal_stature_m / UNIVERSAL_HEIGHT_M - float(np.median(points @ world.normal))
    return world.camera_height_m / depth if depth > MIN_FLOOR_DEPTH * e.nominal_stature_m else None


def _feet_above_floor(e: TrackEvidence, world: World, k: float) -> float | None:
    """How high the track's lowest points (:func:`_lowest_points`) stand above the floor once scaled
    by ``k`` (metres; None: no point known)."""
    points = _lowest_points(e, world.normal)
    if points is None:
        return None
    ankle_m = ANKLE_HEIGHT_M * k * e.nominal_stature_m / UNIVERSAL_HEIGHT_M
    return float(k * np.median(points @ world.normal) - ankle_m + world.camera_height_m)


def _world_without_contacts(evidence: list[TrackEvidence], camera_height_m: float | None,
                            scene: SceneTilt | None) -> World:
    """No track stood still: the scene's up (and its errors), else the people's; the given height or none."""
    up = _mean_up(evidence) if evidence else np.array([0.0, 1.0, 0.0])
    world = World(up, camera_height_m or np.nan, 0.0 if camera_height_m else np.inf, camera_height_m is not None)
    if scene is not None:
        world = replace(world, normal=scene.up, pitch_sd_deg=scene.pitch_sd_deg, roll_sd_deg=scene.roll_sd_deg,
                        tilt_from="scene", scene_share=1.0, scene=scene)
    return _with_people(world, evidence)


def _mean_up(evidence: list[TrackEvidence]) -> np.ndarray:
    """The tracks' up estimates averaged, each weighted by its inverse variance (as
    :func:`_tilt_sd_deg` combines their errors)."""
    total = np.sum([e.up / e.up_sd_deg ** 2 for e in evidence], axis=0)
    return total / np.linalg.norm(total)


def _tilt_sd_deg(evidence: list[TrackEvidence]) -> float:
    """The error (degrees) of the tracks' tilt estimates combined (inverse-variance)."""
    sds = np.array([e.up_sd_deg for e in evidence])
    return float(1.0 / np.sqrt(np.sum(1.0 / sds ** 2)))


def place_in_world(rec: TrackRecording, world: World, fps: float) -> TrackRecording:
    """A whole-take fit (at ``fps`` Hz) scaled about the camera by its :class:`PersonSize` factor
    (its image unchanged), on the world's floor, its root lifted where an ankle would sink below it
    (as the whole-take fit does on its own floor); where no floor was found, on its own, if any, scaled."""
    k = world.people[rec.track].scale_factor
    motion = scaled_about_origin(rec.motion(fps), k)
    if not world.floor_known:
        floor_offset_m = None if rec.floor_offset_m is None else k * rec.floor_offset_m
        return replace(rec.with_motion(motion), floor_offset_m=floor_offset_m)
    ankles = replace(motion, root_m=np.zeros_like(motion.root_m)).joints_m()[:, list(ANKLES)]
    lifted = above_floor(motion.root_m, ankles, world.normal, -world.camera_height_m, ANKLE_HEIGHT_M * motion.scale)
    return replace(rec.with_motion(replace(motion, root_m=lifted)), up_view=world.normal,
                   floor_offset_m=-world.camera_height_m)
