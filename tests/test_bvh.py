"""BVH reading, writing and forward kinematics against hand-computed poses."""
import os
import re
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.formats.bvh import (
    ADDED,
    NO_POSITIONS,
    REPLACED,
    Bvh,
    BvhError,
    format_bvh,
    forward_kinematics,
    local_transforms,
    motion_from_rotations,
    parse_bvh,
    read_bvh,
)

from .conftest import SHARED_BVH, needs

# A two-bone arm: root at (1,2,3) with channels in an unusual order, one joint rotating,
# an End Site. Frame 0: no rotation; frame 1: root turned 90° about z, elbow 90° about y.
ARM = """HIERARCHY
ROOT root
{
\tOFFSET 1.0 2.0 3.0
\tCHANNELS 6 Zposition Xposition Yposition Yrotation Xrotation Zrotation
\tJOINT elbow
\t{
\t\tOFFSET 10.0 0.0 0.0
\t\tCHANNELS 3 Xrotation Yrotation Zrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 5.0 0 0
\t\t}
\t}
}
MOTION
Frames: 2
Frame Time: 0.0083333
0 0 0 0 0 0 0 0 0
1.0e+0 0 0 0 0 90 0 90 0
"""


def test_fk_hand_computed():
    bvh = parse_bvh(ARM)
    pos, _ = forward_kinematics(bvh)
    assert bvh.names == ["root", "elbow", "elbow_End"]
    np.testing.assert_allclose(pos[0], [[1, 2, 3], [11, 2, 3], [16, 2, 3]], atol=1e-12)
    # Frame 1: root moved +1 in z; Rz(90) maps x→y so the elbow is at root + (0,10,0);
    # the elbow's Ry(90) maps x→-z, then Rz(90) leaves -z alone: hand at elbow + (0,0,-5).
    np.testing.assert_allclose(pos[1], [[1, 2, 4], [1, 12, 4], [1, 12, -1]], atol=1e-12)
    assert bvh.fps == pytest.approx(120.0, rel=1e-4)


def test_crlf_tabs_and_scientific_notation_read_the_same():
    messy = ARM.replace("\n", "\r\n").replace("\t", "  \t ").replace("10.0 0.0 0.0", "1e1 0.0E0 -0.0")
    a, b = forward_kinematics(parse_bvh(ARM))[0], forward_kinematics(parse_bvh(messy))[0]
    np.testing.assert_allclose(a, b, atol=0)


def test_round_trip_keeps_positions():
    bvh = parse_bvh(ARM)
    again = parse_bvh(format_bvh(bvh))
    np.testing.assert_allclose(forward_kinematics(again)[0], forward_kinematics(bvh)[0], atol=1e-6)
    assert again.channels == bvh.channels


@needs(SHARED_BVH)
def test_real_file_round_trip(tmp_path):
    from mocapdb.core.formats.bvh import write_bvh
    bvh = read_bvh(SHARED_BVH / "002_03.bvh")
    write_bvh(tmp_path / "out.bvh", bvh)
    again = read_bvh(tmp_path / "out.bvh")
    np.testing.assert_allclose(forward_kinematics(again)[0], forward_kinematics(bvh)[0], atol=1e-6)


@pytest.mark.parametrize("text, message", [
    ("hello", "does not start with HIERARCHY"),
    (ARM.split("MOTION")[0], "no MOTION section"),
    (ARM.replace("Frames: 2", "Frames: 3"), "only 2 are present"),
    (ARM.replace("1.0e+0 0 0 0 0 90 0 90 0", "1 0 0 0 0 90 0 90"), "frame 1 has 8 values"),
    (ARM.replace("1.0e+0 0 0", "1.0e+0 abc 0"), "non-numeric"),
    (ARM.replace("CHANNELS 3 Xrotation", "CHANNELS 3 Wrotation"), "bad channel list"),
    (ARM.replace("\t}\n}\nMOTION", "\t}\nMOTION"), "unclosed"),
    (ARM.replace("OFFSET 10.0 0.0 0.0", "OFFSET 10.0 zero 0.0"), "OFFSET needs three numbers"),
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: 0"), "bad.bvh:18: Frame Time: 0 is not a frame duration"),
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: -0.01"),
     "bad.bvh:18: Frame Time: -0.01 is not a frame duration"),
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: inf"), "bad.bvh:18: Frame Time: inf is not a frame duration"),
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: nan"), "bad.bvh:18: Frame Time: nan is not a frame duration"),
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: 1e9"), "Frame Time: 1e9 is not a frame duration"),
    (ARM.replace("OFFSET 10.0 0.0 0.0", "OFFSET 10.0 nan 0.0"), r"bad.bvh:8: OFFSET of 'elbow' is not finite"),
    (ARM.replace("OFFSET 1.0 2.0 3.0", "OFFSET 1.0 -inf 3.0"), r"bad.bvh:4: OFFSET of 'root' is not finite"),
    (ARM.replace("1.0e+0 0 0 0 0 90", "1.0e+0 0 0 0 0 inf"), r"bad.bvh:\d+: NaN or infinite value in the MOTION data "
                                                            r"\(frame 1, root Zrotation"),
    (ARM.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 NaN 0 0 0 0"), r"\(frame 0, root Xrotation"),
    (ARM.replace("Frames: 2", "Frames: 20000000"), "bad.bvh:17: Frames: 20000000 is absurd"),
    (ARM.replace("Frames: 2", "Frames: 0"), "bad.bvh:17: Frames: 0: no motion to read"),
    (ARM.replace("JOINT elbow", "JOINT"), "bad.bvh:6: JOINT without a name"),
    (ARM.replace("JOINT elbow", "JOINT root"), "bad.bvh:6: joint name 'root' appears twice"),
    ("\ufeffHIER\0ARCHY", "bad.bvh: not a text file"),
    (ARM.replace("CHANNELS 3 Xrotation Yrotation", "CHANNELS 3 Xrotation Xrotation"),
     "bad.bvh:9: channel list Xrotation Xrotation Zrotation names Xrotation twice"),
    (ARM + "0 0 0 0 0 0 0 0 0\n", "bad.bvh:21: more motion rows than the header's 'Frames: 2'"),
    (ARM.replace("1.0e+0 0 0 0 0 90", "2e7 0 0 0 0 90"),
     r"bad.bvh:20: frame 1, root Zposition 2e\+07 is beyond 1e\+07 units \(10 km in millimetres\)"),
    (ARM.replace("OFFSET 10.0 0.0 0.0", "OFFSET 10.0 1e9 0.0"), "bad.bvh:8: OFFSET of 'elbow' .* is beyond 1e"),
    (ARM.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 x 0"), "bad.bvh:19: non-numeric value in the MOTION data"),
    (ARM.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0"), "bad.bvh:19: frame 0 has 8 values, expected 9"),
])
def test_bad_input_gives_clear_error(text, message):
    with pytest.raises(BvhError, match=message):
        parse_bvh(text, "bad.bvh")


def test_missing_file_names_it(tmp_path):
    with pytest.raises(BvhError, match="nope.bvh: cannot read"):
        read_bvh(tmp_path / "nope.bvh")


def blender_style(bvh: Bvh) -> Bvh:
    """``bvh`` as Blender's exporter writes it: every joint also gets position channels, which
    hold the joint's OFFSET (its local translation) in every frame."""
    channels, columns = [], []
    for j, chans in enumerate(bvh.channels):
        own = bvh.motion[:, bvh.channel_start[j]:bvh.channel_start[j] + len(chans)]
        if j > 0 and chans:
            chans = ["Xposition", "Yposition", "Zposition"] + chans
            own = np.hstack([np.tile(bvh.offsets[j], (bvh.n_frames, 1)), own])
        channels.append(chans)
        columns.append(own)
    return replace(bvh, channels=channels, motion=np.hstack(columns))


def _arm_with_elbow_positions(frame0: str, frame1: str) -> Bvh:
    """ARM whose elbow also has position channels, holding ``frame0`` and ``frame1`` ("x y z")."""
    header = ARM.split("MOTION")[0].replace("CHANNELS 3 Xrotation",
                                            "CHANNELS 6 Xposition Yposition Zposition Xrotation")
    return parse_bvh(f"{header}MOTION\nFrames: 2\nFrame Time: 0.0083333\n"
                     f"0 0 0 0 0 0 {frame0} 0 0 0\n1 0 0 0 0 90 {frame1} 0 90 0\n", "arm.bvh")


def test_blender_style_position_channels_replace_the_offset():
    bvh = _arm_with_elbow_positions("10 0 0", "10 0 0")  # = the elbow's OFFSET, as Blender writes it
    assert bvh.position_mode == REPLACED
    np.testing.assert_allclose(forward_kinematics(bvh)[0], forward_kinematics(parse_bvh(ARM))[0], atol=1e-12)
    again = parse_bvh(format_bvh(bvh))
    assert again.position_mode == REPLACED
    np.testing.assert_allclose(forward_kinematics(again)[0], forward_kinematics(bvh)[0], atol=1e-6)


def test_position_channels_that_are_not_the_offset_are_added_to_it():
    bvh = _arm_with_elbow_positions("0.5 0 0", "0 0.5 0")  # small deltas: a stretch, not the bone
    assert bvh.position_mode == ADDED
    pos = forward_kinematics(bvh)[0]
    np.testing.assert_allclose(pos[0, 1], [11.5, 2, 3], atol=1e-12)
    # Frame 1: the root at (1, 2, 4) turned 90° about z maps the elbow's (10, 0.5, 0) to (-0.5, 10, 0).
    np.testing.assert_allclose(pos[1, 1], [0.5, 12, 4], atol=1e-12)
    assert parse_bvh(ARM).position_mode == NO_POSITIONS


def test_blender_style_whole_rig_keeps_forward_kinematics():
    bvh = parse_bvh(ARM)
    styled = parse_bvh(format_bvh(blender_style(bvh)))
    assert styled.position_mode == REPLACED and len(styled.channels[1]) == 6
    np.testing.assert_allclose(forward_kinematics(styled)[0], forward_kinematics(bvh)[0], atol=1e-6)


BIPED = """HIERARCHY
ROOT Bip01 Pelvis
{
\tOFFSET 0 90 0
\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
\tJOINT  Bip01 L Thigh \r
\t{
\t\tOFFSET 10 0 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -45 0
\t\t}
\t}
\tJOINT Bip01 R Thigh {
\t\tOFFSET -10 0 0
\t\tCHANNELS 3 Zrotation Xrotation Yrotation
\t\tEnd Site
\t\t{
\t\t\tOFFSET 0 -45 0
\t\t}
\t}
}
MOTION
Frames: 1
Frame Time: 0.033333
0 0 0 0 0 0 0 0 0 0 0 0
"""


def test_joint_names_run_to_the_end_of_the_line():
    bvh = parse_bvh(BIPED, "biped.bvh")
    assert bvh.names == ["Bip01 Pelvis", "Bip01 L Thigh", "Bip01 L Thigh_End", "Bip01 R Thigh", "Bip01 R Thigh_End"]
    np.testing.assert_allclose(forward_kinematics(bvh)[0][0, 4], [-10, 45, 0])
    assert parse_bvh(format_bvh(bvh)).names == bvh.names


def test_utf8_byte_order_mark_is_accepted(tmp_path):
    (tmp_path / "bom.bvh").write_bytes(b"\xef\xbb\xbf" + ARM.encode())
    np.testing.assert_array_equal(forward_kinematics(read_bvh(tmp_path / "bom.bvh"))[0],
                                  forward_kinematics(parse_bvh(ARM))[0])


def test_trailing_blank_lines_are_not_rows():
    assert parse_bvh(ARM + "\n\n  \n").n_frames == 2


@pytest.mark.parametrize("kind, message", [
    ("fifo", "a FIFO (named pipe), not a BVH file"), ("device", "a device, not a BVH file"),
    ("folder", "a folder, not a BVH file"), ("missing", "cannot read the BVH file (No such file"),
])
def test_only_regular_files_are_read(tmp_path, kind, message):
    """A FIFO would block and /dev/zero never ends: both are refused before a byte is read."""
    path = tmp_path / "x.bvh"
    {"fifo": lambda: os.mkfifo(path), "device": lambda: path.symlink_to("/dev/zero"), "folder": path.mkdir,
     "missing": lambda: None}[kind]()
    with pytest.raises(BvhError, match=f"x.bvh: {re.escape(message)}"):
        read_bvh(path)


def test_a_file_beyond_the_size_bound_is_refused_unread(tmp_path, monkeypatch):
    from mocapdb.core.formats import bvh

    (tmp_path / "big.bvh").write_text(ARM)
    monkeypatch.setattr(bvh, "MAX_BVH_BYTES", len(ARM) - 1)
    with pytest.raises(BvhError, match=r"big.bvh: \d+ bytes, more than a BVH file may hold"):
        read_bvh(tmp_path / "big.bvh")


def _chain(n_joints: int) -> str:
    """A chain of ``n_joints`` joints, written without recursion: the deepest hierarchy a file can hold."""
    body = ["HIERARCHY", "ROOT j0", "{", "OFFSET 0 0 0", "CHANNELS 6 Xposition Yposition Zposition "
            "Zrotation Xrotation Yrotation"]
    for j in range(1, n_joints):
        body += [f"JOINT j{j}", "{", "OFFSET 0 1 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
    body += ["}"] * n_joints + ["MOTION", "Frames: 1", "Frame Time: 0.01", " ".join(["0"] * (3 * n_joints + 3))]
    return "\n".join(body) + "\n"


def test_reading_is_linear_in_the_joint_count():
    """A 100,000-joint chain (hierarchy depth 100,000) reads with no recursion limit, in time
    growing linearly (was quadratic: 51 s); compared by ratio in one run, not by a clock bound."""
    import time

    def seconds(n):
        text = _chain(n)
        start = time.perf_counter()
        assert len(parse_bvh(text).names) == n
        return time.perf_counter() - start

    seconds(1000)
    small, large = min(seconds(10_000) for _ in range(2)), min(seconds(100_000) for _ in range(2))
    assert large < 30 * small, (small, large)  # 10x the joints: linear gives ~10x, quadratic ~100x


def test_binary_file_is_not_text(tmp_path):
    (tmp_path / "model.bvh").write_bytes(b"Kaydara FBX Binary  \x00\x1a\x00\xe8\x1c\x00\x00")
    with pytest.raises(BvhError, match="model.bvh: not a text file"):
        read_bvh(tmp_path / "model.bvh")


def test_motion_from_rotations_keeps_offsets_in_replacing_position_channels():
    bvh = _arm_with_elbow_positions("10 0 0", "10 0 0")
    rot, trans = local_transforms(bvh)
    again = replace(bvh, motion=motion_from_rotations(bvh, rot, trans[:, 0] - bvh.offsets[0]))
    np.testing.assert_allclose(again.motion[:, 6:9], bvh.motion[:, 6:9], atol=0)  # the elbow's OFFSET
    np.testing.assert_allclose(forward_kinematics(again)[0], forward_kinematics(bvh)[0], atol=1e-9)
