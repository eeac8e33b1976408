"""Held-out motion rendered to 2D keypoint frames, with the truth it came from.

Held-out BVH clips (``data_specs/evaluation_split.md``; the database must be built without them)
are retargeted like database clips (:class:`Truth`), optionally scaled to another subject height,
turned by yaws off the database's grid, seen by a pinhole camera at several heights and pitches,
and perturbed by detector-like noise, dropout and left/right swaps (:class:`Scenario`,
:func:`render`), optionally with the detector's own 3D (:func:`detector_world`: world landmarks with
errors mostly in depth, slow, swapped with the 2D). Scoring the engine on these frames:
:mod:`mocapdb.evaluation.reconstruction`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import yaw_matrix
from mocapdb.core.skeleton import KP, MIRROR_PAIRS, N_KEYPOINTS_2D, PELVIS, bone_lengths_m
from mocapdb.evaluation.bodies import reshape_body, sample_body
from mocapdb.evaluation.face_render import detected_faces
from mocapdb.evaluation.hand_render import detected_hands
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.world.detector_prior import Z_AXIS, rotation_between

BODIES = ("universal", "varied")
SWAP_PAIRS = [(KP[right], KP[left]) for right, left in MIRROR_PAIRS]  # right/left keypoint pairs
EXTREMITY_SWAP_PAIRS = [(EXTREMITIES.index(name), EXTREMITIES.index("l" + name[1:]))
                        for name in EXTREMITIES if name.startswith("r_")]
WORLD_ERROR_FRAMES = 12       # the simulated world landmarks' errors are correlated over this many frames (0.5 s)
WORLD_ACROSS_SHARE = 1.0 / 3  # their error across the viewing ray, a share of the error along it
DETECTOR_WORLD_SD_M = 0.08    # the scenarios' error along the ray: raw landmarks ~8-9 cm MPJPE, as MediaPipe's
#                               10-12 cm on the balancing take's better cameras (issue 37's table)
IMAGE_HEIGHT_PX = 1080
UNIVERSAL_HEIGHT_M = 1.75   # the database skeleton's height (data_specs/skeleton.md)


@dataclass(frozen=True)
class Scenario:
    """One rendering condition."""

    name: str
    camera_height_m: float = 1.5
    noise_px: float = 0.0       # Gaussian σ, pixels of a 1080-pixel-high image
    dropout: float = 0.0        # probability that a keypoint is missing
    swap: float = 0.0           # probability per frame that left and right are swapped
    pitch_deg: float = 0.0      # camera tilted down by this angle about its x axis
    roll_deg: float = 0.0       # then rolled about its optical axis: the world's up leans this far to the image's left
    subject_height_m: float = UNIVERSAL_HEIGHT_M  # truth scaled by this / 1.75 before rendering
    height_given: bool = False  # the engine is told subject_height_m (EngineConfig.subject_height_m)
    body: str = "universal"     # "universal": the retargeted clip; "varied": its source joints on a
    #                             sampled body per clip and yaw (mocapdb.evaluation.bodies)
    camera_height_given: bool = False  # the engine is told camera_height_m (EngineConfig.camera_height_m)
    world_sd_m: float = 0.0     # the keypoints carry the detector's 3D (world landmarks), its error along the
    #                             viewing ray this SD (metres; :func:`detector_world`); 0: none carried

    def __post_init__(self) -> None:
        if self.body not in BODIES:
            raise ValueError(f"body must be one of {BODIES}, not {self.body!r}")
        if self.body == "varied" and (self.height_given or self.subject_height_m != UNIVERSAL_HEIGHT_M):
            raise ValueError("a varied body samples its own height: leave subject_height_m and height_given")


DEFAULT_SCENARIOS = (
    Scenario("clean, camera 1.5 m"),
    Scenario("sigma 5 px, camera 1.5 m", noise_px=5.0),
    Scenario("clean, camera 1.0 m", camera_height_m=1.0),
    Scenario("clean, camera 2.2 m", camera_height_m=2.2),
    Scenario("sigma 5 px + 10% dropout + 5% swaps", noise_px=5.0, dropout=0.1, swap=0.05),
    Scenario("clean, camera 1.5 m pitched 15 deg", pitch_deg=15.0),
    Scenario("clean, camera 1.5 m pitched 15 deg, rolled 30 deg", pitch_deg=15.0, roll_deg=30.0),
    Scenario("clean, subject 1.55 m, height given", subject_height_m=1.55, height_given=True),
    Scenario("varied bodies, clean, camera 1.5 m", body="varied"),
    Scenario("varied bodies, clean, pitched 15 deg", pitch_deg=15.0, body="varied"),
    Scenario("varied bodies, sigma 5 px + 10% dropout + 5% swaps", noise_px=5.0, dropout=0.1, swap=0.05,
             body="varied"),
    Scenario("varied bodies, clean, detector 3D", body="varied", world_sd_m=DETECTOR_WORLD_SD_M),
    Scenario("varied bodies, sigma 5 px + 10% dropout + 5% swaps, detector 3D", noise_px=5.0, dropout=0.1,
             swap=0.05, body="varied", world_sd_m=DETECTOR_WORLD_SD_M),
)


@dataclass
class EvalConfig:
    """The held-out evaluation: the yaws and scenarios each clip is rendered with, its camera, the engine's settings."""

    yaws_deg: tuple[float, ...] = (6.0, 51.0, 99.0, 141.0, 186.0, 231.0, 279.0, 321.0)  # 3° or 6° off the 12° grid
    scenarios: tuple[Scenario, ...] = DEFAULT_SCENARIOS
    fps: float = 24.0
    camera_distance_m: float = 5.0   # from the clip's mean pelvis (horizontal), at least ...
    min_clearance_m: float = 3.0     # ... and far enough that every pelvis of the turned clip is this far in front
    focal_px: float = 1000.0
    image_size: tuple[int, int] = (1920, 1080)
    seed: int = 0
    engine: EngineConfig = field(default_factory=EngineConfig)
    stream_lags: tuple[int, ...] = ()  # also the default stream (the online take) at these lags (frames)


@dataclass
class Truth:
    """A held-out clip's joints on the universal skeleton: what errors are measured against (its
    motion is only rendered: :attr:`positions` are the clip's forward kinematics)."""

    name: str
    positions: np.ndarray    # [F, 15, 3] world, floor at 0
    yaws_deg: tuple[float, ...] | None = None  # this clip's yaws; None: EvalConfig.yaws_deg
    source_m: np.ndarray | None = None  # [F, 15, 3] the source skeleton's own joints (Clip.source_m)

    def source_joints(self) -> np.ndarray:
        """:attr:`source_m`, which the world takes render; ValueError when this truth has none
        (:func:`load_heldout` gives them)."""
        if self.source_m is None:
            raise ValueError(f"held-out clip {self.name}: no source skeleton joints (source_m)")
        return self.source_m


def load_heldout(paths: list[Path], fps: float) -> list[Truth]:
    """Retarget held-out BVH files exactly as the builder does."""
    config = ClipOptions(fps=fps)
    truths = []
    for path in paths:
        c = process_clip(path, path.parent, config)
        if c.source_m is None:
            raise ValueError(f"{path}: retargeted without the source skeleton's own joints")
        truths.append(Truth(c.name, c.positions.astype(np.float64), source_m=c.source_m.astype(np.float64)))
    return truths


def scenario_positions(truth: Truth, scenario: Scenario, clip_index: int, yaw_index: int,
                       seed: int) -> tuple[np.ndarray, float]:
    """The truth joints ``[F, 15, 3]`` (world, floor at 0) a scenario renders for one clip and yaw,
    and the body's stature (metres). Universal body: the retargeted clip scaled to the scenario's
    subject height. Varied: the source joints on a body drawn for (seed, clip, yaw), the same in
    every scenario."""
    if scenario.body == "universal":
        return scaled_positions(truth.positions, scenario.subject_height_m), scenario.subject_height_m
    if truth.source_m is None:
        raise ValueError(f"{truth.name}: a varied-body scenario needs the clip's source joints")
    body = sample_body(np.random.default_rng((seed, clip_index, yaw_index)))
    lengths = body.bone_lengths_m(bone_lengths_m(truth.source_m).mean(axis=0))
    return reshape_body(truth.source_m, lengths), body.height_m


def scaled_positions(positions: np.ndarray, subject_height_m: float) -> np.ndarray:
    """``positions [F, 15, 3]`` (skeleton and root path) scaled by ``subject_height_m`` / 1.75 about
    the floor point under the clip's mean pelvis."""
    s = subject_height_m / UNIVERSAL_HEIGHT_M
    if s == 1.0:
        return positions
    centre = positions[:, PELVIS].mean(axis=0) * [1.0, 0.0, 1.0]
    return centre + s * (positions - centre)


def camera_distance(positions: np.ndarray, yaw_deg: float, config: EvalConfig) -> float:
    """Horizontal camera distance from the clip's mean pelvis for one view: ``camera_distance_m``,
    or more so every pelvis of the turned clip stays ``min_clearance_m`` in front of the camera."""
    centre = positions[:, PELVIS].mean(axis=0) * [1.0, 0.0, 1.0]
    towards = ((positions[:, PELVIS] - centre) @ yaw_matrix(yaw_deg).T)[:, 2]  # the camera is at +z
    return max(config.camera_distance_m, config.min_clearance_m + max(float(towards.max()), 0.0))


def camera_view(positions: np.ndarray, yaw_deg: float, height_m: float, distance_m: float,
                pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """World points ``[F, J, 3]`` in the camera-aligned frame (x right, y up, z away from the camera):
    turned by ``yaw_deg`` about the clip's mean pelvis, seen by a camera ``distance_m`` in front of
    it (along +z) at ``height_m`` above the floor, looking along −z, tilted down by ``pitch_deg`` and
    rolled by ``roll_deg`` (:func:`_rolled`)."""
    centre = positions[:, PELVIS].mean(axis=0) * [1, 0, 1]
    turned = (positions - centre) @ yaw_matrix(yaw_deg).T - [0.0, height_m, distance_m]
    return _rolled(_pitched(turned, pitch_deg), roll_deg)


def _rolled(cam_points: np.ndarray, roll_deg: float) -> np.ndarray:
    """Camera-aligned points of a camera rolled by ``roll_deg`` about its optical axis: the world's up
    then leans that far to the image's left (as ``World.roll_deg``); negative ``roll_deg`` undoes it."""
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    x, y, z = cam_points[..., 0], cam_points[..., 1], cam_points[..., 2]
    return np.stack([c * x - s * y, s * x + c * y, z], axis=-1)


def _pitched(points: np.ndarray, pitch_deg: float) -> np.ndarray:
    """Points relative to the camera centre (y up, camera looking along −z) → camera-aligned (z away
    from the camera) for a camera tilted down by ``pitch_deg``; the map is its own inverse."""
    c, s = np.cos(np.radians(pitch_deg)), np.sin(np.radians(pitch_deg))
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return np.stack([x, c * y - s * z, -s * y - c * z], axis=-1)


def camera_to_world(cam_points: np.ndarray, height_m: float, distance_m: float, pitch_deg: float = 0.0,
                    roll_deg: float = 0.0) -> np.ndarray:
    """The inverse of :func:`camera_view` up to the clip's turn and centre: camera-aligned points →
    the turned world (y up, metres above the floor; x-z horizontal, about the floor point under the
    clip's mean pelvis)."""
    return _pitched(_rolled(cam_points, -roll_deg), pitch_deg) + [0.0, height_m, distance_m]


def view_of(truth: Truth, yaw_deg: float, height_m: float, distance_m: float, pitch_deg: float = 0.0) -> np.ndarray:
    """:func:`camera_view` of a truth clip ``[F, 15, 3]``."""
    return camera_view(truth.positions, yaw_deg, height_m, distance_m, pitch_deg)


def project(cam_points: np.ndarray, focal_px: float, image_size: tuple[int, int]) -> np.ndarray:
    """Pixels ``[..., 2]`` of camera-aligned points: u = cx + f·x/z, v = cy − f·y/z."""
    z = cam_points[..., 2]
    return np.stack([image_size[0] / 2 + focal_px * cam_points[..., 0] / z,
                     image_size[1] / 2 - focal_px * cam_points[..., 1] / z], axis=-1)


def render(cam_points: np.ndarray, scenario: Scenario, focal_px: float, image_size: tuple[int, int],
           rng: np.random.Generator, extremities_cam: np.ndarray | None = None,
           hands_cam: np.ndarray | None = None, faces_cam: np.ndarray | None = None) -> list[KeypointFrame]:
    """Detector-like keypoint frames of camera-aligned points ``[F, 15, 3]`` (with the detector's own
    3D where ``scenario.world_sd_m`` > 0: :func:`detector_world`), and of the heels, toes, knuckles and
    face points ``extremities_cam [F, 14, 3]`` (``keypoint_layouts.EXTREMITIES`` order) where given:
    the same noise, dropout and left/right swaps (drawn after the body's, so its frames do not change);
    and of the hands' 21 points ``hands_cam [F, 2, 21, 3]`` where given (``Person.hands``, drawn last:
    :func:`~mocapdb.evaluation.hand_render.detected_hands`) and of the face mesh's head vertices ``faces_cam
    [F, N_HEAD, 3]`` where given (``Person.face``, drawn after the hands:
    :func:`~mocapdb.evaluation.face_render.detected_faces`)."""
    px, conf = _detected(project(cam_points[:, :N_KEYPOINTS_2D], focal_px, image_size), scenario, image_size, rng)
    swapped = rng.random(len(px)) < scenario.swap
    _swap(px, swapped, SWAP_PAIRS)
    world = detector_world(cam_points, scenario.world_sd_m, swapped, rng) if scenario.world_sd_m > 0 else None
    ends = None if extremities_cam is None else _extremities(extremities_cam, scenario, swapped, focal_px,
                                                             image_size, rng)
    hands = None if hands_cam is None else detected_hands(project(hands_cam, focal_px, image_size), hands_cam,
                                                          focal_px, scenario.noise_px > 0, scenario.dropout,
                                                          swapped, image_size, rng)
    faces = None if faces_cam is None else detected_faces(project(faces_cam, focal_px, image_size), faces_cam,
                                                          focal_px, scenario.noise_px > 0, rng)
    return [KeypointFrame(i, None, [Person(px[i], conf[i], world_m=None if world is None else world[i],
                                           extremities=None if ends is None else ends[i],
                                           hands=None if hands is None else hands[i],
                                           face=None if faces is None else faces[i])])
            for i in range(len(px))]


def _detected(px: np.ndarray, scenario: Scenario, image_size: tuple[int, int], rng: np.random.Generator
              ) -> tuple[np.ndarray, np.ndarray]:
    """Pixels ``[F, K, 2]`` with the scenario's noise, and their confidences ``[F, K]`` (0: dropped or
    outside the image, as a detector leaves them)."""
    px = px + rng.normal(scale=scenario.noise_px * image_size[1] / IMAGE_HEIGHT_PX, size=px.shape)
    conf = np.where(rng.random(px.shape[:2]) < scenario.dropout, 0.0, 0.9)
    inside = (px >= 0).all(axis=-1) & (px[..., 0] < image_size[0]) & (px[..., 1] < image_size[1])
    conf[~inside] = 0.0
    return px, conf


def _swap(values: np.ndarray, swapped: np.ndarray, pairs: list[tuple[int, int]]) -> None:
    """Exchange each pair's entries ``values [F, K, ...]`` in the ``swapped [F]`` frames, in place."""
    for right, left in pairs:
        values[swapped, right], values[swapped, left] = values[swapped, left].copy(), values[swapped, right].copy()


def _extremities(cam_points: np.ndarray, scenario: Scenario, swapped: np.ndarray, focal_px: float,
                 image_size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """``[F, 14, 3]`` x px, y px, confidence of camera-aligned extremity points (NaN: not rendered, unseen)."""
    px, conf = _detected(project(cam_points, focal_px, image_size), scenario, image_size, rng)
    conf[~np.isfinite(px).all(axis=-1)] = 0.0
    _swap(px, swapped, EXTREMITY_SWAP_PAIRS)
    _swap(conf, swapped, EXTREMITY_SWAP_PAIRS)
    px[conf == 0.0] = np.nan
    return np.concatenate([px, conf[..., None]], axis=-1)


def detector_world(cam_points: np.ndarray, sd_m: float, swapped: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """World landmarks ``[F, 14, 3]`` as a detector gives them (``data_specs/keypoint_formats.md``,
    "World landmarks") of camera-aligned points ``[F, 15, 3]``: metres about the hips' centre, image
    axes (x right, y down, z away) turned so that the ray through the hips is z. Each joint's error
    is a slow random walk back to 0 (AR(1) over :data:`WORLD_ERROR_FRAMES` frames), of SD ``sd_m``
    along that ray and :data:`WORLD_ACROSS_SHARE` of it across: a monocular model's depth is its
    weakest axis. Left and right are swapped in the ``swapped [F]`` frames, as the keypoints."""
    points = cam_points[:, :N_KEYPOINTS_2D] * [1.0, -1.0, 1.0]            # image axes
    hips = 0.5 * (points[:, KP["r_hip"]] + points[:, KP["l_hip"]])
    turns = np.stack([rotation_between(ray / np.linalg.norm(ray), Z_AXIS) for ray in hips])   # the ray onto z
    world = np.einsum("fij,fkj->fki", turns, points - hips[:, None])
    rho = np.exp(-1.0 / WORLD_ERROR_FRAMES)
    steps = rng.normal(size=world.shape) * (sd_m * np.array([WORLD_ACROSS_SHARE, WORLD_ACROSS_SHARE, 1.0]))
    gain = np.sqrt(1.0 - rho ** 2)   # e[f] = rho e[f-1] + gain steps[f], e[0] = steps[0]: stationary from the start
    error, _ = lfilter([gain], [1.0, -rho], steps, axis=0, zi=((1.0 - gain) * steps[0])[None])
    world = world + error
    _swap(world, swapped, SWAP_PAIRS)
    return world
