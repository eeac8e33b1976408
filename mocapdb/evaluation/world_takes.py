"""The takes of ``mocapdb eval --world`` (:mod:`mocapdb.evaluation.world`): several held-out clips
rendered together by one pinhole camera.

A scenario (:class:`WorldScenario`) places its people (:class:`PersonSpec`) on the floor plan;
:func:`build_take` draws the camera's height (:data:`CAMERA_HEIGHT_RANGE_M`), each person's body
(:func:`body_lengths_m`), clip and jitter, and renders every person with detector-like noise
(:func:`mocapdb.evaluation.heldout.render`) into one take (:class:`WorldTake`) with its truth
(:class:`TruePerson`, :class:`Camera`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.skeleton import KP, N_KEYPOINTS_2D, PELVIS, bone_lengths_m, stature_m
from mocapdb.evaluation.bodies import CHILD_HEIGHT_RANGE_M, HEIGHT_RANGE_M, child_proportions, reshape_body, sample_body
from mocapdb.evaluation.heldout import Scenario, Truth, camera_to_world, camera_view, project, render
from mocapdb.runtime.engine_config import EngineConfig

CAMERA_HEIGHT_RANGE_M = (1.0, 2.0)  # drawn per take
BOX_HEIGHT_M = 0.4
ANKLES = [KP["r_ankle"], KP["l_ankle"]]


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
    source = truth.source_joints()
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
    long_clips = [t for t in truths if len(t.source_joints()) >= config.frames]
    walkers = long_clips or sorted(truths, key=lambda t: -len(t.source_joints()))
    n_frames = min(config.frames, min(len(t.source_joints()) for t in walkers))
    noise = Scenario(scenario.name, noise_px=scenario.noise_px, dropout=scenario.dropout, swap=scenario.swap)
    people = []
    for i, spec in enumerate(scenario.people):
        pool = truths if spec.still else walkers
        truth = pool[(scenario_index + repeat * len(scenario.people) + i) % len(pool)]
        spec = _jittered(spec, rng) if config.jitter else spec
        lengths = body_lengths_m(truth.source_joints(), spec.kind, rng)
        cam = person_view(truth, spec, lengths, n_frames, camera, config.focal_px, config.image_size)
        rendered = render(cam, noise, config.focal_px, config.image_size,
                          np.random.default_rng((config.seed, scenario_index, repeat, i)))
        people.append(TruePerson(spec, truth.name, float(stature_m(lengths)), cam,
                                 np.array([f.people[0].points_px for f in rendered]),
                                 np.array([f.people[0].confidence for f in rendered])))
    frames = [KeypointFrame(k, None, [Person(p.points_px[k], p.confidence[k]) for p in people])
              for k in range(n_frames)]
    return WorldTake(scenario, repeat, camera, people, frames)
