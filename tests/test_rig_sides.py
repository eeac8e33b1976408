"""Sides of a rig against its poses: clear names stand unless the poses clearly contradict them.

A real CMU run (Character Creator names) renamed to a studio's ``UpperArm_L`` convention, its
trunk turned at the waist in every frame (issue 36, item 5).
"""
import re
from dataclasses import replace

import numpy as np
import pytest

from mocapdb.core.formats.bvh import Bvh, accumulate_transforms, local_transforms, motion_from_rotations, read_bvh
from mocapdb.core.joint_map import JointMapError, detect_mapping

from .conftest import SHARED_BVH, needs

pytestmark = needs(SHARED_BVH)

RUN = "002_03.bvh"       # CMU subject 2, "run/jog"
WAIST = "CC_Base_Waist"  # carries the spine, the arms and the head; the legs hang from the pelvis
SIDE_NOTE = r"left {} on the character's left \(cosine (0\.\d\d|1\.00)\)"


def _studio_name(name: str, swap: bool) -> str:
    """``CC_Base_L_Upperarm`` → ``UpperArm_L`` (``UpperArm_R`` when ``swap``), ``CC_Base_Hip`` → ``Hips``."""
    sided = re.fullmatch(r"CC_Base_([LR])_(\w+)", name)
    if sided:
        side = {"L": "R", "R": "L"}[sided[1]] if swap else sided[1]
        return f"{sided[2].replace('Upperarm', 'UpperArm')}_{side}"
    return {"CC_Base_Hip": "Hips"}.get(name, name.removeprefix("CC_Base_"))


def _studio(bvh: Bvh, swap: bool = False) -> Bvh:
    return replace(bvh, names=[_studio_name(n, swap) for n in bvh.names])


def _rotation(axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """Rotations ``[F, 3, 3]`` by ``angle_deg`` about the unit ``axis [F, 3]`` (right-handed)."""
    x, y, z = axis.T
    k = np.stack([np.stack([0 * x, -z, y], -1), np.stack([z, 0 * x, -x], -1), np.stack([-y, x, 0 * x], -1)], -2)
    angle = np.radians(angle_deg)
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _turned(bvh: Bvh, joint: str, angle_deg: float, about: str) -> Bvh:
    """``joint`` and what hangs from it turned by ``angle_deg`` in every frame, about the character's
    left (``about="left"``: positive leans forward) or the vertical (``"up"``)."""
    local, trans = local_transforms(bvh)
    pos, rot = accumulate_transforms(bvh.parents, local, trans)
    lateral = pos[:, bvh.index("CC_Base_L_Thigh")] - pos[:, bvh.index("CC_Base_R_Thigh")]
    axis = lateral if about == "left" else np.broadcast_to([0.0, 1.0, 0.0], lateral.shape)  # CMU files: y up
    j = bvh.index(joint)
    parent = rot[:, bvh.parents[j]]
    turn = _rotation(axis / np.linalg.norm(axis, axis=-1, keepdims=True), angle_deg)
    local[:, j] = np.swapaxes(parent, -1, -2) @ turn @ parent @ local[:, j]
    return replace(bvh, motion=motion_from_rotations(bvh, local, trans[:, 0] - bvh.offsets[0]))


def _without(bvh: Bvh, tops: set[str]) -> Bvh:
    """``bvh`` without the joints ``tops`` and all that hangs from them."""
    gone: set[int] = set()
    for j, p in enumerate(bvh.parents):
        if bvh.names[j] in tops or p in gone:
            gone.add(j)
    kept = [j for j in range(len(bvh.names)) if j not in gone]
    index = {j: i for i, j in enumerate(kept)}
    columns = [c for j in kept for c in range(bvh.channel_start[j], bvh.channel_start[j] + len(bvh.channels[j]))]
    parents = np.array([index.get(int(bvh.parents[j]), -1) for j in kept])
    return replace(bvh, names=[bvh.names[j] for j in kept], parents=parents, offsets=bvh.offsets[kept],
                   channels=[bvh.channels[j] for j in kept], end_site=bvh.end_site[kept], motion=bvh.motion[:, columns])


@pytest.fixture(scope="module")
def run() -> Bvh:
    return read_bvh(SHARED_BVH / RUN)


def _sides_note(bvh: Bvh) -> str:
    return next(n for n in detect_mapping(bvh).notes if n.startswith("sides:"))


def test_an_upright_run_keeps_its_note(run):
    note = _sides_note(_studio(run))
    assert re.fullmatch(r"sides: facing from the toes; " + SIDE_NOTE.format("arm") + ", " + SIDE_NOTE.format("leg"),
                        note)
    assert min(float(c) for c in re.findall(r"cosine (\S+)\)", note)) > 0.9


@pytest.mark.parametrize("lean_deg", [-40.0, 40.0])
def test_a_leaning_trunk_keeps_the_named_sides(run, lean_deg):
    """The old check took up from the hips to the shoulders in each frame: a trunk leaning back
    40° from the legs tipped the toes pointing down into the facing, cosines 0.43 and 0.46."""
    note = _sides_note(_studio(_turned(run, WAIST, lean_deg, about="left")))
    assert re.search(SIDE_NOTE.format("arm"), note) and re.search(SIDE_NOTE.format("leg"), note)


def test_poses_that_cannot_tell_leave_the_sides_to_the_names(run):
    """Shoulders turned 70° from the hips: the arms lie on neither side (cosine 0.40), the legs on the left."""
    note = _sides_note(_studio(_turned(run, WAIST, 70.0, about="up")))
    cosine = float(re.search(r"left arm from its name, the poses cannot tell \(cosine (\S+)\)", note)[1])
    assert 0.2 < cosine < 0.5 and re.search(SIDE_NOTE.format("leg"), note)


@pytest.mark.parametrize("lean_deg", [-40.0, 0.0, 40.0])
def test_swapped_names_are_refused(run, lean_deg):
    swapped = _studio(_turned(run, WAIST, lean_deg, about="left"), swap=True)
    with pytest.raises(JointMapError, match="left and right do not match the poses") as err:
        detect_mapping(swapped)
    clearly_right = r"named left lies on the character's right \(cosine (-0\.[5-9]\d|-1\.00)\)"
    assert len(re.findall(clearly_right, str(err.value))) == 2


def test_without_a_facing_arms_and_legs_that_cannot_tell_leave_the_sides_to_the_names(run):
    faceless = _without(run, {"CC_Base_FacialBone", "CC_Base_L_ToeBase", "CC_Base_L_ToeBaseShareBone",
                              "CC_Base_R_ToeBase", "CC_Base_R_ToeBaseShareBone"})
    note = _sides_note(_studio(_turned(faceless, WAIST, 70.0, about="up")))
    assert re.fullmatch(r"sides: from the names; no toes or face show the facing, and the poses cannot tell "
                        r"whether the left arm and the left leg lie on the same side \(cosine 0\.[234]\d\)", note)
