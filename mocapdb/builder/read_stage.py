"""The build's ``read`` stage: the BVH sources found, each file's joint map, and every file's clips
(retargeted to the universal skeleton, in ``config.workers`` processes) appended to the work
folder's frame arrays; a bad file is skipped with its reason, never the end of a build.
"""
from __future__ import annotations

import fnmatch
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from mocapdb.builder.config import BuildConfig, BuildError
from mocapdb.builder.run import BuildRun, BuildSummary, checkpoint
from mocapdb.builder.work import WorkArray
from mocapdb.core.clips import Clip, clips_from_bvh, joint_map_for
from mocapdb.core.formats.bvh import BvhError
from mocapdb.core.joint_map import JointMapError, load_joint_map_file
from mocapdb.core.progress import progress
from mocapdb.core.skeleton import N_POINTS, RIG_JOINTS


def find_sources(sources: list[str], exclude: Sequence[str] = ()) -> list[tuple[Path, Path]]:
    """BVH files named or found (recursively) under ``sources``, minus ``exclude`` glob patterns.

    Returns sorted ``(file, source_root)`` pairs; a pattern matches the file name or its path.
    """
    found: dict[Path, Path] = {}
    for src in sources:
        root = Path(src)
        if root.is_dir():
            files = [p for p in root.rglob("*") if p.suffix.lower() == ".bvh" and p.is_file()]
        elif root.is_file():
            files, root = [root], root.parent
        else:
            raise BuildError(f"source {src!r} is neither a BVH file nor a folder")
        for f in files:
            if not any(fnmatch.fnmatch(f.name, pat) or fnmatch.fnmatch(str(f), pat) for pat in exclude):
                found.setdefault(f, root)
    return sorted(found.items())


def joint_maps_of(config: BuildConfig, files: list[tuple[Path, Path]]) -> list[Path | None]:
    """Each file's joint map (:func:`~mocapdb.core.clips.joint_map_for`), every one loaded once:
    a bad one raises :class:`JointMapError` before any file is read."""
    options = config.clip_options()
    maps = [joint_map_for(path, root, options) for path, root in files]
    for map_path in dict.fromkeys(m for m in maps if m):
        load_joint_map_file(map_path)
    return maps


def _process_one(args: tuple[Path, Path, BuildConfig]) -> list[Clip] | tuple[str, str]:
    """One file's clips, or ``(file, reason)`` when anything goes wrong: one bad file never ends a build."""
    path, root, config = args
    try:
        return clips_from_bvh(path, root, config.clip_options())
    except (BvhError, JointMapError) as exc:
        return (str(path), str(exc))
    except Exception as exc:  # noqa: BLE001 - any failure on one file is that file's skip reason
        return (str(path), f"unexpected {type(exc).__name__}: {exc}")


def _clip_row(clip: Clip) -> dict:
    return {"name": clip.name, "source": clip.source, "source_fps": clip.source_fps, "convention": clip.convention,
            "credit": clip.credit, "mirrored": clip.mirrored, "n_frames": len(clip.positions)}


def read_stage(run: BuildRun, files: list[tuple[Path, Path]]) -> list[WorkArray]:
    """Every file's clips (in ``config.workers`` processes) appended to the frame arrays in the files'
    order; the clip table and the skipped files go to the stage's record."""
    record = run.work.record("read")
    if "files_done" not in record:
        record.update(files_done=0, clips=[], skipped=[], rigs={})
        run.work.new_array("positions", np.float32, (N_POINTS, 3))
        run.work.new_array("quaternions", np.float32, (len(RIG_JOINTS), 4))
    arrays = [run.work.array("positions"), run.work.array("quaternions")]
    frames = sum(c["n_frames"] for c in record["clips"])
    for array in arrays:
        array.resize(frames)  # what an interrupted run appended after its last commit goes
    jobs = [(path, root, run.config) for path, root in files[record["files_done"]:]]
    bar = progress(total=len(files), initial=record["files_done"], desc="read+retarget", unit="file")
    for job, result in zip(jobs, run.readers.in_order(_process_one, jobs)):
        if isinstance(result, tuple):
            record["skipped"].append(list(result))
        else:
            rig = _rig_of(result[0], joint_map_for(job[0], job[1], run.config.clip_options()))
            record["rigs"][rig] = record["rigs"].get(rig, 0) + 1
        for clip in result if isinstance(result, list) else []:
            arrays[0].append(clip.positions)
            arrays[1].append(clip.quaternions)
            record["clips"].append(_clip_row(clip))
        record["files_done"] += 1
        bar.update()
        checkpoint(run, arrays)
    bar.close()
    return arrays


def _rig_of(clip: Clip, joint_map: Path | None) -> str:
    """How a file's rig was read, for the summary: its convention label, and the joint map."""
    return f"{clip.convention} ({joint_map})" if joint_map else clip.convention


def check_read(record: dict, config: BuildConfig, summary: BuildSummary) -> None:
    """The skipped files into the summary; :class:`BuildError` with ``--strict`` and a skip, or without
    any clip."""
    summary.skipped = [tuple(s) for s in record["skipped"]]
    summary.rigs = dict(record.get("rigs", {}))
    if summary.skipped and config.strict:
        raise BuildError("--strict: " + "; ".join(f"{p}: {why}" for p, why in summary.skipped))
    if not record["clips"]:
        why = f": all {len(summary.skipped)} BVH file(s) were skipped" if summary.skipped else ""
        raise BuildError(f"no readable BVH clip among the sources{why}", summary.skipped)
