"""Several rigs in one build: a joint map per folder or file pattern, the rigs counted, and the
database equal to building each folder with its own map and putting the two together."""
import shutil

import numpy as np
import pytest

from mocapdb.builder.config import BuildConfig
from mocapdb.builder.pipeline import _fingerprints, build
from mocapdb.builder.read_stage import find_sources
from mocapdb.cli.main import main
from mocapdb.core.clips import JOINT_MAP_FILE, ClipOptions, joint_map_for
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.joint_map import JointMapError

from .rig_styles import STYLES, rig_text

FRAMES = 20  # 0.67 s at 30 fps: one clip per file
NONSENSE = {name: f"J{i:02d}" for i, name in enumerate(STYLES["game_engine"].expected().values())}
STUDIO_MAP = "[joints]\n" + "\n".join(f'{role} = "{NONSENSE[name]}"'
                                        for role, name in STYLES["game_engine"].expected().items())
CLIP_COLUMNS = ["clip_name", "clip_source", "clip_source_fps", "clip_n_frames", "clip_convention", "clip_credit",
                "clip_mirrored"]
FRAME_COLUMNS = ["frame_index", "quaternions", "positions"]


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """``lib/a_auto`` (Unreal and Mixamo rigs, read without a map), ``lib/b_studio`` (a rig of
    nonsense names that needs a map) and that map in ``maps/studio.toml``."""
    root = tmp_path_factory.mktemp("rigs")
    auto, studio, maps = root / "lib" / "a_auto", root / "lib" / "b_studio", root / "maps"
    for folder in (auto, studio, maps):
        folder.mkdir(parents=True)
    (auto / "unreal.bvh").write_text(rig_text(STYLES["unreal"], 1, FRAMES))
    (auto / "mixamo.bvh").write_text(rig_text(STYLES["mixamo"], 2, FRAMES))
    (studio / "take.bvh").write_text(rig_text(STYLES["game_engine"], 3, FRAMES, rename=NONSENSE))
    (maps / "studio.toml").write_text(STUDIO_MAP)
    return root


def _config(**kw) -> BuildConfig:
    return BuildConfig(**{"clusters": 6, "landmarks": 40, "workers": 1, **kw})


def _table(db, columns) -> dict:
    return {c: getattr(db, c) for c in columns}


def _joined(first: dict, second: dict) -> dict:
    return {c: list(first[c]) + list(second[c]) if isinstance(first[c], list) else np.concatenate([first[c], second[c]])
            for c in first}


def _assert_tables_equal(a: dict, b: dict) -> None:
    for column in a:
        if isinstance(a[column], list):
            assert a[column] == b[column], column
        else:
            np.testing.assert_array_equal(a[column], b[column], err_msg=column)


def test_two_rigs_in_one_build_equal_each_built_with_its_own_map(library, tmp_path):
    auto, studio = library / "lib" / "a_auto", library / "lib" / "b_studio"
    studio_map = library / "maps" / "studio.toml"
    pattern = str(studio / "*")
    summary = build([str(auto), str(studio)], tmp_path / "both", _config(joint_maps=((pattern, studio_map),)))
    assert summary.rigs == {"detected (upperarm_l, thigh_l)": 1, "motionbuilder_mixamo": 1,
                            f"joint map ({studio_map})": 1} and not summary.skipped
    assert f"files per rig: detected (upperarm_l, thigh_l) 1; joint map ({studio_map}) 1" in summary.report()
    build([str(auto)], tmp_path / "auto", _config())
    build([str(studio)], tmp_path / "studio", _config(joint_map=studio_map))
    both, parts = load_database(tmp_path / "both"), [load_database(tmp_path / n) for n in ("auto", "studio")]
    assert both.clip_convention == ["motionbuilder_mixamo"] * 2 + ["detected (upperarm_l, thigh_l)"] * 2 + \
        ["joint map"] * 2
    for columns in (CLIP_COLUMNS, FRAME_COLUMNS):
        _assert_tables_equal(_table(both, columns), _joined(*(_table(p, columns) for p in parts)))
    views = [p.keypoints_2d for p in parts]  # each frame's 2D poses from every yaw: the frame's alone
    np.testing.assert_array_equal(both.keypoints_2d, np.concatenate(views))
    np.testing.assert_array_equal(both.frame_clip, np.concatenate([parts[0].frame_clip,
                                                                   parts[1].frame_clip + parts[0].n_clips]))


def test_a_map_beside_the_files_serves_its_folder(library, tmp_path):
    lib = tmp_path / "lib"
    shutil.copytree(library / "lib", lib)
    shutil.copy(library / "maps" / "studio.toml", lib / "b_studio" / JOINT_MAP_FILE)
    summary = build([str(lib)], tmp_path / "db", _config())
    assert summary.rigs[f"joint map ({lib / 'b_studio' / JOINT_MAP_FILE})"] == 1 and not summary.skipped
    assert load_database(tmp_path / "db").clip_convention.count("joint map") == 2
    # Without it the studio's file is skipped, named with what the recogniser found.
    (lib / "b_studio" / JOINT_MAP_FILE).unlink()
    summary = build([str(lib)], tmp_path / "db2", _config())
    assert [p for p, _ in summary.skipped] == [str(lib / "b_studio" / "take.bvh")]
    assert "no joint's name reads as a left hand" in summary.skipped[0][1]


def test_which_map_a_file_gets(tmp_path):
    (tmp_path / "lib" / "studio" / "day1").mkdir(parents=True)
    for name in ("lib/studio/joint_map.toml", "given.toml", "pattern.toml"):
        (tmp_path / name).write_text("")
    day1, root = tmp_path / "lib" / "studio" / "day1" / "take.bvh", tmp_path / "lib"
    given = ClipOptions(joint_map=tmp_path / "given.toml")
    assert joint_map_for(day1, root, given) == tmp_path / "lib" / "studio" / JOINT_MAP_FILE  # nearest, upwards
    assert joint_map_for(tmp_path / "lib" / "other.bvh", root, given) == tmp_path / "given.toml"
    assert joint_map_for(tmp_path / "lib" / "other.bvh", root, ClipOptions()) is None
    patterned = ClipOptions(joint_maps=(("*/day1/*", tmp_path / "pattern.toml"),))
    assert joint_map_for(day1, root, patterned) == tmp_path / "pattern.toml"
    # Only up to the source root: a map above the folder given is not the library's.
    assert joint_map_for(day1, tmp_path / "lib" / "studio" / "day1", ClipOptions()) is None


def test_a_changed_or_added_map_restarts_the_read(library, tmp_path):
    lib = tmp_path / "lib"
    shutil.copytree(library / "lib", lib)
    config = _config()
    files = find_sources([str(lib)])

    def read_fingerprint():
        return _fingerprints(config, files, [joint_map_for(p, r, config.clip_options()) for p, r in files])["read"]

    before = read_fingerprint()
    (lib / "b_studio" / JOINT_MAP_FILE).write_text(STUDIO_MAP)
    added = read_fingerprint()
    (lib / "b_studio" / JOINT_MAP_FILE).write_text(STUDIO_MAP + "\n# edited\n")
    assert len({str(before), str(added), str(read_fingerprint())}) == 3


def test_a_bad_map_beside_the_files_fails_before_any_file_is_read(library, tmp_path, monkeypatch):
    import mocapdb.core.clips as clips

    lib = tmp_path / "lib"
    shutil.copytree(library / "lib", lib)
    (lib / "b_studio" / JOINT_MAP_FILE).write_text("[joints]\nleft_hand = 'J00'\n")
    read = []
    monkeypatch.setattr(clips, "read_bvh", lambda path: read.append(path))
    with pytest.raises(JointMapError, match="joint_map.toml: unknown role"):
        build([str(lib)], tmp_path / "db", _config())
    assert read == [] and not (tmp_path / "db").exists()


def test_joint_map_for_on_the_command_line(library, tmp_path, capsys):
    studio = library / "lib" / "b_studio"
    assert main(["build", str(studio), "--out", str(tmp_path / "db"), "--clusters", "4", "--landmarks", "30",
                 "--workers", "1", "--joint-map-for", "*/b_studio/*", str(library / "maps" / "studio.toml")]) == 0
    assert f"files per rig: joint map ({library / 'maps' / 'studio.toml'}) 1" in capsys.readouterr().out
    assert main(["build", str(studio), "--out", str(tmp_path / "db2"),
                 "--joint-map-for", "*", str(tmp_path / "none")]) == 2
    assert "cannot read" in capsys.readouterr().err
