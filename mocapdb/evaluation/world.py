"""`mocapdb eval --world`: several people in one camera's world, scored against the truth.

A **take** is a handful of held-out clips (``data_specs/evaluation_split.md``) rendered together by
one pinhole camera (:class:`WorldScenario`, :func:`build_take`):

* each person is a clip's source joints on a body of its own (:func:`body_lengths_m`): adults
  1.50-1.95 m, a child 1.0-1.4 m with a child's proportions
  (:func:`mocapdb.evaluation.bodies.child_proportions`, ``data_specs/evaluation_bodies.md``);
* placed on the floor plan (:class:`PersonSpec`: distance, lateral offset, heading), on a flat floor
  at y = 0 or, for the person on the box, standing on it (:data:`BOX_HEIGHT_M`: its soles there);
* walking (the middle :attr:`WorldConfig.frames` frames of a clip) or still (one frame of the clip
  with both feet down, held: the bystander and the person on the box);
* one camera per take, :data:`CAMERA_HEIGHT_RANGE_M` high (drawn per take), level or pitched down;
* rendered with detector-like noise (:func:`mocapdb.evaluation.heldout.render`: σ px, dropout,
  left/right swaps; keypoints outside the image unseen): every frame holds every person.

Each take runs through the engine (:class:`~mocapdb.runtime.engine.Engine`, ``keep_take``) and the
whole-take world (:func:`mocapdb.runtime.world.fit_takes`) twice: with the camera height given and
with nothing given. Tracks are matched to people by their 2D keypoints (:func:`match_tracks`).

Scores (:func:`score_take`): per person (its longest track) the stature error (% of the true
stature; engine stature = 1.75 m × the track's body scale), the root error (median over frames of
the pelvis distance, m, and of it as % of the true camera-to-pelvis distance), the floor error (the
fitted floor's camera height minus the true one, m; the angle between the fitted and the true
up, degrees); per track the plausibility flags (:func:`track_flags`); per take the error of
every pair of people's stature ratio (%). Summaries per scenario and camera-height mode, by role,
and the checks against issue 27's targets (:func:`check_lines`).
"""
from __future__ import annotations

import logging
import time
from dataclasses import asdict, dataclass, field, replace
from itertools import combinations
from pathlib import Path

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.outputs import CAMERA_FROM_VIEW, TrackRecording
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import ANKLE_HEIGHT_M, KP, N_KEYPOINTS_2D, PELVIS, bone_lengths_m, stature_m
from mocapdb.evaluation.bodies import CHILD_HEIGHT_RANGE_M, HEIGHT_RANGE_M, child_proportions, reshape_body, sample_body
from mocapdb.evaluation.heldout import (
    UNIVERSAL_HEIGHT_M,
    Scenario,
    Truth,
    camera_to_world,
    camera_view,
    load_heldout,
    project,
    render,
)
from mocapdb.evaluation.metrics import planted_feet
from mocapdb.runtime.engine import Engine, EngineConfig
from mocapdb.runtime.take import take_joints
from mocapdb.runtime.world import fit_takes

LOG = logging.getLogger(__name__)

HUMAN_STATURE_RANGE_M = (0.8, 2.3)  # a track's stature outside this is not a person's
CAMERA_HEIGHT_RANGE_M = (1.0, 2.0)  # drawn per take
BOX_HEIGHT_M = 0.4
FLOOR_TOLERANCE_M = 0.05  # planted soles further below a floor than this are implausible
MATCH_MAX_BOX = 0.25      # a track follows a person whose keypoints lie within this × its box height
ANKLES = [KP["r_ankle"], KP["l_ankle"]]
MODES = (("camera_height_given", True), ("nothing_given", False))  # report name, camera height given
FLAGS = ("out_of_range", "behind_camera", "below_fitted_floor", "below_true_floor")  # track_flags
IMPLAUSIBLE = FLAGS[:3]  # impossible in the track's own world; under the true floor is an error against the truth

TARGET_STATURE_GIVEN_PCT = 3.0  # camera height given: median stature error
TARGET_ROOT_GIVEN_M = 0.25      # camera height given: median root error
TARGET_STATURE_MAX_PCT = 15.0   # nothing given: no stature off by more
TARGET_RATIO_PCT = 5.0          # nothing given: no pair's stature ratio off by more
TARGET_ROOT_PCT = 10.0          # nothing given: median root error, % of the distance
TARGET_CHILD_PCT = 10.0         # the child's stature error, both modes


@dataclass(frozen=True)
class PersonSpec:
    """One person of a scenario, placed on the floor plan as seen from the camera: the mean pelvis
    ``distance_m`` in front of it (horizontally) and ``lateral_m`` to its right; walking (or, still,
    facing) along ``heading_deg`` (0 towards the camera, 90 to the right, 180 away)."""

    role: str                   # report label: adult, child, bystander, far, on box, partial
    kind: str = "adult"         # body: "adult" or "child"
    still: bool = False         # one frame with both feet down, held
    distance_m: float = 6.0
    lateral_m: float = 0.0
    heading_deg: float = 0.0
    support_m: float = 0.0      # what it stands on (BOX_HEIGHT_M: the box), metres above the floor
    edge_inside_m: float | None = None  # walks away along the image's left edge, its pelvis this far
    #                                     inside (level camera; lateral_m and heading_deg unused)


@dataclass(frozen=True)
class WorldScenario:
    """A take's layout: its people, the camera's pitch (degrees down) and the detector's noise."""

    name: str
    people: tuple[PersonSpec, ...]
    pitch_deg: float = 0.0
    noise_px: float = 2.0   # Gaussian σ, pixels of a 1080-pixel-high image
    dropout: float = 0.05   # probability that a keypoint is missing
    swap: float = 0.02      # probability per frame and person that left and right are swapped


WORLD_SCENARIOS = (
    WorldScenario("family: two adults + child, level camera", (
        PersonSpec("adult", distance_m=7.0, lateral_m=-1.7),
        PersonSpec("child", kind="child", distance_m=6.5, lateral_m=-0.2),
        PersonSpec("adult", distance_m=7.5, lateral_m=1.3, heading_deg=180.0))),
    WorldScenario("coach: two athletes + still bystander + far person, pitched 12 deg", (
        PersonSpec("adult", distance_m=7.0, lateral_m=-1.5),
        PersonSpec("adult", distance_m=7.0, lateral_m=1.5, heading_deg=180.0),
        PersonSpec("bystander", still=True, distance_m=5.0, heading_deg=30.0),
        PersonSpec("far", distance_m=15.0, lateral_m=6.0, heading_deg=90.0)),
        pitch_deg=12.0, noise_px=3.0, swap=0.03),
    WorldScenario("box: one adult on a 0.4 m box + one walking, pitched 10 deg", (
        PersonSpec("on box", still=True, support_m=BOX_HEIGHT_M, distance_m=5.5, lateral_m=-1.2, heading_deg=20.0),
        PersonSpec("adult", distance_m=7.0, lateral_m=1.0)),
        pitch_deg=10.0),
    WorldScenario("partial: one adult cut by the image edge + one whole, level camera", (
        PersonSpec("partial", distance_m=5.0, edge_inside_m=0.15),
        PersonSpec("adult", distance_m=7.0, lateral_m=0.8))),
    WorldScenario("park: adult + child + far person, pitched 15 deg", (
        PersonSpec("adult", distance_m=6.5, lateral_m=-1.2, heading_deg=180.0),
        PersonSpec("child", kind="child", distance_m=6.0, lateral_m=0.9),
        PersonSpec("far", distance_m=15.0, lateral_m=-6.0, heading_deg=-90.0)),
        pitch_deg=15.0),
)


@dataclass
class WorldConfig:
    scenarios: tuple[WorldScenario, ...] = WORLD_SCENARIOS
    repeats: int = 10         # takes per scenario: other camera heights, bodies, clips, jitter
    frames: int = 72          # per take (3 s at 24 fps; fewer if a walking clip is shorter)
    fps: float = 24.0
    focal_px: float = 1000.0
    image_size: tuple[int, int] = (1920, 1080)
    seed: int = 0
    jitter: bool = True       # per take: distance ±0.3 m, lateral ±0.2 m, heading ±15° of the layout
    engine: EngineConfig = field(default_factory=EngineConfig)

    @classmethod
    def quick(cls, **changes) -> WorldConfig:
        """One take per scenario, 48 frames."""
        return cls(**{"repeats": 1, "frames": 48, **changes})


@dataclass(frozen=True)
class Camera:
    """The take's camera: centre ``height_m`` above the floor, tilted down by ``pitch_deg``."""

    height_m: float
    pitch_deg: float = 0.0

    def up_view(self) -> np.ndarray:
        """The world's up ``[3]`` in the view frame (camera-aligned with z negated)."""
        pitch = np.radians(self.pitch_deg)
        return np.array([0.0, np.cos(pitch), np.sin(pitch)])

    def heights_m(self, cam_points: np.ndarray) -> np.ndarray:
        """Heights above the floor (metres) of camera-aligned points ``[..., 3]``."""
        return camera_to_world(cam_points, self.height_m, 0.0, self.pitch_deg)[..., 1]


@dataclass
class TruePerson:
    """One rendered person: truth ``cam_m [F, 15, 3]`` (camera-aligned, metres), stature (m) and
    the detector-like input ``points_px [F, 14, 2]``, ``confidence [F, 14]``."""

    spec: PersonSpec
    clip: str
    stature_m: float
    cam_m: np.ndarray
    points_px: np.ndarray
    confidence: np.ndarray

    def box_px(self, focal_px: float, image_size: tuple[int, int]) -> float:
        """Median height (px) of the clean keypoints' image box."""
        px = project(self.cam_m[:, :N_KEYPOINTS_2D], focal_px, image_size)
        return float(np.median(np.ptp(px[..., 1], axis=1)))

    def outside_share(self, focal_px: float, image_size: tuple[int, int]) -> float:
        """Share of the clean keypoints that fall outside the image."""
        px = project(self.cam_m[:, :N_KEYPOINTS_2D], focal_px, image_size)
        inside = (px >= 0).all(axis=-1) & (px[..., 0] < image_size[0]) & (px[..., 1] < image_size[1])
        return float(1.0 - inside.mean())


@dataclass
class WorldTake:
    """A rendered take: its scenario and repeat, camera, people and keypoint frames."""

    scenario: WorldScenario
    repeat: int
    camera: Camera
    people: list[TruePerson]
    frames: list[KeypointFrame]


@dataclass
class TrackFit:
    """One engine track after the whole-take world, camera-aligned (metres): input frame indices
    ``frames [n]``, ``joints_m [n, 15, 3]``, ``root_m [n, 3]``, the stature (m), the fitted floor
    ``up_view · p = floor_offset_m`` (view frame; None: none found) and the input keypoints the
    track took, ``keypoints [n, 14, 3]`` (x, y px, confidence)."""

    track: int
    frames: np.ndarray
    joints_m: np.ndarray
    root_m: np.ndarray
    stature_m: float
    up_view: np.ndarray | None
    floor_offset_m: float | None
    keypoints: np.ndarray
    static: bool = False


def body_lengths_m(source_m: np.ndarray, kind: str, rng: np.random.Generator) -> np.ndarray:
    """Bone lengths ``[8]`` (metres) of a body drawn for a clip's source joints ``[F, 15, 3]``:
    :func:`~mocapdb.evaluation.bodies.sample_body` (a child: its height range and proportions),
    scaled so that its stature is exactly the drawn height."""
    child = kind == "child"
    body = sample_body(rng, CHILD_HEIGHT_RANGE_M if child else HEIGHT_RANGE_M)
    lengths = body.bone_lengths_m(bone_lengths_m(source_m).mean(axis=0))
    if child:
        lengths = child_proportions(lengths)
    return lengths * (body.height_m / stature_m(lengths))


def clip_heading_deg(source_m: np.ndarray) -> float:
    """Direction (degrees from +z towards +x) of a clip's horizontal pelvis travel, first to last frame."""
    travel = source_m[-1, PELVIS] - source_m[0, PELVIS]
    return float(np.degrees(np.arctan2(travel[0], travel[2])))


def still_frame(source_m: np.ndarray) -> int:
    """The frame of a clip with both feet lowest (the higher ankle at its lowest): a standing pose."""
    return int(np.argmin(source_m[:, ANKLES, 1].max(axis=1)))


def placement(spec: PersonSpec, focal_px: float, image_size: tuple[int, int]) -> tuple[float, float, float]:
    """(distance m, lateral m, heading deg) of a person; on the image edge: walking away along the
    ray through the left edge (level camera), the pelvis ``edge_inside_m`` inside it."""
    if spec.edge_inside_m is None:
        return spec.distance_m, spec.lateral_m, spec.heading_deg
    slope = image_size[0] / 2.0 / focal_px  # lateral / distance along the edge ray
    lateral = -slope * spec.distance_m + spec.edge_inside_m * np.hypot(1.0, slope)
    return spec.distance_m, float(lateral), float(np.degrees(np.arctan2(-slope, -1.0)))


def person_view(truth: Truth, spec: PersonSpec, lengths_m: np.ndarray, n_frames: int, camera: Camera,
                focal_px: float, image_size: tuple[int, int]) -> np.ndarray:
    """A person's joints ``[n_frames, 15, 3]`` in the camera-aligned frame: the clip's middle frames
    (still: its :func:`still_frame` held) on the body ``lengths_m``, standing ``support_m`` up,
    turned to its heading and placed (:func:`placement`)."""
    source = truth.source_m
    if spec.still:
        segment = source[np.full(n_frames, still_frame(source))]
    else:
        start = (len(source) - n_frames) // 2
        segment = source[start:start + n_frames]
    world = reshape_body(segment, lengths_m) + [0.0, spec.support_m, 0.0]
    distance, lateral, heading = placement(spec, focal_px, image_size)
    yaw = heading - clip_heading_deg(source)
    return camera_view(world, yaw, camera.height_m, distance, camera.pitch_deg) + [lateral, 0.0, 0.0]


def _jittered(spec: PersonSpec, rng: np.random.Generator) -> PersonSpec:
    """``spec`` moved by up to ±0.3 m in distance, ±0.2 m laterally and ±15° in heading."""
    d, x, h = rng.uniform(-1.0, 1.0, 3) * [0.3, 0.2, 15.0]
    return replace(spec, distance_m=spec.distance_m + d, lateral_m=spec.lateral_m + x, heading_deg=spec.heading_deg + h)


def build_take(truths: list[Truth], scenario: WorldScenario, scenario_index: int, repeat: int,
               config: WorldConfig) -> WorldTake:
    """Take ``repeat`` of a scenario, deterministic in (seed, scenario, repeat): camera height,
    bodies, clips (walkers: distinct clips at least :attr:`WorldConfig.frames` long, if there are),
    jitter and noise."""
    rng = np.random.default_rng((config.seed, scenario_index, repeat))
    camera = Camera(float(rng.uniform(*CAMERA_HEIGHT_RANGE_M)), scenario.pitch_deg)
    long_clips = [t for t in truths if len(t.source_m) >= config.frames]
    walkers = long_clips or sorted(truths, key=lambda t: -len(t.source_m))
    n_frames = min(config.frames, min(len(t.source_m) for t in walkers))
    noise = Scenario(scenario.name, noise_px=scenario.noise_px, dropout=scenario.dropout, swap=scenario.swap)
    people = []
    for i, spec in enumerate(scenario.people):
        pool = truths if spec.still else walkers
        truth = pool[(scenario_index + repeat * len(scenario.people) + i) % len(pool)]
        spec = _jittered(spec, rng) if config.jitter else spec
        lengths = body_lengths_m(truth.source_m, spec.kind, rng)
        cam = person_view(truth, spec, lengths, n_frames, camera, config.focal_px, config.image_size)
        rendered = render(cam, noise, config.focal_px, config.image_size,
                          np.random.default_rng((config.seed, scenario_index, repeat, i)))
        people.append(TruePerson(spec, truth.name, float(stature_m(lengths)), cam,
                                 np.array([f.people[0].points_px for f in rendered]),
                                 np.array([f.people[0].confidence for f in rendered])))
    frames = [KeypointFrame(k, None, [Person(p.points_px[k], p.confidence[k]) for p in people])
              for k in range(n_frames)]
    return WorldTake(scenario, repeat, camera, people, frames)


def track_fit(rec: TrackRecording, fitted: TrackRecording) -> TrackFit:
    """A track as the engine recorded it (``rec``: its input keypoints) and as the whole-take world
    fitted it (``fitted``)."""
    frames, joints, root = take_joints(fitted)
    up = None if fitted.up_view is None else np.asarray(fitted.up_view, dtype=np.float64)
    return TrackFit(rec.track, frames, joints, root, UNIVERSAL_HEIGHT_M * float(fitted.scales[-1]), up,
                    fitted.floor_offset_m, np.array(rec.keypoints).reshape(-1, N_KEYPOINTS_2D, 3), rec.static)


def run_take(db: MotionDatabase, take: WorldTake, camera_height_m: float | None,
             config: WorldConfig) -> tuple[list[TrackFit], float, float]:
    """The take through the engine and the whole-take world (``camera_height_m`` given or None):
    every track (static ones too), and the seconds of each."""
    engine_config = replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=config.image_size,
                            keep_take=True, camera_height_m=camera_height_m)
    engine = Engine(db, engine_config)
    t0 = time.perf_counter()
    for frame in take.frames:
        engine.step(frame)
    recordings = engine.finish()
    t1 = time.perf_counter()
    fitted = fit_takes(recordings, config.fps, camera_height_m=camera_height_m)
    t2 = time.perf_counter()
    return [track_fit(rec, fit) for rec, fit in zip(recordings, fitted)], t1 - t0, t2 - t1


def keypoint_distance_px(keypoints: np.ndarray, points_px: np.ndarray, confidence: np.ndarray) -> np.ndarray:
    """Median over frames of the mean distance (px) between a track's keypoints ``[n, 14, 3]`` and
    each person's input ``points_px [P, n, 14, 2]`` over the keypoints both see (``confidence
    [P, n, 14]``): ``[P]``, inf where they share none."""
    seen = (keypoints[None, ..., 2] > 0) & (confidence > 0)
    dist = np.linalg.norm(keypoints[None, ..., :2] - points_px, axis=-1)
    count = seen.sum(axis=-1)
    per_frame = np.where(count > 0, (dist * seen).sum(axis=-1) / np.maximum(count, 1), np.nan)
    out = np.full(len(points_px), np.inf)
    some = np.isfinite(per_frame).any(axis=1)
    out[some] = np.nanmedian(per_frame[some], axis=1)
    return out


def match_tracks(fits: list[TrackFit], people: list[TruePerson], focal_px: float,
                 image_size: tuple[int, int]) -> list[int | None]:
    """The person (index) each track follows: the nearest by :func:`keypoint_distance_px` if within
    :data:`MATCH_MAX_BOX` of that person's box height; None for a track that follows nobody."""
    n_frames = len(people[0].points_px)
    boxes = np.array([p.box_px(focal_px, image_size) for p in people])
    points = np.stack([p.points_px for p in people])
    confidence = np.stack([p.confidence for p in people])
    out: list[int | None] = []
    for fit in fits:
        keep = (fit.frames >= 0) & (fit.frames < n_frames)
        idx = fit.frames[keep]
        cost = keypoint_distance_px(fit.keypoints[keep], points[:, idx], confidence[:, idx]) / boxes
        best = int(np.argmin(cost))
        out.append(best if cost[best] <= MATCH_MAX_BOX else None)
    return out


def _sole_heights_m(fit: TrackFit, camera: Camera, support_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Per frame of a track, its lower sole's height (m: ankle minus the body's ankle height) above
    the fitted floor (NaN without one) and above the true surface ``support_m`` up from the floor."""
    ankles = fit.joints_m[:, ANKLES]
    sole = ANKLE_HEIGHT_M * fit.stature_m / UNIVERSAL_HEIGHT_M
    true = camera.heights_m(ankles).min(axis=1) - support_m - sole
    if fit.up_view is None or fit.floor_offset_m is None:
        return np.full(len(ankles), np.nan), true
    fitted = ((ankles * CAMERA_FROM_VIEW) @ fit.up_view).min(axis=1) - fit.floor_offset_m - sole
    return fitted, true


def track_flags(fit: TrackFit, camera: Camera, person: TruePerson | None, fps: float) -> dict[str, bool]:
    """A track's :data:`FLAGS`: its stature outside :data:`HUMAN_STATURE_RANGE_M`, a root at or
    behind the camera (z ≤ 0) in any frame, its lower sole more than :data:`FLOOR_TOLERANCE_M` under
    the fitted floor, or under the true surface it stands on (median over the frames where the
    person's true foot is planted; a track of nobody: all its frames, on the floor). The first three
    are :data:`IMPLAUSIBLE` (impossible in the world the track reconstructs); the last is an error
    against the truth (a body 5 % too big, scaled about a camera 1.5 m up, stands 7.5 cm into it)."""
    support = person.spec.support_m if person is not None else 0.0
    fitted, true = _sole_heights_m(fit, camera, support)
    planted = np.ones(len(fit.frames), dtype=bool)
    if person is not None:
        world = camera_to_world(person.cam_m[:, ANKLES], camera.height_m, 0.0, camera.pitch_deg)
        index = np.clip(fit.frames, 0, len(world) - 1)
        planted = planted_feet(world, fps).any(axis=1)[index]
    lo, hi = HUMAN_STATURE_RANGE_M
    flags = (not lo <= fit.stature_m <= hi, bool((fit.root_m[:, 2] <= 0.0).any()),
             bool(_median(fitted[planted]) < -FLOOR_TOLERANCE_M), bool(_median(true[planted]) < -FLOOR_TOLERANCE_M))
    return dict(zip(FLAGS, flags))


def floor_errors(fit: TrackFit, camera: Camera) -> tuple[float, float]:
    """The fitted floor's camera height minus the true one (m) and the angle between the fitted and
    the true up (degrees); NaN without a fitted floor."""
    if fit.up_view is None or fit.floor_offset_m is None:
        return float("nan"), float("nan")
    cosine = float(np.clip(fit.up_view @ camera.up_view() / np.linalg.norm(fit.up_view), -1.0, 1.0))
    return -fit.floor_offset_m - camera.height_m, float(np.degrees(np.arccos(cosine)))


def score_person(person: TruePerson, fit: TrackFit, camera: Camera) -> dict:
    """A person against its track: stature error (% of the true stature), median root error (m and
    % of the true camera-to-pelvis distance, over the track's frames), floor errors."""
    keep = (fit.frames >= 0) & (fit.frames < len(person.cam_m))
    truth = person.cam_m[fit.frames[keep], PELVIS]
    error = np.linalg.norm(fit.root_m[keep] - truth, axis=-1)
    height_error, angle = floor_errors(fit, camera)
    return {"stature_m": fit.stature_m, "stature_error_pct": 100.0 * (fit.stature_m / person.stature_m - 1.0),
            "root_error_m": _median(error), "root_error_pct": _median(100.0 * error / np.linalg.norm(truth, axis=-1)),
            "camera_height_error_m": height_error, "floor_angle_deg": angle}


def ratio_error_pct(est_a: float, est_b: float, true_a: float, true_b: float) -> float:
    """How far (%) the estimated ratio of two statures is from the true one, either way round."""
    r = (est_a / est_b) / (true_a / true_b)
    return 100.0 * (max(r, 1.0 / r) - 1.0)


def score_take(take: WorldTake, fits: list[TrackFit], config: WorldConfig) -> dict:
    """A take's people (each its longest matching track), tracks (with :func:`track_flags`) and the
    stature-ratio error of every pair of people with a track."""
    owners = match_tracks(fits, take.people, config.focal_px, config.image_size)
    tracks = []
    for fit, owner in zip(fits, owners):
        person = None if owner is None else take.people[owner]
        flags = track_flags(fit, take.camera, person, config.fps)
        tracks.append({"track": fit.track, "person": owner, "frames": len(fit.frames), "stature_m": fit.stature_m,
                       "static": fit.static, "flags": flags, "implausible": any(flags[f] for f in IMPLAUSIBLE)})
    people = [_person_entry(take, i, fits, owners, config) for i in range(len(take.people))]
    pairs = [ratio_error_pct(a["stature_m"], b["stature_m"], a["true_stature_m"], b["true_stature_m"])
             for a, b in combinations([p for p in people if p["track"] is not None], 2)]
    return {"scenario": take.scenario.name, "repeat": take.repeat, "camera_height_m": take.camera.height_m,
            "pitch_deg": take.camera.pitch_deg, "frames": len(take.frames), "people": people, "tracks": tracks,
            "pair_ratio_error_pct": pairs, "false_tracks": sum(o is None for o in owners)}


def _person_entry(take: WorldTake, index: int, fits: list[TrackFit], owners: list[int | None],
                  config: WorldConfig) -> dict:
    """One person's report entry (:func:`score_person` on its longest track; NaN without one)."""
    person = take.people[index]
    mine = [fit for fit, owner in zip(fits, owners) if owner == index]
    entry = {"role": person.spec.role, "kind": person.spec.kind, "clip": person.clip, "still": person.spec.still,
             "support_m": person.spec.support_m, "true_stature_m": person.stature_m,
             "distance_m": float(np.median(np.linalg.norm(person.cam_m[:, PELVIS], axis=-1))),
             "unseen_keypoints": float(np.mean(person.confidence <= 0)),
             "outside_image": person.outside_share(config.focal_px, config.image_size),
             "tracks": [fit.track for fit in mine], "track": None, "static": None}
    nan = float("nan")
    entry.update(stature_m=nan, stature_error_pct=nan, root_error_m=nan, root_error_pct=nan,
                 camera_height_error_m=nan, floor_angle_deg=nan)
    if mine:
        main = max(mine, key=lambda fit: len(fit.frames))
        entry.update(track=main.track, static=main.static, **score_person(person, main, take.camera))
    return entry


def _median(values: np.ndarray) -> float:
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(np.median(values)) if len(values) else float("nan")


def _max(values) -> float:
    values = np.asarray(list(values), dtype=np.float64)
    values = values[np.isfinite(values)]
    return float(values.max()) if len(values) else float("nan")


def summarise(takes: list[dict]) -> dict:
    """Figures over takes (:func:`score_take`): people and those missed; |stature error| median and
    max (%); largest pair-ratio error (%); median root error (m, %); largest |child stature error|
    (%); median |camera-height error| (m) and floor angle (degrees); tracks, implausible ones, those
    outside the human range, false ones."""
    people = [p for t in takes for p in t["people"]]
    tracks = [k for t in takes for k in t["tracks"]]
    stature = np.abs([p["stature_error_pct"] for p in people])
    return {
        "takes": len(takes), "people": len(people), "missed": sum(p["track"] is None for p in people),
        "stature_error_pct": {"median": _median(stature), "max": _max(stature)},
        "pair_ratio_error_pct_max": _max(r for t in takes for r in t["pair_ratio_error_pct"]),
        "root_error_m": _median([p["root_error_m"] for p in people]),
        "root_error_pct": _median([p["root_error_pct"] for p in people]),
        "child_stature_error_pct_max": _max(abs(p["stature_error_pct"]) for p in people if p["kind"] == "child"),
        "camera_height_error_m": _median(np.abs([p["camera_height_error_m"] for p in people])),
        "floor_angle_deg": _median([p["floor_angle_deg"] for p in people]),
        "tracks": len(tracks), "implausible_tracks": sum(k["implausible"] for k in tracks),
        "out_of_range_tracks": sum(k["flags"]["out_of_range"] for k in tracks),
        "flagged_tracks": {flag: sum(k["flags"][flag] for k in tracks) for flag in FLAGS},
        "false_tracks": sum(t["false_tracks"] for t in takes),
    }


def by_role(takes: list[dict]) -> dict[str, dict]:
    """Per role: people, missed, |stature error| median and max (%), median root error (m, %)."""
    out = {}
    for role in sorted({p["role"] for t in takes for p in t["people"]}):
        people = [p for t in takes for p in t["people"] if p["role"] == role]
        stature = np.abs([p["stature_error_pct"] for p in people])
        out[role] = {"people": len(people), "missed": sum(p["track"] is None for p in people),
                     "stature_error_pct": {"median": _median(stature), "max": _max(stature)},
                     "root_error_m": _median([p["root_error_m"] for p in people]),
                     "root_error_pct": _median([p["root_error_pct"] for p in people])}
    return out


def run_takes(db: MotionDatabase, takes: list[WorldTake], config: WorldConfig) -> dict[str, list[dict]]:
    """Every take through :func:`run_take` and :func:`score_take` in each of :data:`MODES`: per mode
    the takes' results with their engine and world seconds (progress at info level)."""
    bar = progress(total=len(takes) * len(MODES), desc="world", unit="take")
    results: dict[str, list[dict]] = {mode: [] for mode, _ in MODES}
    for take in takes:
        for mode, given in MODES:
            fits, engine_s, world_s = run_take(db, take, take.camera.height_m if given else None, config)
            result = score_take(take, fits, config)
            results[mode].append({**result, "mode": mode, "engine_seconds": engine_s, "world_seconds": world_s})
            LOG.info(f"world: {take.scenario.name} #{take.repeat + 1}, {mode.replace('_', ' ')}: {len(fits)} "
                     f"tracks for {len(take.people)} people, engine {engine_s:.1f} s, world {world_s:.2f} s")
            bar.update(1)
    bar.close()
    return results


def evaluate_world(db: MotionDatabase, heldout: list[Path], config: WorldConfig) -> dict:
    """Every scenario's takes, each with the camera height given and with nothing given, scored
    (module docstring): a JSON-able report with per-take detail, summaries and timings (seconds)."""
    t_start = time.perf_counter()
    truths = load_heldout(heldout, config.fps)
    takes = [build_take(truths, s, i, r, config) for i, s in enumerate(config.scenarios) for r in range(config.repeats)]
    results = run_takes(db, takes, config)
    every = [t for mode, _ in MODES for t in results[mode]]
    return {
        "database": {"projections": db.n_projections, "frames": db.n_frames, "clusters": db.n_clusters},
        "heldout_clips": [t.name for t in truths],
        "config": {"repeats": config.repeats, "frames": config.frames, "fps": config.fps, "focal_px": config.focal_px,
                   "image_size": list(config.image_size), "seed": config.seed, "jitter": config.jitter,
                   "camera_height_range_m": list(CAMERA_HEIGHT_RANGE_M),
                   "human_stature_range_m": list(HUMAN_STATURE_RANGE_M)},
        "scenarios": [asdict(s) for s in config.scenarios],
        "summary": [{"scenario": s.name, "mode": mode, **summarise([t for t in takes if t["scenario"] == s.name])}
                    for s in config.scenarios for mode, takes in results.items()],
        "overall": {mode: summarise(results[mode]) for mode, _ in MODES},
        "by_role": {mode: by_role(results[mode]) for mode, _ in MODES},
        "takes": every,
        "seconds": {"engine": sum(t["engine_seconds"] for t in every), "world": sum(t["world_seconds"] for t in every),
                    "total": time.perf_counter() - t_start},
    }


def _cell(value: float, digits: int = 1) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


_SUMMARY_HEADER = ("| scenario | camera height | people (missed) | stature error median / max | pair ratio max | "
                   "root error | root / distance | child | camera height error / floor angle | implausible tracks: "
                   "any (size / behind camera / under own floor) | soles under the true floor | false tracks |")
_ROLE_HEADER = "| role | camera height | people (missed) | stature error median / max | root error | root / distance |"


def format_table(report: dict) -> str:
    """Markdown tables of :func:`evaluate_world`'s report: per scenario and mode, then per role."""
    lines = [_SUMMARY_HEADER, "|---" * 12 + "|"]
    for row in report["summary"]:
        lines.append(_summary_row(row["scenario"], row["mode"], row))
    for mode, row in report["overall"].items():
        lines.append(_summary_row("**all**", mode, row))
    lines += ["", _ROLE_HEADER, "|---" * 6 + "|"]
    for mode, roles in report["by_role"].items():
        for role, r in roles.items():
            lines.append(f"| {role} | {_mode_label(mode)} | {r['people']} ({r['missed']}) | "
                         f"{_cell(r['stature_error_pct']['median'])} / {_cell(r['stature_error_pct']['max'])} % | "
                         f"{_cell(r['root_error_m'], 2)} m | {_cell(r['root_error_pct'])} % |")
    return "\n".join(lines)


def _mode_label(mode: str) -> str:
    return "given" if mode == "camera_height_given" else "not given"


def _summary_row(name: str, mode: str, r: dict) -> str:
    return (f"| {name} | {_mode_label(mode)} | {r['people']} ({r['missed']}) | "
            f"{_cell(r['stature_error_pct']['median'])} / {_cell(r['stature_error_pct']['max'])} % | "
            f"{_cell(r['pair_ratio_error_pct_max'])} % | {_cell(r['root_error_m'], 2)} m | "
            f"{_cell(r['root_error_pct'])} % | {_cell(r['child_stature_error_pct_max'])} % | "
            f"{_cell(r['camera_height_error_m'], 2)} m / {_cell(r['floor_angle_deg'])}° | "
            f"{r['implausible_tracks']} ({' / '.join(str(r['flagged_tracks'][f]) for f in IMPLAUSIBLE)}) of "
            f"{r['tracks']} | {r['flagged_tracks']['below_true_floor']} | {r['false_tracks']} |")


def check_lines(report: dict) -> list[str]:
    """A PASS/FAIL line per target of issue 27 (over every scenario's takes of the mode named)."""
    given, nothing = report["overall"]["camera_height_given"], report["overall"]["nothing_given"]
    both = [(given, "camera height given"), (nothing, "nothing given")]
    checks = [(f"{label}: tracks outside the human range {HUMAN_STATURE_RANGE_M[0]}-{HUMAN_STATURE_RANGE_M[1]} m",
               r["out_of_range_tracks"], 0, "tracks") for r, label in both]
    checks += [(f"{label}: implausible tracks (size, behind the camera, soles > 5 cm under its own floor)",
                r["implausible_tracks"], 0, "tracks") for r, label in both]
    checks += [(f"{label}: people without a track", r["missed"], 0, "people") for r, label in both]
    checks += [("camera height given: median stature error", given["stature_error_pct"]["median"],
                TARGET_STATURE_GIVEN_PCT, "%"),
               ("camera height given: median root error", given["root_error_m"], TARGET_ROOT_GIVEN_M, "m"),
               ("nothing given: largest stature error", nothing["stature_error_pct"]["max"],
                TARGET_STATURE_MAX_PCT, "%"),
               ("nothing given: largest pair stature-ratio error", nothing["pair_ratio_error_pct_max"],
                TARGET_RATIO_PCT, "%"),
               ("nothing given: median root error / distance", nothing["root_error_pct"], TARGET_ROOT_PCT, "%")]
    checks += [(f"{label}: child's largest stature error", r["child_stature_error_pct_max"], TARGET_CHILD_PCT, "%")
               for r, label in both]
    return [f"{_verdict(value, target)}  {label}: {_cell(value, 0 if unit in ('tracks', 'people') else 2)} {unit} "
            f"≤ {target:g} {unit}" for label, value, target, unit in checks]


def _verdict(value: float, target: float) -> str:
    """PASS, FAIL, or n/a where there is nothing to score (no child in the run, nobody tracked)."""
    if not np.isfinite(value):
        return "n/a "
    return "PASS" if value <= target else "FAIL"
