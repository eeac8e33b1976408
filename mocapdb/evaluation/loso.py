"""`mocapdb eval --leave-one-subject-out`: every subject held out in turn from its own database.

Subject = the number before the first ``_`` of a BVH file name (``002_05.bvh`` → 2). For each
subject a database is built from all the other subjects' files with the normal builder (default
:class:`~mocapdb.builder.config.BuildConfig` except ``workers``, and ``clusters``/``landmarks`` when
given) into a temporary folder that is removed afterwards, and a bounded sample of the subject's
own clips is evaluated against it (:mod:`mocapdb.evaluation.reconstruction`: both engine variants on the same
rendered frames, the database floor of that fold's database):

* per clip the longest continuous run (:func:`~mocapdb.core.clips.process_clip`), at most
  ``max_frames`` frames from its middle; at most ``max_clips`` clips per subject, evenly spaced in
  sorted order;
* ``yaws_per_clip`` yaws per clip off the database's 12° grid, taken in turn from
  :data:`LOSO_YAWS` (clip i: entries 2i, 2i+1, … modulo 8);
* the camera stands :attr:`EvalConfig.camera_distance_m` (5 m) from the clip's mean pelvis, or
  further, so that it stays :attr:`EvalConfig.min_clearance_m` (3 m) from every pelvis of the
  turned clip (clips that travel towards the camera);
* :data:`LOSO_SCENARIOS`;
* the default stream (the online take) at :data:`STREAM_LAGS` beside the per-frame stream (``refined``).

Figures are per fold and overall (all folds' frames pooled).
"""
from __future__ import annotations

import csv
import logging
import re
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from mocapdb.builder.config import BuildConfig
from mocapdb.builder.pipeline import build
from mocapdb.builder.read_stage import find_sources
from mocapdb.core import domains as D
from mocapdb.core.clips import process_clip
from mocapdb.core.errors import UsageError
from mocapdb.core.formats.database_reader import load_database
from mocapdb.evaluation.heldout import DETECTOR_WORLD_SD_M, Scenario, Truth
from mocapdb.evaluation.reconstruction import (
    EvalConfig,
    ScenarioResult,
    compute_floors,
    engine_summary,
    evaluate_scenario,
    stream_variant,
)

LOSO_YAWS = (6.0, 51.0, 99.0, 141.0, 186.0, 231.0, 279.0, 321.0)  # 3° or 6° off the 12° grid
LOSO_SCENARIOS = (
    Scenario("varied bodies, clean, camera 1.5 m", body="varied"),
    Scenario("varied bodies, clean, pitched 15 deg", pitch_deg=15.0, body="varied"),
    Scenario("varied bodies, sigma 5 px + 10% dropout + 5% swaps", noise_px=5.0, dropout=0.1, swap=0.05,
             body="varied"),
    Scenario("varied bodies, clean, camera height 1.5 m given", body="varied", camera_height_given=True),
    Scenario("universal body, clean, camera 1.5 m"),
    Scenario("varied bodies, sigma 5 px + 10% dropout + 5% swaps, detector 3D", noise_px=5.0, dropout=0.1,
             swap=0.05, body="varied", world_sd_m=DETECTOR_WORLD_SD_M),
)

STREAM_LAGS = (0, 3, 6)  # the default stream is scored at these lags (frames) beside the per-frame stream
LOG = logging.getLogger(__name__)
DESCRIPTIONS_FILE = "cmu_motion_descriptions.csv"


@dataclass
class LosoConfig:
    max_frames: int = D.MAX_FRAMES.default          # per clip, from its middle (at the database frame rate)
    max_clips: int = D.MAX_CLIPS.default             # per subject, evenly spaced in sorted order
    yaws_per_clip: int = 2
    yaws_deg: tuple[float, ...] = LOSO_YAWS
    subjects: tuple[int, ...] | None = None  # held out in turn; None: every subject
    build: BuildConfig = field(default_factory=lambda: BuildConfig(workers=2))
    eval: EvalConfig = field(default_factory=lambda: EvalConfig(scenarios=LOSO_SCENARIOS, stream_lags=STREAM_LAGS))

    @classmethod
    def quick(cls, **changes) -> LosoConfig:
        """2 clips per subject, 120 frames each, the first 2 scenarios."""
        config = cls(**{"max_clips": 2, "max_frames": 120, **changes})
        config.eval = replace(config.eval, scenarios=config.eval.scenarios[:2])
        return config


def subject_of(path: str | Path) -> int | None:
    """The subject number of a BVH file: the number before the first ``_`` of its name, else None."""
    match = re.fullmatch(r"0*(\d+)_.*", Path(path).name)
    return int(match.group(1)) if match else None


def trial_of(path: str | Path) -> int | None:
    """The trial number after the first ``_`` (``002_05.bvh`` → 5), else None."""
    match = re.fullmatch(r"\d+_0*(\d+)\D?.*", Path(path).stem)
    return int(match.group(1)) if match else None


def group_by_subject(files: list[Path]) -> dict[int, list[Path]]:
    """Files by subject, sorted; every file must carry a subject number."""
    groups: dict[int, list[Path]] = {}
    unnamed = [f for f in files if subject_of(f) is None]
    if unnamed:
        raise UsageError(f"--leave-one-subject-out needs files named SUBJECT_TRIAL.bvh (e.g. 002_05.bvh); "
                         f"no subject number in {', '.join(f.name for f in unnamed[:5])}")
    for f in sorted(files):
        if (subject := subject_of(f)) is not None:  # every file has one (checked above)
            groups.setdefault(subject, []).append(f)
    return dict(sorted(groups.items()))


def load_descriptions(sources: list[str]) -> dict[tuple[int, int], str]:
    """``(subject, trial)`` → motion description from a :data:`DESCRIPTIONS_FILE` in a source folder
    (or next to a source file); empty when there is none."""
    out: dict[tuple[int, int], str] = {}
    for src in sources:
        path = Path(src)
        table = (path if path.is_dir() else path.parent) / DESCRIPTIONS_FILE
        if not table.is_file():
            continue
        with table.open(newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                try:
                    key = (int(row["Subject"]), int(row["Trial #"]))
                except (KeyError, TypeError, ValueError):
                    continue
                out.setdefault(key, (row.get("Motion Description") or "").strip())
    return out


def _description(descriptions: dict[tuple[int, int], str], subject: int, path: Path) -> str:
    """The motion description of one of ``subject``'s files (:func:`load_descriptions`), else ""."""
    trial = trial_of(path)
    return "" if trial is None else descriptions.get((subject, trial), "")


def evenly_spaced(items: list, n: int) -> list:
    """At most ``n`` of ``items``, evenly spaced, first and last included."""
    if len(items) <= n:
        return list(items)
    return [items[i] for i in np.unique(np.round(np.linspace(0, len(items) - 1, n)).astype(int))]


def sample_truths(files: list[Path], config: LosoConfig) -> list[Truth]:
    """The bounded evaluation sample of one subject's files (see the module docstring)."""
    truths = []
    clip_config = replace(config.build.clip_options(), fps=config.eval.fps)
    for i, path in enumerate(evenly_spaced(sorted(files), config.max_clips)):
        clip = process_clip(path, path.parent, clip_config)
        if clip.source_m is None:
            raise ValueError(f"{path}: retargeted without the source skeleton's own joints")
        run = middle_frames(len(clip.positions), config.max_frames)
        yaws = tuple(config.yaws_deg[(config.yaws_per_clip * i + j) % len(config.yaws_deg)]
                     for j in range(config.yaws_per_clip))
        truths.append(Truth(clip.name, clip.positions[run].astype(np.float64), yaws,
                            clip.source_m[run].astype(np.float64)))
    return truths


def middle_frames(n: int, max_frames: int) -> slice:
    """At most ``max_frames`` of ``n`` frames, from the middle."""
    start = max(0, (n - max_frames) // 2)
    return slice(start, min(n, start + max_frames))


def _stderr(message: str) -> None:
    """Progress of a long evaluation, logged at info level (``mocapdb eval`` shows it; ``-q`` hides it)."""
    LOG.info(message)


def leave_one_subject_out(sources: list[str], config: LosoConfig, log=_stderr) -> dict:
    """Build a database without each subject in turn and evaluate that subject's sample on it."""
    wall = time.perf_counter()
    groups = group_by_subject([f for f, _ in find_sources(sources)])
    if len(groups) < 2:
        raise UsageError(f"--leave-one-subject-out needs files of at least 2 subjects; found {list(groups) or 'none'}")
    subjects = list(config.subjects) if config.subjects else list(groups)
    missing = [s for s in subjects if s not in groups]
    if missing:
        raise UsageError(f"no files of subject(s) {missing} among the sources (subjects: {list(groups)})")
    descriptions = load_descriptions(sources)
    scenarios = config.eval.scenarios
    overall = [ScenarioResult(s) for s in scenarios]
    folds = []
    for subject in subjects:
        truths = sample_truths(groups[subject], config)
        motions = list(dict.fromkeys(_description(descriptions, subject, f)
                                     for f in evenly_spaced(groups[subject], config.max_clips)))
        train = [str(f) for s, files in groups.items() if s != subject for f in files]
        with tempfile.TemporaryDirectory(prefix=f"mocapdb-loso-{subject}-") as tmp:
            t0 = time.perf_counter()
            summary = build(train, Path(tmp) / "db", config.build)
            t1 = time.perf_counter()
            db = load_database(Path(tmp) / "db")
            floors = compute_floors(db, truths, scenarios, config.eval)
            t2 = time.perf_counter()
            rng = np.random.default_rng(config.eval.seed + subject)
            results = [evaluate_scenario(db, truths, s, config.eval, rng, floors) for s in scenarios]
            t3 = time.perf_counter()
            database = {"files": summary.files, "clips": db.n_clips, "frames": db.n_frames,
                        "projections": db.n_projections, "clusters": db.n_clusters}
            del db
        for total, result in zip(overall, results):
            total.extend(result)
        fold = {"subject": subject, "motion": "; ".join(m for m in motions if m),
                "clips": [{"name": t.name, "frames": len(t.positions), "yaws_deg": list(t.yaws_deg or [])}
                          for t in truths],  # sample_truths gives every clip its yaws
                "truth_frames": int(sum(len(t.positions) for t in truths)),
                "database": database, "build_seconds": round(t1 - t0, 2), "floor_seconds": round(t2 - t1, 2),
                "eval_seconds": round(t3 - t2, 2), "scenarios": [r.report() for r in results]}
        folds.append(fold)
        log(f"subject {subject}: database of {database['files']} files, {database['frames']} frames, "
            f"{database['projections']} projections built in {fold['build_seconds']:.1f} s; floor "
            f"{fold['truth_frames']} truth frames in {fold['floor_seconds']:.2f} s; eval {fold['eval_seconds']:.1f} s")
    return {
        "mode": "leave-one-subject-out",
        "sources": [str(s) for s in sources],
        "subjects": subjects,
        "sample": {"max_frames": config.max_frames, "max_clips": config.max_clips,
                   "yaws_per_clip": config.yaws_per_clip, "yaws_deg": list(config.yaws_deg),
                   "camera_distance_m": config.eval.camera_distance_m, "min_clearance_m": config.eval.min_clearance_m},
        "build": {k: v for k, v in asdict(config.build).items() if k in ("fps", "yaw_step_deg", "clusters", "dims",
                                                                           "landmarks", "seed", "workers", "mirror")},
        "engine": engine_summary(config.eval.engine),
        "folds": folds,
        "overall": {"scenarios": [r.report() for r in overall]},
        "wall_seconds": round(time.perf_counter() - wall, 1),
    }


def _fmt(value, spec: str, missing: str = "-") -> str:
    return missing if value is None else format(value, spec)


def format_table(report: dict, motion_width: int = 24) -> str:
    """Per subject and overall, one row per scenario: frames, the database floor (15 joints), MPJPE
    over the 13 joints below the head (cm) of the published engine, the refined per-frame engine (the
    per-frame stream), the default stream at :data:`STREAM_LAGS` and the whole-take fit, and for the
    whole-take fit PA-MPJPE (13 joints), bone-length error (cm), acceleration error (mm/frame²;
    published in brackets), planted-foot skating (cm/s; refined per frame in brackets) and root error
    (% of distance)."""
    streams = " ".join(f"{f'L{lag}':>6}" for lag in STREAM_LAGS)
    head = (f"{'subject':<8} {'motion':<{motion_width}} {'scenario':<40} {'frames':>6} {'floor':>6} "
            f"{'pub':>6} {'ref':>6} {streams} {'take':>6} {'PA':>6} {'bone':>5} {'accel (pub)':>12} "
            f"{'skate (ref)':>12} {'root %':>7}")
    lines = [head, "-" * len(head)]

    def rows(subject: str, motion: str, scenarios: list[dict]) -> None:
        for sc in scenarios:
            pub, ref, take = sc["published"], sc["refined"], sc["whole take"]
            accel_take, accel_pub = take["accel_error_mm_per_frame2"], pub["accel_error_mm_per_frame2"]
            accel = f"{_fmt(accel_take, '.1f')} ({_fmt(accel_pub, '.1f')})"
            skate_take, skate_ref = take["foot_skating_cm_per_s"]["mean"], ref["foot_skating_cm_per_s"]["mean"]
            skate = f"{_fmt(skate_take, '.1f')} ({_fmt(skate_ref, '.0f')})"
            lagged = [sc.get(stream_variant(lag), {}) for lag in STREAM_LAGS]
            mpjpe = " ".join(f"{_fmt(v.get('mpjpe13_cm'), '.2f'):>6}" for v in (pub, ref, *lagged, take))
            lines.append(
                f"{subject:<8} {motion[:motion_width]:<{motion_width}} {sc['scenario']['name'][:40]:<40} "
                f"{take['frames_with_output']:>6} {_fmt(take['floor_mpjpe_cm'], '.2f'):>6} {mpjpe} "
                f"{_fmt(take['pa_mpjpe13_cm'], '.2f'):>6} {_fmt(take['bone_error_cm'], '.2f'):>5} {accel:>12} "
                f"{skate:>12} {_fmt(take['root_error_pct_distance'], '.2f'):>7}")
            subject, motion = "", ""

    for fold in report["folds"]:
        rows(str(fold["subject"]), fold["motion"], fold["scenarios"])
    rows("overall", "", report["overall"]["scenarios"])
    lines.append("")
    lines += [f"subject {f['subject']}: build {f['build_seconds']:.1f} s, floor {f['floor_seconds']:.2f} s, "
              f"eval {f['eval_seconds']:.1f} s" for f in report["folds"]]
    lines.append(f"total wall time {report['wall_seconds']:.1f} s")
    return "\n".join(lines)
