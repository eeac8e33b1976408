"""The accuracy gate (``tools/accuracy_gate.py``; contract ``data_specs/accuracy_gate.md``): a fixed,
fast evaluation whose figures CI compares with stored thresholds, so that a change losing accuracy fails.

Synthetic part (:func:`evaluate_bodies`): the held-out CMU clips :data:`GATE_CLIPS` (none of them in
``demo/sample.db``), at most :data:`MAX_FRAMES` frames from each one's middle, each seen from the 12
yaws :data:`GATE_YAWS_DEG` (:func:`mocapdb.evaluation.loso.sample_truths`), their source joints re-posed on
the fixed unusual bodies :data:`GATE_BODIES` (:func:`mocapdb.evaluation.bodies.reshape_body`), seen
by the held-out camera 1.5 m high (:mod:`mocapdb.evaluation.heldout`), rendered exactly (no noise,
nothing dropped) in the keypoint layout of mocap-derived 2D such as HumanEva's: no nose
(:data:`DROPPED`), no heels or toes (never rendered). The engine runs refined (the default); its
per-frame output and its whole take are scored over the 13 joints below the head
(:class:`mocapdb.evaluation.reconstruction.VariantStats`), pooled per body and per action; so is the
default stream (the online take, as ``live`` sends it) at :data:`STREAM_LAGS`, from every
:data:`STREAM_YAW_EVERY`-th yaw.

Real part (:func:`real_take_figures`): every camera of a calibrated Pose2Sim take alone
(:func:`mocapdb.evaluation.real_take.evaluate_real_take`), the mean over the cameras of :data:`REAL_RUNS`.

Figures are named ``part/row/variant/metric`` (all: lower is better); :func:`compare` checks them
against the thresholds (a missing or non-finite figure fails).
"""
from __future__ import annotations

import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mocapdb.core.formats.database import MotionDatabase
from mocapdb.core.formats.keypoints import KeypointFrame
from mocapdb.core.skeleton import KP, MEASURED_BONE_NAMES, universal_bone_lengths_m
from mocapdb.evaluation.bodies import Body, reshape_body
from mocapdb.evaluation.engine_runs import run_sequence, stream_runs, track_files_take
from mocapdb.evaluation.floor import FloorIndex, database_floor
from mocapdb.evaluation.heldout import EvalConfig, Scenario, Truth, camera_distance, camera_view, render
from mocapdb.evaluation.loso import LosoConfig, sample_truths
from mocapdb.evaluation.real_take import evaluate_real_take
from mocapdb.evaluation.reconstruction import (
    TAKE_VARIANT,
    VariantStats,
    View,
    stream_variant,
    variant_config,
)
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig

# clip (SUBJECT_TRIAL of ../shared/data/cmu_bvh): action. The shared set's only run (002_03) is in the
# demo database; 007_12 (brisk walk, pelvis 1.9 m/s median) is the fastest held-out locomotion.
GATE_CLIPS = {"007_01": "walk", "007_12": "brisk walk", "002_05": "punching"}  # CMU's "punch/strike"
MAX_FRAMES = 240     # per clip, at the evaluation's 24 fps
GATE_YAWS_DEG = tuple(3.0 + 30.0 * k for k in range(12))  # all round, 3° off the database's 12° grid
DROPPED = ("head",)  # the universal head keypoint is the nose
EXACT = Scenario("exact 2D, camera 1.5 m, no nose, heels or toes")
STREAM_LAGS = (0, 6)      # the default stream (the online take) at these lags (frames; lag 3: leave-one-subject-out)
STREAM_YAW_EVERY = 4      # ... from every 4th of the clip's yaws (3 of 12: the gate's time)
VARIANTS = ("refined", TAKE_VARIANT) + tuple(stream_variant(lag) for lag in STREAM_LAGS)
BODY_METRICS = ("mpjpe13_cm", "pa_mpjpe13_cm", "bone_error_cm")  # VariantStats.summary() keys
CONTEXT_METRICS = ("floor_mpjpe_cm",)  # reported, not gated: the database floor is the database's, not the engine's
# (variant, size mode) of the real take's runs, and its figures: name, key path in a run's report
REAL_RUNS = (("refined", "nothing_given"), (TAKE_VARIANT, "nothing_given"), (TAKE_VARIANT, "camera_height_given"),
             (stream_variant(0), "nothing_given"))
REAL_METRICS = (("mpjpe13_cm", ("mpjpe_cm",)), ("pa_mpjpe13_cm", ("pa_mpjpe_cm",)),
                ("bone_error_cm", ("bone_length_cm", "mean_error_7")),
                ("root_error_pct_distance", ("root_error_pct_distance",)))
COLUMN_NAMES = {"mpjpe13_cm": "MPJPE cm", "pa_mpjpe13_cm": "PA-MPJPE cm", "bone_error_cm": "bone error cm",
                "floor_mpjpe_cm": "database floor cm", "root_error_pct_distance": "root error % of distance"}


@dataclass(frozen=True)
class GateBody:
    """A fixed unusual body: the universal skeleton scaled to ``height_m`` tall, its bones times set
    factors (bone name: factor, 1 when not named; a :class:`~mocapdb.evaluation.bodies.Body`), then
    bones of a set length (``fixed_m``, metres). Unusual against the engine's prior, which is centred
    on the universal proportions (CMU's own are not: its shanks are about 20 % longer)."""

    name: str
    height_m: float
    factors: tuple[tuple[str, float], ...] = ()
    fixed_m: tuple[tuple[str, float], ...] = ()

    def lengths_m(self) -> np.ndarray:
        """This body's bone lengths ``[8]`` (metres, MEASURED_BONE_NAMES order)."""
        named = dict(self.factors)
        factors = np.array([named.get(name, 1.0) for name in MEASURED_BONE_NAMES])
        lengths = Body(self.height_m, factors).bone_lengths_m(universal_bone_lengths_m())
        for name, length_m in self.fixed_m:
            lengths[MEASURED_BONE_NAMES.index(name)] = length_m
        return lengths


GATE_BODIES = (
    GateBody("narrow hips", 1.75, fixed_m=(("hip_width", 0.095),)),  # HumanEva's mocap hip joint centres
    GateBody("short legs", 1.65, factors=(("thigh", 0.88), ("shank", 0.88))),
    GateBody("long arms", 1.80, factors=(("upper_arm", 1.12), ("forearm", 1.12))),
)


def gate_truths(bvh_dir: Path) -> list[Truth]:
    """The :data:`GATE_CLIPS` of ``bvh_dir``, capped and given their yaws (module docstring)."""
    files = [bvh_dir / f"{clip}.bvh" for clip in GATE_CLIPS]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise FileNotFoundError(f"accuracy gate clips missing: {', '.join(missing)}")
    config = LosoConfig(max_frames=MAX_FRAMES, max_clips=len(files), yaws_per_clip=len(GATE_YAWS_DEG),
                        yaws_deg=GATE_YAWS_DEG)
    return sample_truths(files, config)


def without_keypoints(frames: list[KeypointFrame], names: Collection[str]) -> list[KeypointFrame]:
    """``frames`` with the keypoints ``names`` unseen (confidence 0, NaN position), in place."""
    index = [KP[name] for name in names]
    for frame in frames:
        for person in frame.people:
            person.points_px[index], person.confidence[index] = np.nan, 0.0
    return frames


def gate_engine_config(config: EvalConfig) -> EngineConfig:
    """The engine as the held-out evaluation runs it refined (its whole take: as ``reconstruct`` runs
    it, :func:`~mocapdb.evaluation.engine_runs.track_files_take`)."""
    camera = replace(config.engine, fps=config.fps, focal_px=config.focal_px, image_size=config.image_size)
    return variant_config(camera, True)


def score_view(db: MotionDatabase, positions_m: np.ndarray, yaw_deg: float, floor_m: np.ndarray,
               config: EvalConfig, stream: bool = True) -> dict[str, VariantStats]:
    """World joints ``[F, 15, 3]`` seen from ``yaw_deg``, without :data:`DROPPED`, through the engine:
    per :data:`VARIANTS` its stats (``floor_m [F]``: the database floor per frame; the stream's left
    empty unless ``stream``)."""
    height = EXACT.camera_height_m
    distance = camera_distance(positions_m, yaw_deg, config)
    view = View(camera_view(positions_m, yaw_deg, height, distance), height, distance, 0.0)
    rng = np.random.default_rng(config.seed)  # exact input: nothing is drawn from it
    frames = without_keypoints(render(view.cam, EXACT, config.focal_px, config.image_size, rng), DROPPED)
    engine = gate_engine_config(config)
    stats = {name: VariantStats() for name in VARIANTS}
    stats["refined"].add(run_sequence(Engine(db, engine), frames), view, floor_m, frames, config)
    take = track_files_take(db, engine, frames, config.fps)
    stats[TAKE_VARIANT].add(take, view, floor_m, frames, config, person_frames=len(frames))
    for lag, run in (stream_runs(db, engine, frames, STREAM_LAGS) if stream else {}).items():
        stats[stream_variant(lag)].add(run, view, floor_m, frames, config, person_frames=len(frames))
    return stats


def evaluate_bodies(db: MotionDatabase, bvh_dir: Path, config: EvalConfig | None = None
                    ) -> dict[tuple[str, str], dict[str, VariantStats]]:
    """Every gate clip on every gate body from its yaws: stats per (body, action) and variant."""
    config = config or EvalConfig()
    index = FloorIndex.from_positions(db.positions)
    out: dict[tuple[str, str], dict[str, VariantStats]] = {}
    for truth in gate_truths(bvh_dir):
        action = GATE_CLIPS[truth.name.split("@")[0]]
        for body in GATE_BODIES:
            posed = reshape_body(truth.source_joints(), body.lengths_m())
            floor = database_floor(index, posed).mpjpe_m
            stats = out.setdefault((body.name, action), {name: VariantStats() for name in VARIANTS})
            for k, yaw in enumerate(truth.yaws_deg or ()):
                for name, view_stats in score_view(db, posed, yaw, floor, config, k % STREAM_YAW_EVERY == 0).items():
                    stats[name].extend(view_stats)
    return out


def body_figures(stats: Mapping[tuple[str, str], Mapping[str, VariantStats]]) -> dict[str, float]:
    """Figures ``bodies/<body>/<variant>/<metric>`` and ``actions/<action>/…`` (pooled over the
    other), metrics :data:`BODY_METRICS` and :data:`CONTEXT_METRICS`."""
    figures = {}
    for part, axis in (("bodies", 0), ("actions", 1)):
        for row in dict.fromkeys(key[axis] for key in stats):
            for variant in VARIANTS:
                pooled = VariantStats()
                for key, by_variant in stats.items():
                    if key[axis] == row:
                        pooled.extend(by_variant[variant])
                summary = pooled.summary()
                for metric in BODY_METRICS + CONTEXT_METRICS:
                    figures[f"{part}/{row}/{variant}/{metric}"] = _number(summary[metric])
    return figures


def real_take_figures(db: MotionDatabase, folder: Path) -> dict[str, float]:
    """Figures ``real take/<variant>, <size mode>/<metric>``: the mean over the take's cameras."""
    report = evaluate_real_take(db, folder)
    figures = {}
    for variant, mode in REAL_RUNS:
        runs = [entry["runs"][variant][mode] for entry in report["cameras"].values()]
        for metric, path in REAL_METRICS:
            values = [_number(_lookup(run, path)) for run in runs]
            figures[f"real take/{variant}, {mode.replace('_', ' ')}/{metric}"] = float(np.mean(values))
    return figures


def _lookup(report: Mapping, path: tuple[str, ...]) -> object:
    for key in path:
        report = report[key]
    return report


def _number(value: object) -> float:
    """``value`` as a float; NaN when it is not a number (None: a summary's missing figure)."""
    return float(value) if isinstance(value, (int, float)) else float("nan")


@dataclass(frozen=True)
class Check:
    """One figure against its threshold (at most ``limit``; ``measured``: its value when the threshold
    was set); ``skipped``: its part did not run."""

    name: str
    value: float | None
    limit: float
    measured: float | None = None
    skipped: bool = False

    @property
    def ok(self) -> bool:
        """Passed: skipped, or a finite value at most the limit (missing or NaN fails)."""
        if self.skipped:
            return True
        return self.value is not None and math.isfinite(self.value) and self.value <= self.limit

    def line(self) -> str:
        """``PASS|FAIL|SKIP  name: value ≤ limit (measured …)``."""
        verdict = "SKIP" if self.skipped else "PASS" if self.ok else "FAIL"
        value = "missing" if self.value is None else f"{self.value:.2f}"
        measured = "" if self.measured is None else f" (measured {self.measured:.2f})"
        return f"{verdict}  {self.name}: {value} ≤ {self.limit:.2f}{measured}"


def compare(figures: Mapping[str, float | None], thresholds: Mapping[str, Mapping[str, float]],
            skipped_parts: Collection[str] = ()) -> list[Check]:
    """A :class:`Check` per entry of ``thresholds`` (figure name: ``{"max": largest value allowed,
    "measured": …}``), its value from ``figures`` (None when absent); a figure whose part (the name
    up to its first ``/``) is in ``skipped_parts`` is skipped."""
    return [Check(name, figures.get(name), float(entry["max"]), entry.get("measured"),
                  name.split("/")[0] in skipped_parts) for name, entry in thresholds.items()]


def thresholds_from(figures: Mapping[str, float], relative: float, absolute: float) -> dict[str, dict[str, float]]:
    """Thresholds for the gated ``figures`` (not :data:`CONTEXT_METRICS`): ``{"measured": value, "max":
    value × (1 + relative) + absolute}``, the value rounded to 0.01 first (so the file's own ``measured`` gives
    its ``max`` again), the threshold to 0.01; ValueError on a non-finite figure."""
    bad = [name for name, value in figures.items() if not math.isfinite(value)]
    if bad:
        raise ValueError(f"cannot set thresholds from non-finite figures: {', '.join(bad)}")
    return {name: {"measured": round(value, 2), "max": round(round(value, 2) * (1.0 + relative) + absolute, 2)}
            for name, value in figures.items() if gated(name)}


def gated(name: str) -> bool:
    """Whether figure ``name`` is gated (its metric not one of :data:`CONTEXT_METRICS`)."""
    return name.rsplit("/", 1)[-1] not in CONTEXT_METRICS


def format_table(figures: Mapping[str, float]) -> str:
    """A markdown table of ``figures``: a row per name without its metric, a column per metric."""
    if not figures:
        return "(no figures)"
    rows: dict[str, dict[str, float]] = {}
    for name, value in figures.items():
        row, metric = name.rsplit("/", 1)
        rows.setdefault(row, {})[metric] = value
    metrics = list(dict.fromkeys(metric for cells in rows.values() for metric in cells))
    lines = ["| figures | " + " | ".join(COLUMN_NAMES.get(m, m) for m in metrics) + " |",
             "|---" * (len(metrics) + 1) + "|"]
    for row, cells in rows.items():
        values = (f"{cells[m]:.2f}" if m in cells and math.isfinite(cells[m]) else "–" for m in metrics)
        lines.append(f"| {row} | " + " | ".join(values) + " |")
    return "\n".join(lines)
