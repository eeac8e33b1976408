"""BVH reading, writing and forward kinematics against hand-computed poses."""
import numpy as np
import pytest

from mocapdb.bvh import BvhError, format_bvh, forward_kinematics, parse_bvh, read_bvh

from .conftest import SHARED_BVH

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


@pytest.mark.skipif(not SHARED_BVH.is_dir(), reason="shared CMU data not present")
def test_real_file_round_trip(tmp_path):
    from mocapdb.bvh import write_bvh
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
    (ARM.replace("Frame Time: 0.0083333", "Frame Time: 0"), "nothing to read"),
])
def test_bad_input_gives_clear_error(text, message):
    with pytest.raises(BvhError, match=message):
        parse_bvh(text, "bad.bvh")


def test_missing_file_names_it(tmp_path):
    with pytest.raises(BvhError, match="nope.bvh: cannot read"):
        read_bvh(tmp_path / "nope.bvh")
