"""The head, hands and feet against synthetic truth (``mocapdb eval --ends``; ``data_specs/evaluation_bodies.md``,
"Head, hands and feet"): held-out clips re-posed on fixed bodies, their face, hand and foot points attached
to the clips' own head, hands and feet (:mod:`mocapdb.evaluation.end_truth`), rendered with the body
(:func:`~mocapdb.evaluation.heldout.render`), run through the engine as users run it, and scored by the
geodesic angle between the true and the estimated global rotation (view frame) of each humanoid end bone:

* **whole take**: the humanoid BVH of ``reconstruct`` (the engine as it runs for the track files, then the
  whole-take fit; forward kinematics of ``motion_bvh(…, rig="humanoid")``);
* **stream**: the default stream at lag 0, or another lag (the online take's ``end_quaternions`` on its
  rotations).

Each is also scored **not turned** (end rotations left at identity: the bone where its parent puts it),
what the end joints' own measure must beat.

The hands are given as BlazePose gives them (wrist, index and little-finger knuckles: ``hand_points=3``) or,
as ``detect --hands`` adds them, with the hand landmark model's 21 points a hand (``hand_points=21``,
:mod:`mocapdb.evaluation.hand_render`); with 21, each finger joint's bend is scored too (the absolute
difference of its flexion from the truth's, degrees; not turned: straight fingers).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mocapdb.core.formats.bvh import forward_kinematics
from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.geometry import matrix_to_quat
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import CAMERA_FROM_VIEW, PersonPose, motion_bvh
from mocapdb.core.skeleton import END_JOINTS, N_POINTS, PELVIS, stature_m
from mocapdb.evaluation.bodies import reshape_body
from mocapdb.evaluation.end_truth import EndTruth, end_points, face_mesh_points, load_end_truth
from mocapdb.evaluation.engine_runs import run_sequence, stream_config
from mocapdb.evaluation.gate import GATE_BODIES, GATE_CLIPS, MAX_FRAMES, GateBody, gate_engine_config
from mocapdb.evaluation.hand_render import bend_errors_deg, finger_medians, hands_world, motion_hand_points
from mocapdb.evaluation.heldout import EvalConfig, Scenario, Truth, camera_distance, camera_view, render
from mocapdb.evaluation.loso import LosoConfig, sample_truths
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig
from mocapdb.runtime.online_take import OnlineParams, OnlineTake
from mocapdb.runtime.world.fuse import fit_takes

HUMANOID_ENDS = ("RightFoot", "LeftFoot", "RightHand", "LeftHand", "Head")   # END_JOINTS order
GROUPS = {"head": (4,), "hands": (2, 3), "feet": (0, 1)}                      # rows of END_JOINTS
MESH_GROUPS = ("head, mesh seen", "head, no mesh")    # the head's frames with and without a face mesh
SCENARIOS = (Scenario("exact 2D"),
             Scenario("sigma 5 px + 10% dropout + 5% swaps", noise_px=5.0, dropout=0.1, swap=0.05))
ENDS_YAWS_DEG = (3.0, 63.0, 123.0, 183.0, 243.0, 303.0)   # all round, 3 deg off the database's 12 deg grid


@dataclass
class EndErrors:
    """Geodesic errors (degrees) per variant: ``[N, 5]`` rows of frames, END_JOINTS columns (NaN: no output)."""

    errors: dict[str, list[np.ndarray]] = field(default_factory=dict)
    # per variant the fingers' bend errors (degrees) ``[N, 2, 5, 3]`` (hand_render.bend_errors_deg), if scored
    fingers: dict[str, list[np.ndarray]] = field(default_factory=dict)
    # per variant which frames had a face mesh ``[N]`` (bool), if rendered
    meshes: dict[str, list[np.ndarray]] = field(default_factory=dict)

    def add(self, variant: str, errors_deg: np.ndarray, bends_deg: np.ndarray | None = None,
            mesh_seen: np.ndarray | None = None) -> None:
        self.errors.setdefault(variant, []).append(errors_deg)
        if bends_deg is not None:
            self.fingers.setdefault(variant, []).append(bends_deg)
        if mesh_seen is not None:
            self.meshes.setdefault(variant, []).append(mesh_seen)

    def extend(self, other: EndErrors) -> None:
        for mine, theirs in ((self.errors, other.errors), (self.fingers, other.fingers), (self.meshes, other.meshes)):
            for variant, rows in theirs.items():
                mine.setdefault(variant, []).extend(rows)

    def medians(self) -> dict[str, dict[str, float]]:
        """Per variant and :data:`GROUPS` entry the median error (degrees) over frames, views and sides; where
        face meshes were rendered also the head's where one was seen and where none was (:data:`MESH_GROUPS`)."""
        out = {}
        for variant, rows in self.errors.items():
            stacked = np.concatenate(rows) if rows else np.full((0, len(END_JOINTS)), np.nan)
            out[variant] = {group: _median(stacked[:, list(cols)]) for group, cols in GROUPS.items()}
            if variant in self.meshes:
                seen = np.concatenate(self.meshes[variant])
                head = stacked[:, GROUPS["head"][0]]
                out[variant].update(zip(MESH_GROUPS, (_median(head[seen]), _median(head[~seen]))))
        return out


def _median(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else float("nan")


def geodesic_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The angle (degrees) of the rotation between rotation matrices ``a`` and ``b`` ``[..., 3, 3]``
    (NaN where either is)."""
    q = matrix_to_quat(np.nan_to_num(np.swapaxes(a, -1, -2) @ b))
    angle = np.degrees(2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0])))
    return np.where(np.isfinite(a).all(axis=(-2, -1)) & np.isfinite(b).all(axis=(-2, -1)), angle, np.nan)


def end_globals(motion: Motion) -> np.ndarray:
    """``[F, 5, 3, 3]`` the humanoid end bones' global rotations (the motion's frame) as its BVH poses them."""
    bvh = motion_bvh(motion, rig="humanoid")
    return forward_kinematics(bvh, [bvh.names.index(n) for n in HUMANOID_ENDS])[1]


def view_rotation(yaw_deg: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> np.ndarray:
    """``[3, 3]`` the rotation taking the truth's world axes to a held-out camera's view frame (x right,
    y up, z towards the camera) for :func:`~mocapdb.evaluation.heldout.camera_view`'s turn and tilts."""
    points = np.zeros((1, N_POINTS + 3, 3))
    points[0, N_POINTS:] = np.eye(3)
    cam = camera_view(points, yaw_deg, 0.0, 0.0, pitch_deg, roll_deg)[0]
    return (cam[N_POINTS:] - cam[PELVIS]).T * CAMERA_FROM_VIEW[:, None]


class Estimates:
    """What an output gives over ``n`` frames, turned and not turned (rows 0, 1; NaN: no frame): the end
    globals ``ends [2, n, 5, 3, 3]`` (view frame) and, if ``fingers``, the hands' 21 points
    ``hands [2, n, 2, 21, 3]``."""

    def __init__(self, n: int, fingers: bool) -> None:
        self.fingers = fingers
        self.ends = np.full((2, n, len(END_JOINTS), 3, 3), np.nan)
        self.hands = np.full((2, n if fingers else 0, 2, 21, 3), np.nan)

    def put(self, index: np.ndarray, motion: Motion, keep: np.ndarray | slice = slice(None)) -> None:
        """Frames ``index`` of the outputs from ``motion`` (its frames ``keep``), turned and not turned (its end
        and finger rotations dropped)."""
        for k, m in enumerate((motion, replace(motion, end_rotations=None, finger_rotations=None))):
            self.ends[k, index] = end_globals(m)[keep]
            if self.fingers:
                self.hands[k, index] = motion_hand_points(m)[keep]


def whole_take_ends(db: MotionDatabase, engine: EngineConfig, frames: list[KeypointFrame], fps: float,
                    fingers: bool = False) -> Estimates:
    """The main track's outputs (:class:`Estimates`; the hands' points if ``fingers``) in the humanoid BVH
    ``reconstruct`` writes of ``frames``."""
    run = run_sequence(Engine(db, engine.for_track_files()), frames)
    fitted = fit_takes(run.recordings, fps)
    out = Estimates(len(frames), fingers)
    if fitted:
        motion = max((rec.motion(fps) for rec in fitted), key=len)
        index = motion.first_frame + np.arange(len(motion))
        keep = (index >= 0) & (index < len(frames))
        out.put(index[keep], motion, keep)
    return out


def stream_ends(db: MotionDatabase, engine: EngineConfig, frames: list[KeypointFrame], lag_frames: int = 0,
                fingers: bool = False) -> Estimates:
    """As :func:`whole_take_ends` for the default stream at lag 0 (the online take's rotations,
    ``end_quaternions`` and ``finger_quaternions``; one person: each frame's first pose)."""
    config = stream_config(engine)
    online = OnlineTake(config.fps, OnlineParams(lag_frames=lag_frames), (config.focal_px, *config.center_px))
    run = Engine(db, config)
    poses: list[PersonPose | None] = [None] * len(frames)
    for i, frame in enumerate(frames):
        due = online.push(i, i / config.fps, run.step(frame))
        for index, _, people in due + (online.flush() if i == len(frames) - 1 else []):
            poses[index] = people[0] if people else None
    out = Estimates(len(frames), fingers)
    have = [i for i, p in enumerate(poses) if p is not None and p.end_quaternions is not None]
    if have:
        kept = [p for p in poses if p is not None and p.end_quaternions is not None]
        turned = [p.finger_quaternions for p in kept]
        motion = Motion(np.array([p.quaternions for p in kept]), np.array([p.root_m for p in kept]) * CAMERA_FROM_VIEW,
                        config.fps, "view", end_rotations=np.array([p.end_quaternions for p in kept]),
                        finger_rotations=None if any(f is None for f in turned) else np.array(turned))
        out.put(np.array(have), motion)
    return out


def view_frames(posed_m: np.ndarray, truth: EndTruth, stature: float, yaw_deg: float, scenario: Scenario,
                config: EvalConfig, hand_points: int = 3, face_mesh: bool = False
                ) -> tuple[list[KeypointFrame], np.ndarray]:
    """A body ``posed_m [F, 15, 3]`` with its end points (and with ``hand_points`` 21, its hands' 21 points; with
    ``face_mesh``, its face mesh: :func:`~mocapdb.evaluation.end_truth.face_mesh_points`) seen from ``yaw_deg``
    (the held-out camera, 1.5 m high, level) and rendered under ``scenario``: the keypoint frames, and the true
    end rotations ``[F, 5, 3, 3]`` in the view frame."""
    ends = end_points(posed_m, truth.rotations, stature)
    n_ends = N_POINTS + ends.shape[1]
    hands = (np.zeros((len(posed_m), 0, 3)) if hand_points == 3 or truth.hand_points_m is None
             else hands_world(posed_m, truth.rotations, truth.hand_points_m, stature).reshape(len(posed_m), 42, 3))
    n_hands = n_ends + hands.shape[1]
    faces = face_mesh_points(posed_m, truth.rotations, stature) if face_mesh else np.zeros((len(posed_m), 0, 3))
    points = np.concatenate([posed_m, ends, hands, faces], axis=1)
    distance = camera_distance(posed_m, yaw_deg, config)
    cam = camera_view(points, yaw_deg, scenario.camera_height_m, distance, scenario.pitch_deg, scenario.roll_deg)
    rng = np.random.default_rng((config.seed, int(yaw_deg * 10)))
    frames = render(cam[:, :N_POINTS], scenario, config.focal_px, config.image_size, rng, cam[:, N_POINTS:n_ends],
                    cam[:, n_ends:n_hands].reshape(len(posed_m), 2, 21, 3) if hands.shape[1] else None,
                    cam[:, n_hands:] if face_mesh else None)
    view = view_rotation(yaw_deg, scenario.pitch_deg, scenario.roll_deg)
    return frames, np.einsum("ij,fkjl->fkil", view, truth.rotations)


def variants(lag_frames: int = 0) -> tuple[str, ...]:
    """The outputs scored: the whole take and the stream at ``lag_frames``, each turned and not turned."""
    return ("whole take", "whole take, not turned", f"stream lag {lag_frames}", f"stream lag {lag_frames}, not turned")


def score_ends(db: MotionDatabase, posed_m: np.ndarray, truth: EndTruth, stature: float, yaw_deg: float,
               scenario: Scenario, config: EvalConfig, lag_frames: int = 0, hand_points: int = 3,
               face_mesh: bool = False) -> EndErrors:
    """One body, view and scenario through the engine: the errors of every output (:func:`variants`; the
    fingers' bends too with ``hand_points`` 21; the face mesh rendered with ``face_mesh``)."""
    frames, true_view = view_frames(posed_m, truth, stature, yaw_deg, scenario, config, hand_points, face_mesh)
    engine = gate_engine_config(config)
    out = EndErrors()
    true_hands = truth.hand_points_m if hand_points == 21 else None
    fingers = true_hands is not None
    outputs = (whole_take_ends(db, engine, frames, config.fps, fingers),
               stream_ends(db, engine, frames, lag_frames, fingers))
    mesh_seen = np.array([bool(f.people) and f.people[0].face is not None and f.people[0].face[1, 3] > 0
                          for f in frames]) if face_mesh else None
    for k, variant in enumerate(variants(lag_frames)):
        estimate = outputs[k // 2]
        out.add(variant, geodesic_deg(estimate.ends[k % 2], true_view),
                None if true_hands is None else bend_errors_deg(estimate.hands[k % 2], true_hands), mesh_seen)
    return out


def ends_truths(bvh_files: Iterable[Path], max_frames: int, yaws_deg: tuple[float, ...], fps: float
                ) -> list[tuple[Truth, EndTruth]]:
    """Each held-out clip's body truth (:func:`~mocapdb.evaluation.loso.sample_truths`) and end truth."""
    files = list(bvh_files)
    config = LosoConfig(max_frames=max_frames, max_clips=len(files), yaws_per_clip=len(yaws_deg), yaws_deg=yaws_deg,
                        eval=EvalConfig(fps=fps))
    truths = sample_truths(files, config)
    return [(t, load_end_truth(f, fps, max_frames)) for t, f in zip(truths, sorted(files))]


def evaluate_ends(db: MotionDatabase, bvh_files: Iterable[Path], bodies: tuple[GateBody, ...] = GATE_BODIES,
                  scenarios: tuple[Scenario, ...] = SCENARIOS, yaws_deg: tuple[float, ...] = ENDS_YAWS_DEG,
                  max_frames: int = MAX_FRAMES, config: EvalConfig | None = None, lag_frames: int = 0,
                  hand_points: int = 3, face_mesh: bool = False) -> dict[str, EndErrors]:
    """Every clip on every body from every yaw under each scenario (the stream at ``lag_frames``; the hands
    as ``hand_points`` 3 or 21 points; the face mesh rendered with ``face_mesh``): the errors per scenario name."""
    config = config or EvalConfig()
    out = {s.name: EndErrors() for s in scenarios}
    for truth, ends in ends_truths(bvh_files, max_frames, yaws_deg, config.fps):
        for body in bodies:
            lengths = body.lengths_m()
            posed, stature = reshape_body(truth.source_joints(), lengths), float(stature_m(lengths))
            for scenario in scenarios:
                for yaw in yaws_deg:
                    out[scenario.name].extend(score_ends(db, posed, ends, stature, yaw, scenario, config, lag_frames,
                                                         hand_points, face_mesh))
    return out


def format_ends(results: dict[str, EndErrors]) -> str:
    """A Markdown table: a row per scenario and variant, the median geodesic error (degrees) per group."""
    groups = list(GROUPS) + (list(MESH_GROUPS) if any(e.meshes for e in results.values()) else [])
    lines = ["| input | output | " + " | ".join(f"{g} deg" for g in groups) + " |", "|---|---|" + "---|" * len(groups)]
    for scenario, errors in results.items():
        for variant, medians in errors.medians().items():
            lines.append(f"| {scenario} | {variant} | " + " | ".join(f"{medians[g]:.1f}" for g in groups) + " |")
    fingers = [(s, v, finger_medians(rows)) for s, e in results.items() for v, rows in e.fingers.items()]
    if fingers:
        lines += ["", "| input | output | " + " | ".join(f"{f} bend deg" for f in fingers[0][2]) + " |",
                  "|---|---|" + "---|" * len(fingers[0][2])]
        lines += [f"| {s} | {v} | " + " | ".join(f"{m:.1f}" for m in medians.values()) + " |"
                  for s, v, medians in fingers]
    return "\n".join(lines)


def gate_clip_files(bvh_dir: Path) -> list[Path]:
    """The accuracy gate's held-out clips in ``bvh_dir``."""
    return [bvh_dir / f"{clip}.bvh" for clip in GATE_CLIPS]


GATE_ENDS_BODY = GATE_BODIES[1]   # short legs: the body furthest from the engine's assumed size
GATE_ENDS_YAWS_DEG = (3.0, 93.0, 183.0, 273.0)
GATE_ENDS_VARIANTS = ("whole take", "stream lag 0")
# the groups the gate checks and their figures' names (and, from the hands' 21 points, ``hands_21_points``)
GATE_ENDS_GROUPS = {**{group: group for group in GROUPS}, MESH_GROUPS[0]: "head_mesh_seen",
                    MESH_GROUPS[1]: "head_no_mesh"}
GATE_ENDS_FIGURES = tuple(GATE_ENDS_GROUPS.values()) + ("hands_21_points",)
# The part's threshold margin (relative, absolute degrees): 0.05 px of noise on the exact input (3 draws)
# moved its figures by up to +4.4 % (the stream's feet; the others within 1.5 %), beyond the gate's 3 %
GATE_MARGIN = (0.10, 0.1)


def gate_figures(db: MotionDatabase, bvh_dir: Path) -> dict[str, float]:
    """The accuracy gate's part ``ends``: the gate's clips on :data:`GATE_ENDS_BODY` from
    :data:`GATE_ENDS_YAWS_DEG`, exact 2D with the face mesh rendered; figures ``ends/<variant>/<group>_deg``
    (median geodesic error, degrees) of :data:`GATE_ENDS_VARIANTS`: :data:`GROUPS` and the head where a mesh is
    seen and where none is (``head_mesh_seen``, ``head_no_mesh``); and rendered again with the hands' 21 points
    (``detect --hands``), the hands' (``hands_21_points``)."""
    clips, scenario = gate_clip_files(bvh_dir), SCENARIOS[0]
    medians = evaluate_ends(db, clips, (GATE_ENDS_BODY,), (scenario,), GATE_ENDS_YAWS_DEG,
                            face_mesh=True)[scenario.name].medians()
    with_hands = evaluate_ends(db, clips, (GATE_ENDS_BODY,), (scenario,), GATE_ENDS_YAWS_DEG,
                               hand_points=21)[scenario.name].medians()
    figures = {f"ends/{variant}/{key}_deg": medians[variant][group] for variant in GATE_ENDS_VARIANTS
               for group, key in GATE_ENDS_GROUPS.items()}
    return figures | {f"ends/{variant}/hands_21_points_deg": with_hands[variant]["hands"]
                      for variant in GATE_ENDS_VARIANTS}
