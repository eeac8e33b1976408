"""A hostile rig (issue 52, item 6): a real clip with a joint chain thousands of levels deep hung
inside it is read, inspected and built as the clip without it, in work linear in its joints."""
import sys
from pathlib import Path

import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.formats.bvh import format_bvh, parse_bvh, read_bvh
from mocapdb.core.formats.database_reader import load_database
from mocapdb.core.joint_map import JointMapError, describe, detect_mapping, extract_keypoints
from mocapdb.core.rig_words import split_words

from .conftest import SAMPLE_BVH

CLIP = SAMPLE_BVH / "002_01.bvh"  # Character Creator rig, 142 joints, 60 fps
CHAIN_PARENT = "CC_Base_Spine01"  # the clip's joint the chain hangs from
CHAIN_OFFSET = "0.000000 0.010000 0.000000"  # each link 0.01 file units (cm) beyond the one above
CHAIN_ROTATION = "0.100000 -0.200000 0.300000"  # each link's Z, Y, X rotation channels, degrees


def _link_lines(depth: int, link: str) -> list[str]:
    """The chain's HIERARCHY lines: ``depth`` nested joints named ``<link><i>``, then their closing braces."""
    lines = []
    for i in range(depth):
        lines += [f"JOINT {link}{i}", "{", f"OFFSET {CHAIN_OFFSET}", "CHANNELS 3 Zrotation Yrotation Xrotation"]
    return lines + ["}"] * depth


def clip_with_chain(depth: int, frames: int, parent: str = CHAIN_PARENT, link: str = "Link") -> str:
    """:data:`CLIP`'s first ``frames`` frames with a chain ``depth`` joints deep (named ``<link><i>``) as
    the first child of ``parent``: its lines after the parent's CHANNELS line, its 3 columns a link
    in every MOTION row after the parent's columns."""
    bvh = read_bvh(CLIP)
    column = int(bvh.channel_start[bvh.index(parent)]) + len(bvh.channels[bvh.index(parent)])
    lines = CLIP.read_text().splitlines()
    at = lines.index(next(line for line in lines if line.split() == ["JOINT", parent]))
    channels_at = next(k for k in range(at, len(lines)) if lines[k].split()[0] == "CHANNELS")
    motion_at = lines.index("MOTION")
    rows = [row.split() for row in lines[motion_at + 3:motion_at + 3 + frames]]
    widened = [" ".join(row[:column] + [CHAIN_ROTATION] * depth + row[column:]) for row in rows]
    header = lines[:channels_at + 1] + _link_lines(depth, link) + lines[channels_at + 1:motion_at]
    return "\n".join(header + ["MOTION", f"Frames: {frames}", lines[motion_at + 2]] + widened) + "\n"


def _inspect(path: Path, capsys) -> list[str]:
    """`mocapdb inspect`'s lines for ``path`` but the file's own (name, joint count)."""
    assert main(["inspect", str(path)]) == 0
    return [line for line in capsys.readouterr().out.splitlines() if not line.startswith(("file:", "joints:"))]


def test_a_10000_level_chain_inside_a_clip_is_inspected_and_built_as_the_clip_without_it(tmp_path, capsys):
    for name, depth in (("plain", 0), ("deep", 10_000)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "002_01.bvh").write_text(clip_with_chain(depth, frames=60))
    deep_file = tmp_path / "deep" / "002_01.bvh"
    assert len(read_bvh(deep_file).names) == len(read_bvh(CLIP).names) + 10_000
    assert _inspect(deep_file, capsys) == _inspect(tmp_path / "plain" / "002_01.bvh", capsys)
    for name in ("plain", "deep"):
        assert main(["build", str(tmp_path / name), "--out", str(tmp_path / f"{name}.db"), "--clusters", "5",
                     "--landmarks", "100", "--workers", "1"]) == 0
    plain, deep = load_database(tmp_path / "plain.db"), load_database(tmp_path / "deep.db")
    np.testing.assert_array_equal(deep.clip_n_frames, plain.clip_n_frames)
    np.testing.assert_allclose(deep.positions, plain.positions, atol=1e-9)


def test_a_deep_chain_writes_and_reads_back_without_recursion():
    deep = parse_bvh(clip_with_chain(10_000, frames=2))
    again = parse_bvh(format_bvh(deep))
    assert again.names == deep.names
    np.testing.assert_array_equal(again.parents, deep.parents)
    np.testing.assert_allclose(again.motion, deep.motion, atol=1e-6)


def _lines_executed(work, budget: float = float("inf")) -> int:
    """Python lines ``work()`` executes; an AssertionError past ``budget`` lines (a runaway stops early)."""
    executed = 0

    def count(frame, event, arg):
        nonlocal executed
        executed += event == "line"
        if executed > budget:
            raise AssertionError(f"more than {budget:.0f} lines executed")
        return count

    sys.settrace(count)
    try:
        work()
    finally:
        sys.settrace(None)
    return executed


def _recognise(text: str) -> None:
    """Read, recognise, inspect and extract the keypoints of a clip's BVH text."""
    bvh = parse_bvh(text)
    mapping = detect_mapping(bvh)
    describe(bvh, mapping)
    extract_keypoints(bvh, mapping)


def test_the_work_grows_linearly_with_the_chain_depth():
    """Counted in executed lines, not seconds (deterministic on a loaded machine): 4x the levels give
    at most 5x the lines (linear work gives under 4x; a walk up the chain per joint gave ~16x)."""
    shallow, deep = clip_with_chain(1000, frames=5), clip_with_chain(4000, frames=5)
    lines_shallow = _lines_executed(lambda: _recognise(shallow))
    lines_deep = _lines_executed(lambda: _recognise(deep), budget=5 * lines_shallow)
    assert lines_deep < 5 * lines_shallow, (lines_shallow, lines_deep)


def test_a_name_is_cut_into_words_in_time_linear_in_its_length():
    assert split_words("lhumerusupperarm") == ("l", "humerus", "upper", "arm")
    short = _lines_executed(lambda: split_words("q" * 1000))
    longer = "x" * 4000  # another letter: not an answer the word cache holds
    assert _lines_executed(lambda: split_words(longer), budget=5 * short) < 5 * short


def test_a_role_that_10000_names_could_take_is_refused_unless_a_joint_map_names_it(tmp_path):
    hands = parse_bvh(clip_with_chain(10_000, frames=60, parent="CC_Base_L_Forearm", link="LeftHand"), "hands.bvh")
    with pytest.raises(JointMapError, match=r"hands.bvh: .*\n  l_hand: 10001 joints' names read as a left hand "
                                            r"\(hand, wrist\); at most 32 are compared"):
        detect_mapping(hands)
    assert detect_mapping(hands, {"l_hand": "CC_Base_L_Hand"}).joints["l_forearm"] == "CC_Base_L_Forearm"
