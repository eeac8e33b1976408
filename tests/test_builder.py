"""`mocapdb build` end to end on real bundled clips: contents, determinism, bad inputs, CLI."""
import os
import shutil

import numpy as np
import pytest

from mocapdb.builder.config import BuildConfig, BuildError
from mocapdb.builder.pipeline import build
from mocapdb.builder.read_stage import find_sources
from mocapdb.cli.main import main
from mocapdb.core.clips import ClipOptions, clips_from_bvh, continuous_runs, process_clip
from mocapdb.core.domains import DomainError
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.geometry import normalize_pose_2d, project_views
from mocapdb.core.motion_ops import mirror_keypoints
from mocapdb.core.skeleton import (
    BONE_LENGTHS_M,
    KEYPOINTS,
    KP,
    MIRROR_PAIRS,
    PELVIS,
    RIG_JOINTS,
    pose_from_rotations,
)

from .conftest import SAMPLE_BVH

CLIPS = ["002_03.bvh", "002_04.bvh"]  # run and jump: short real clips


@pytest.fixture(scope="module")
def sources(tmp_path_factory):
    folder = tmp_path_factory.mktemp("src")
    for name in CLIPS + ["CREDIT.txt"]:
        shutil.copy(SAMPLE_BVH / name, folder / name)
    return folder


def _config(**kw) -> BuildConfig:
    return BuildConfig(**{"clusters": 20, "landmarks": 300, "workers": 1, **kw})


@pytest.fixture(scope="module")
def built(sources, tmp_path_factory):
    out = tmp_path_factory.mktemp("db") / "db"
    summary = build([str(sources)], out, _config())
    return summary, load_database(out)


def test_database_contents(built):
    summary, db = built
    assert summary.clips == 4 and db.n_clips == 4 and summary.mirrored == 2
    assert "2 of them mirrored copies" in summary.report()
    # 60 fps clips resampled to 24 fps: (n - 1) / 60 s long, one frame every 1/24 s.
    assert db.n_projections == db.n_frames * 30 == summary.projections
    assert db.n_clusters == 20 and db.cluster_size.sum() == db.n_projections
    assert "mocap.cs.cmu.edu" in db.clip_credit[0]
    assert set(db.clip_convention) == {"character_creator"}


def test_frames_have_constant_bones_and_consistent_rotations(built):
    _, db = built
    pos = db.positions.astype(np.float64)
    for a, b, bone in [("r_hip", "r_knee", "thigh"), ("l_elbow", "l_wrist", "forearm"), ("pelvis", "neck", "torso")]:
        lengths = np.linalg.norm(pos[:, KP[b]] - pos[:, KP[a]], axis=-1)
        np.testing.assert_allclose(lengths, BONE_LENGTHS_M[bone], atol=1e-5)
    again = pose_from_rotations(db.quaternions.astype(np.float64), pos[:, PELVIS])
    np.testing.assert_allclose(again, pos, atol=1e-5)
    assert pos[:, [KP["r_ankle"], KP["l_ankle"]], 1].min() == pytest.approx(0.08, abs=1e-5)


def test_projections_are_normalised_views_of_the_frames(built):
    _, db = built
    rows = np.array([0, 31, 1000 % db.n_projections])
    frames = db.proj_frame[rows]
    yaws = np.array(db.meta["yaws_deg"])[db.proj_yaw[rows]]
    for r, f, yaw in zip(rows, frames, yaws):
        pos = db.positions[f:f + 1].astype(np.float64)
        from mocapdb.core.cameras import DatabaseCamera
        uv = project_views(pos, pos[:, PELVIS], np.array([yaw]), 0.0, DatabaseCamera(**db.meta["camera"]))
        expected, _, _ = normalize_pose_2d(uv[0, 0, :14])
        np.testing.assert_allclose(db.keypoints_2d[r], expected, atol=1e-5)


def test_representatives_belong_to_their_clusters(built):
    _, db = built
    assert np.all(db.cluster[db.representative] == np.arange(db.n_clusters))


def test_build_is_deterministic(sources, tmp_path, built):
    _, first = built
    build([str(sources)], tmp_path / "again", _config())
    second = load_database(tmp_path / "again")
    np.testing.assert_array_equal(first.cluster, second.cluster)
    np.testing.assert_array_equal(first.embedding, second.embedding)
    np.testing.assert_array_equal(first.quaternions, second.quaternions)


def test_unreadable_file_is_skipped_or_fails_strict(sources, tmp_path):
    folder = tmp_path / "mixed"
    shutil.copytree(sources, folder)
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT x\n{\n")
    summary = build([str(folder)], tmp_path / "db", _config())
    assert summary.clips == 4
    assert [p for p, _ in summary.skipped] == [str(folder / "broken.bvh")]
    with pytest.raises(BuildError, match="broken.bvh"):
        build([str(folder)], tmp_path / "db2", _config(strict=True))
    assert not (tmp_path / "db2").exists()


def test_exclude_and_missing_sources(sources, tmp_path):
    assert [f.name for f, _ in find_sources([str(sources)], ["*_04.bvh"])] == ["002_03.bvh"]
    with pytest.raises(BuildError, match="neither a BVH file nor a folder"):
        find_sources([str(tmp_path / "nowhere")])
    with pytest.raises(BuildError, match="does not divide 360"):
        build([str(sources)], tmp_path / "db", _config(yaw_step_deg=7.0))


def test_cli_exit_codes(sources, tmp_path, capsys):
    assert main(["build", str(sources / "002_03.bvh"), "--out", str(tmp_path / "db"),
                 "--clusters", "5", "--landmarks", "100", "--workers", "1", "--no-mirror"]) == 0
    assert "clips 1 (files split at jumps in the data; 0 of them mirrored copies)" in capsys.readouterr().out
    assert load_database(tmp_path / "db").meta["mirror"] is False
    assert main(["build", str(tmp_path / "none"), "--out", str(tmp_path / "x")]) == 2
    assert "argument sources: " in (err := capsys.readouterr().err) and "none: no such file or folder" in err
    assert main(["inspect", str(sources / "002_03.bvh")]) == 0
    assert "character_creator" in capsys.readouterr().out


def test_jumps_in_the_data_split_clips():
    fps = 60.0
    t = np.arange(200) / fps
    points = np.zeros((200, 15, 3))
    points[:, :, 0] = 0.5 * t[:, None]           # walking at 0.5 m/s
    points[0] += [0.0, 0.8, 0.0]                 # a bind-pose frame before the motion
    points[120, 9] += [0.3, 0.0, 0.0]            # a knee glitch: 0.3 m in 1/60 s
    assert continuous_runs(points, fps) == [slice(1, 120), slice(121, 200)]
    assert continuous_runs(points[:20], fps) == []  # nothing 0.5 s long


def _swap_sides(names: tuple[str, ...]) -> list[int]:
    """For each name, the index (in ``names``) of its left/right partner (itself on the midline)."""
    opposite = {a: b for pair in MIRROR_PAIRS for a, b in (pair, pair[::-1])}
    return [names.index(opposite.get(n, n)) for n in names]


def test_mirror_keypoints_reflects_and_swaps_sides():
    pose = np.arange(2 * 15 * 3, dtype=np.float64).reshape(2, 15, 3) + 1.0
    mirrored = mirror_keypoints(pose)
    for name in KEYPOINTS:
        side = {"r": "l", "l": "r"}.get(name[0]) if name[1] == "_" else None
        partner = f"{side}{name[1:]}" if side else name
        np.testing.assert_array_equal(mirrored[:, KP[partner]], pose[:, KP[name]] * [-1, 1, 1])
    assert mirrored[0, KP["l_wrist"], 0] == -pose[0, KP["r_wrist"], 0]
    np.testing.assert_array_equal(mirror_keypoints(mirrored), pose)


def test_mirrored_clip_is_the_mirror_image_of_the_original():
    original, mirror = clips_from_bvh(SAMPLE_BVH / "002_01.bvh", SAMPLE_BVH, ClipOptions())
    assert (original.name, mirror.name) == ("002_01", "002_01~mirror")
    assert (original.mirrored, mirror.mirrored) == (False, True)
    assert (mirror.source, mirror.source_fps, mirror.convention, mirror.credit) == \
        (original.source, original.source_fps, original.convention, original.credit)
    pos, mirror_pos = original.positions.astype(np.float64), mirror.positions.astype(np.float64)
    assert np.abs(mirror_pos - pos).max() > 0.1  # a real walk is not its own mirror image
    # Retargeting is mirror-equivariant: measured bit-identical on the bundled clips.
    np.testing.assert_allclose(mirror_pos, mirror_keypoints(pos), rtol=0, atol=1e-6)
    # Rotations: each joint's is its partner's mirrored, (w, x, y, z) → (w, x, -y, -z).
    partner_quats = original.quaternions[:, _swap_sides(RIG_JOINTS)] * np.array([1, 1, -1, -1], np.float32)
    np.testing.assert_allclose(mirror.quaternions, partner_quats, rtol=0, atol=1e-6)
    for a, b, bone in [("r_hip", "r_knee", "thigh"), ("l_knee", "l_ankle", "shin"), ("r_elbow", "r_wrist", "forearm"),
                       ("l_shoulder", "l_elbow", "upper_arm"), ("pelvis", "neck", "torso")]:
        np.testing.assert_allclose(np.linalg.norm(mirror_pos[:, KP[b]] - mirror_pos[:, KP[a]], axis=-1),
                                   BONE_LENGTHS_M[bone], atol=1e-5)


def test_mirror_doubles_the_database_and_stays_out_of_ground_truth(sources, tmp_path, built):
    _, mirrored_db = built
    build([str(sources)], tmp_path / "plain", _config(mirror=False))
    plain = load_database(tmp_path / "plain")
    assert (mirrored_db.meta["mirror"], plain.meta["mirror"]) == (True, False)
    assert mirrored_db.n_frames == 2 * plain.n_frames and mirrored_db.n_projections == 2 * plain.n_projections
    assert mirrored_db.clip_mirrored.tolist() == [False, True, False, True] and not plain.clip_mirrored.any()
    assert mirrored_db.clip_name == ["002_03", "002_03~mirror", "002_04", "002_04~mirror"]
    for c in range(plain.n_clips):
        first, n = plain.clip_first_frame[c], plain.clip_n_frames[c]
        original = mirrored_db.clip_first_frame[2 * c]
        mirror = mirrored_db.clip_first_frame[2 * c + 1]
        np.testing.assert_array_equal(mirrored_db.positions[original:original + n], plain.positions[first:first + n])
        np.testing.assert_allclose(mirrored_db.positions[mirror:mirror + n],
                                   mirror_keypoints(plain.positions[first:first + n]), rtol=0, atol=1e-6)
    truth = process_clip(sources / "002_04.bvh", sources, _config().clip_options())
    assert (truth.name, truth.mirrored) == ("002_04", False)
    np.testing.assert_array_equal(truth.positions, plain.positions[plain.clip_first_frame[1]:])


def _first_value(text: str, value: str) -> str:
    """``text`` with the first number of the first frame replaced by ``value``."""
    header, rows = text.split("Frame Time: 0.016667\n")
    return f"{header}Frame Time: 0.016667\n{value} {rows.split(' ', 1)[1]}"


# File → (how it breaks 002_03.bvh, the reason the build must give for skipping it).
BAD_FILES = {
    "zero_time.bvh": (lambda t: t.replace("Frame Time: 0.016667", "Frame Time: 0"),
                      ":673: Frame Time: 0 is not a frame duration"),
    "negative_time.bvh": (lambda t: t.replace("Frame Time: 0.016667", "Frame Time: -0.016667"),
                          "Frame Time: -0.016667 is not a frame duration"),
    "inf_time.bvh": (lambda t: t.replace("Frame Time: 0.016667", "Frame Time: inf"), "Frame Time: inf is not"),
    "nan_time.bvh": (lambda t: t.replace("Frame Time: 0.016667", "Frame Time: NaN"), "Frame Time: NaN is not"),
    "nan_offset.bvh": (lambda t: t.replace("OFFSET 0.000000 0.000000 105.214241", "OFFSET 0.000000 nan 105.2"),
                       ":8: OFFSET of 'CC_Base_Hip' is not finite"),
    "nan_motion.bvh": (lambda t: _first_value(t, "nan"),
                       "NaN or infinite value in the MOTION data (frame 0, RL_BoneRoot Xposition"),
    "inf_motion.bvh": (lambda t: _first_value(t, "-inf"), "NaN or infinite value in the MOTION data"),
    "overflow.bvh": (lambda t: _first_value(t, "1e308"), "Xposition 1e+308 is beyond 1e+07 units (10 km"),
    "short.bvh": (lambda t: t.replace("Frames: 86", "Frames: 87"), "header says 87 frames but only 86 are present"),
    "absurd.bvh": (lambda t: t.replace("Frames: 86", "Frames: 99999999"), ":672: Frames: 99999999 is absurd"),
    "boom.bvh": (lambda t: t, "unexpected ZeroDivisionError: float division by zero"),
}


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning",
                            "ignore:invalid value encountered:RuntimeWarning")
def test_bad_files_are_named_skips_and_never_reach_the_database(tmp_path, monkeypatch):
    import mocapdb.core.clips as clips

    folder = tmp_path / "src"
    folder.mkdir()
    text = (SAMPLE_BVH / "002_03.bvh").read_text()
    for name, (corrupt, _) in BAD_FILES.items():
        (folder / name).write_text(corrupt(text))
    (folder / "fbx.bvh").write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00" + bytes(range(256)))
    (folder / "bom.bvh").write_bytes(b"\xef\xbb\xbf" + text.encode())  # fine: a UTF-8 byte-order mark
    extract = clips.extract_keypoints

    def extract_or_fail(bvh, *args, **kwargs):
        if bvh.source.endswith("boom.bvh"):
            raise ZeroDivisionError("float division by zero")  # what `Frame Time: 0` once gave
        return extract(bvh, *args, **kwargs)

    monkeypatch.setattr(clips, "extract_keypoints", extract_or_fail)
    summary = build([str(folder)], tmp_path / "db", _config(mirror=False))
    reasons = dict(summary.skipped)
    assert sorted(reasons) == sorted(str(folder / n) for n in [*BAD_FILES, "fbx.bvh"])
    for name, (_, reason) in BAD_FILES.items():
        assert reason in reasons[str(folder / name)], name
    assert "fbx.bvh: not a text file" in reasons[str(folder / "fbx.bvh")]
    db = load_database(tmp_path / "db")
    assert db.clip_name == ["bom"] and np.isfinite(db.positions).all() and np.isfinite(db.keypoints_2d).all()
    assert f"skipped {folder / 'zero_time.bvh'}: " in summary.report()
    with pytest.raises(BuildError, match=r"--strict: .*absurd.bvh: .*Frames: 99999999 is absurd"):
        build([str(folder)], tmp_path / "strict", _config(strict=True))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["db", "src"]  # nothing half-written


def test_blender_export_reads_as_the_original(tmp_path):
    from mocapdb.core.formats.bvh import REPLACED, format_bvh, read_bvh

    from .test_bvh import blender_style

    (tmp_path / "blender.bvh").write_text(format_bvh(blender_style(read_bvh(SAMPLE_BVH / "002_03.bvh"))))
    assert read_bvh(tmp_path / "blender.bvh").position_mode == REPLACED
    original = process_clip(SAMPLE_BVH / "002_03.bvh", SAMPLE_BVH, _config().clip_options())
    exported = process_clip(tmp_path / "blender.bvh", tmp_path, _config().clip_options())
    np.testing.assert_allclose(exported.positions, original.positions, atol=1e-4)


def _unwritable_outputs(tmp_path):
    (tmp_path / "file.txt").write_text("mine")
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "cat.jpg").write_text("mine")
    return {tmp_path / "file.txt": "exists and is not a mocapdb database",
            tmp_path / "photos": "exists and is not a mocapdb database",
            tmp_path / "file.txt" / "sub" / "db": f"{tmp_path / 'file.txt'} is not a folder"}


def test_unwritable_output_fails_before_any_file_is_read(sources, tmp_path, monkeypatch, capsys):
    import time

    import mocapdb.core.clips as clips
    from mocapdb.core.formats.database import DatabaseError

    read = []
    monkeypatch.setattr(clips, "read_bvh", lambda path: read.append(path))
    for out, message in _unwritable_outputs(tmp_path).items():
        with pytest.raises(DatabaseError, match=message):
            build([str(sources)], out, _config())
        start = time.perf_counter()
        assert main(["build", str(sources), "--out", str(out), "--workers", "1"]) == 2
        assert time.perf_counter() - start < 0.5
        assert f"mocapdb build: error: {out}" in capsys.readouterr().err
    assert read == []
    assert (tmp_path / "file.txt").read_text() == "mine" and sorted(p.name for p in tmp_path.iterdir()) == \
        ["file.txt", "photos"] and [p.name for p in (tmp_path / "photos").iterdir()] == ["cat.jpg"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write anywhere")
def test_output_in_a_read_only_folder_fails_before_work(sources, tmp_path):
    from mocapdb.core.formats.database import DatabaseError

    (tmp_path / "locked").mkdir()
    (tmp_path / "locked").chmod(0o500)
    try:
        with pytest.raises(DatabaseError, match="cannot write in"):
            build([str(sources)], tmp_path / "locked" / "new" / "db", _config())
    finally:
        (tmp_path / "locked").chmod(0o700)


def test_bad_joint_map_fails_before_any_file_is_read(sources, tmp_path, monkeypatch):
    import mocapdb.core.clips as clips
    from mocapdb.core.joint_map import JointMapError

    read = []
    monkeypatch.setattr(clips, "read_bvh", lambda path: read.append(path))
    (tmp_path / "map.toml").write_text("[joints]\nleft_hand = 'LeftHand'\n")
    with pytest.raises(JointMapError, match="map.toml: unknown role"):
        build([str(sources)], tmp_path / "db", _config(joint_map=tmp_path / "map.toml"))
    assert read == [] and not (tmp_path / "db").exists()


def test_database_with_a_nan_is_never_written(built, tmp_path):
    from dataclasses import replace

    from mocapdb.core.formats.database import DatabaseError
    from mocapdb.core.formats.database_writer import write_database

    _, db = built
    positions = db.positions.copy()
    positions[3, 2, 1] = np.nan
    with pytest.raises(DatabaseError, match="NaN or infinite values in positions"):
        write_database(replace(db, positions=positions), tmp_path / "db")
    assert list(tmp_path.iterdir()) == []


BAD_OPTIONS = {  # `mocapdb build` options → what the error must say
    ("--clusters", "0"): "argument --clusters: '0': must be",
    ("--clusters", "-5"): "argument --clusters: '-5': must be",
    ("--dims", "0"): "argument --dims: '0': must be",
    ("--landmarks", "0"): "argument --landmarks: '0': must be",
    ("--landmarks", "1"): "argument --landmarks: '1': must be",
    ("--landmarks", "5"): "--landmarks 5 is too few for --dims 5: landmark MDS needs at least dims + 1",
    ("--fps", "0"): "argument --fps: '0': must be",
    ("--fps", "-24"): "argument --fps: '-24': must be",
    ("--fps", "nan"): "argument --fps: 'nan': must be",
    ("--fps", "inf"): "argument --fps: 'inf': must be",
    ("--yaw-step", "0"): "argument --yaw-step: '0': must be",
    ("--yaw-step", "-12"): "argument --yaw-step: '-12': must be",
    ("--yaw-step", "nan"): "argument --yaw-step: 'nan': must be",
    ("--yaw-step", "inf"): "argument --yaw-step: 'inf': must be",
    ("--yaw-step", "7"): "--yaw-step 7.0 does not divide 360 degrees",
    ("--yaw-step", "720"): "argument --yaw-step: '720': must be",
    ("--yaw-step", "0.01"): "--yaw-step 0.01 does not divide 360 degrees into 1 to 32767 yaws",
    ("--focal", "0"): "argument --focal: '0': must be",
    ("--focal", "-1000"): "argument --focal: '-1000': must be",
    ("--focal", "nan"): "argument --focal: 'nan': must be",
    ("--camera-height", "0"): "argument --camera-height: '0': must be",
    ("--camera-height", "-1.5"): "argument --camera-height: '-1.5': must be",
    ("--camera-height", "inf"): "argument --camera-height: 'inf': must be",
    ("--camera-distance", "0"): "argument --camera-distance: '0': must be",
    ("--camera-distance", "nan"): "argument --camera-distance: 'nan': must be",
    ("--workers", "0"): "argument --workers: '0': must be",
    ("--workers", "-2"): "argument --workers: '-2': must be",
    ("--seed", "-1"): "argument --seed: '-1': must be",
}


@pytest.mark.parametrize("option", BAD_OPTIONS, ids=" ".join)
def test_bad_build_option_fails_before_any_work(sources, tmp_path, monkeypatch, capsys, option):
    import time

    import mocapdb.builder.pipeline as builder
    import mocapdb.core.clips as clips
    from mocapdb.cli.main import parser

    parser()  # its imports (OpenCV) are not the build's time
    read = []
    monkeypatch.setattr(clips, "read_bvh", lambda path: read.append(path))
    monkeypatch.setattr(builder, "find_sources", lambda *a: read.append(a))
    start = time.perf_counter()
    assert main(["build", str(sources), "--out", str(tmp_path / "db"), "--workers", "1", *option]) == 2
    assert time.perf_counter() - start < 1.0
    err = capsys.readouterr().err
    assert err.startswith(f"mocapdb build: error: {BAD_OPTIONS[option]}") and "Traceback" not in err
    assert read == [] and list(tmp_path.iterdir()) == []


def test_bad_config_is_refused_by_the_library_too(sources, tmp_path):
    from mocapdb.core.cameras import DatabaseCamera

    for config in [_config(clusters=0), _config(dims=2.5), _config(landmarks=True), _config(fps=float("nan")),
                   _config(camera=DatabaseCamera(focal_px=0.0)), _config(camera=DatabaseCamera(width_px=0)),
                   _config(workers=0), _config(unit="furlong")]:
        with pytest.raises((BuildError, DomainError)):
            build([str(sources)], tmp_path / "db", config)
    assert list(tmp_path.iterdir()) == []


def test_more_clusters_than_projections_are_reduced_with_a_warning(sources, tmp_path):
    summary = build([str(sources / "002_03.bvh")], tmp_path / "db", _config(clusters=10**6, mirror=False))
    db = load_database(tmp_path / "db")
    assert db.n_clusters == db.n_projections == summary.clusters == db.meta["n_clusters"] < 10**6
    assert summary.warnings == [f"--clusters 1000000 is more than the {db.n_projections} projections: "
                                f"made {db.n_projections} clusters"]
    assert f"warning: {summary.warnings[0]}" in summary.report()


def test_build_cleans_up_after_an_interrupted_build(sources, tmp_path, capsys):
    import subprocess
    import sys

    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True).stdout)
    (tmp_path / f".db.tmp-{dead}").mkdir()
    (tmp_path / f".db.tmp-{dead}" / "projections.parquet").write_bytes(b"half written")
    assert main(["build", str(sources / "002_03.bvh"), "--out", str(tmp_path / "db"), "--clusters", "5",
                 "--landmarks", "100", "--workers", "1", "--no-mirror"]) == 0
    assert f"warning: removed .db.tmp-{dead}, left by an interrupted write" in capsys.readouterr().out
    assert os.listdir(tmp_path) == ["db"]


def test_build_through_a_symlink_writes_its_target(sources, tmp_path, capsys):
    (tmp_path / "store").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "store" / "db")
    assert main(["build", str(sources / "002_03.bvh"), "--out", str(tmp_path / "link"), "--clusters", "5",
                 "--landmarks", "100", "--workers", "1", "--no-mirror"]) == 0
    assert f"wrote {tmp_path / 'link'} (symlink to {tmp_path / 'store' / 'db'})" in capsys.readouterr().out
    assert (tmp_path / "link").is_symlink() and os.listdir(tmp_path / "store") == ["db"]
    assert load_database(tmp_path / "link").n_clusters == 5


def test_engine_commands_verify_checksums_unless_no_verify(small_db_path, tmp_path):
    from mocapdb.cli import main as cli
    from mocapdb.cli.reconstruct import _engine
    from mocapdb.core.formats.database import DatabaseError

    db = tmp_path / "db"
    shutil.copytree(small_db_path, db)
    frames = db / "frames.parquet"
    data = bytearray(frames.read_bytes())
    data[data.index(b"parquet-cpp-arrow")] ^= 1  # a harmless bit: the file still decodes
    frames.write_bytes(bytes(data))
    for command in (["reconstruct", str(tmp_path), "--out", str(tmp_path / "out")], ["live", "--source", "-"]):
        args = cli.parser().parse_args([*command, "--db", str(db)])
        with pytest.raises(DatabaseError, match=r"checksum mismatch: .*frames.parquet .*--no-verify to load it"):
            _engine(args)
        args = cli.parser().parse_args([*command, "--db", str(db), "--no-verify"])
        assert _engine(args).pipeline.db.n_frames == load_database(small_db_path).n_frames


def test_a_build_with_every_source_skipped_names_each_reason(tmp_path, capsys):
    """Every file skipped: each is printed with its reason before the one error line (exit 2), no database."""
    folder = tmp_path / "src"
    folder.mkdir()
    (folder / "cut.bvh").write_text("HIERARCHY\nROOT x\n{\n")
    (folder / "notes.bvh").write_text("not motion capture\n")
    assert main(["build", str(folder), "--out", str(tmp_path / "db"), "--workers", "1"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(": ")[0] for line in lines[:2]] == [f"skipped {folder / 'cut.bvh'}",
                                                           f"skipped {folder / 'notes.bvh'}"]
    assert all(line.split(": ", 1)[1].strip() for line in lines[:2])   # each with its reason
    assert lines[2:] == ["mocapdb build: error: no readable BVH clip among the sources: all 2 BVH file(s) were "
                         "skipped"]
    assert not (tmp_path / "db").exists()
