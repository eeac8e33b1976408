"""Joint mapping: convention detection, overrides, unit and up axis, keypoint extraction."""
import numpy as np
import pytest

from mocapdb.core.formats.bvh import forward_kinematics, parse_bvh, read_bvh
from mocapdb.core.joint_map import (
    _TO_Y_UP,
    UNITS,
    UP_AXES,
    JointMapError,
    describe,
    detect_mapping,
    detect_unit,
    detect_up_axis,
    extract_keypoints,
    load_joint_map_file,
)
from mocapdb.core.skeleton import KEYPOINTS, N_POINTS

from .conftest import SHARED_BVH, needs

KP = {name: i for i, name in enumerate(KEYPOINTS)}

# A T-pose in centimetres, y up, facing +z, the subject's left on +x: (key, parent, offset).
# "{side}" keys exist for l and r; the right side mirrors x.
BODY = [
    ("root", None, (0, 100, 0)), ("spine", "root", (0, 10, 0)), ("chest", "spine", (0, 20, 0)),
    ("neck", "chest", (0, 20, 0)), ("head", "neck", (0, 10, 0)),
    ("{side}_clavicle", "chest", (3, 15, 0)), ("{side}_upperarm", "{side}_clavicle", (15, 0, 0)),
    ("{side}_upperarm_twist", "{side}_upperarm", (0, 0, 0)),
    ("{side}_forearm", "{side}_upperarm", (28, 0, 0)), ("{side}_hand", "{side}_forearm", (25, 0, 0)),
    ("{side}_palm", "{side}_hand", (10, 0, 0)),
    ("{side}_hipjoint", "root", (5, -2, 0)), ("{side}_thigh", "{side}_hipjoint", (5, -3, 0)),
    ("{side}_shin", "{side}_thigh", (0, -45, 0)), ("{side}_knee_share", "{side}_shin", (0, 0, 0)),
    ("{side}_foot", "{side}_shin", (0, -42, 0)), ("{side}_toe", "{side}_foot", (0, -5, 12)),
]
LEG_CM = 87.0

# Per convention: key -> name template ({S} Left/Right, {s} l/r, {L} L/R); None drops the joint.
RIGS = {
    "cmu_asf": dict(root="root", spine="lowerback", chest="thorax", neck="lowerneck", head="head",
                    clavicle="{s}clavicle", upperarm="{s}humerus", upperarm_twist=None, forearm="{s}radius",
                    hand="{s}wrist", palm="{s}hand", hipjoint="{s}hipjoint", thigh="{s}femur", shin="{s}tibia",
                    knee_share=None, foot="{s}foot", toe="{s}toes"),
    "cmu_cgspeed": dict(root="Hips", spine="LowerBack", chest="Spine1", neck="Neck", head="Head",
                        clavicle="{S}Collar", upperarm="{S}Shoulder", upperarm_twist=None, forearm="{S}Elbow",
                        hand="{S}Wrist", palm="{S}Fingers", hipjoint="{L}HipJoint", thigh="{S}Hip",
                        shin="{S}Knee", knee_share=None, foot="{S}Ankle", toe="{S}Toe"),
    "motionbuilder_mixamo": dict(root="Hips", spine="Spine", chest="Spine1", neck="Neck", head="Head",
                                 clavicle="{S}Shoulder", upperarm="{S}Arm", upperarm_twist=None,
                                 forearm="{S}ForeArm", hand="{S}Hand", palm="{S}HandIndex1", hipjoint=None,
                                 thigh="{S}UpLeg", shin="{S}Leg", knee_share=None, foot="{S}Foot",
                                 toe="{S}ToeBase"),
    "character_creator": dict(root="CC_Base_Hip", spine="CC_Base_Waist", chest="CC_Base_Spine02",
                              neck="CC_Base_NeckTwist01", head="CC_Base_Head", clavicle="CC_Base_{L}_Clavicle",
                              upperarm="CC_Base_{L}_Upperarm", upperarm_twist="CC_Base_{L}_UpperarmTwist01",
                              forearm="CC_Base_{L}_Forearm", hand="CC_Base_{L}_Hand", palm="CC_Base_{L}_Mid1",
                              hipjoint=None, thigh="CC_Base_{L}_Thigh", shin="CC_Base_{L}_Calf",
                              knee_share="CC_Base_{L}_KneeShareBone", foot="CC_Base_{L}_Foot",
                              toe="CC_Base_{L}_ToeBase"),
    "makehuman_cmu": dict(root="hip", spine="abdomen", chest="chest", neck="neck", head="head",
                          clavicle="{s}Collar", upperarm="{s}Shldr", upperarm_twist=None, forearm="{s}ForeArm",
                          hand="{s}Hand", palm="{s}Mid1", hipjoint=None, thigh="{s}Thigh", shin="{s}Shin",
                          knee_share=None, foot="{s}Foot", toe="{s}Toe"),
}
EXPECTED_UPPERARM = {"cmu_asf": "lhumerus", "cmu_cgspeed": "LeftShoulder", "motionbuilder_mixamo": "LeftArm",
                     "character_creator": "CC_Base_L_Upperarm", "makehuman_cmu": "lShldr"}
ROOT_CHANNELS = ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]


def _nodes(names: dict, prefix: str = "", scale: float = 1.0) -> list[tuple[str, str | None, np.ndarray]]:
    """The BODY joints named for one convention; dropped joints pass their offset to their children."""
    sides = {"l": ("Left", "l", "L", 1.0), "r": ("Right", "r", "R", -1.0)}
    resolved: dict[str, tuple[str | None, np.ndarray, str | None]] = {}  # key -> (name, world cm, parent key)
    out = []
    for key, parent, offset in BODY:
        for side in ("l", "r") if "{side}" in key else (None,):
            k = key.format(side=side)
            p = parent.format(side=side) if parent else None
            long, short, upper, mirror = sides[side] if side else ("", "", "", 1.0)
            template = names[key.replace("{side}_", "")]
            world = np.array(offset, float) * [mirror, 1, 1] + (resolved[p][1] if p else 0.0)
            while p is not None and resolved[p][0] is None:
                p = resolved[p][2]
            name = None if template is None else prefix + template.format(S=long, s=short, L=upper)
            resolved[k] = (name, world, p)
            if name is not None:
                parent_world = resolved[p][1] if p else np.zeros(3)
                out.append((name, resolved[p][0] if p else None, (world - parent_world) * scale))
    return out


def rig_text(convention: str = "motionbuilder_mixamo", prefix: str = "", scale: float = 1.0,
             rename: dict[str, str] | None = None, extra_child: tuple[str, str] | None = None,
             frames: list[dict[str, float]] | None = None) -> str:
    """BVH text of BODY named as ``convention``; ``frames`` set channels by "joint:Channel" keys."""
    nodes = _nodes(RIGS[convention], prefix, scale)
    rename = rename or {}
    nodes = [(rename.get(n, n), rename.get(p, p), o) for n, p, o in nodes]
    if extra_child:
        nodes.append((extra_child[0], extra_child[1], np.array([1.0, 0, 0]) * scale))
    children: dict[str | None, list] = {}
    for node in nodes:
        children.setdefault(node[1], []).append(node)
    lines, columns = ["HIERARCHY"], []

    def emit(name: str, offset: np.ndarray, depth: int) -> None:
        pad = "  " * depth
        chans = ROOT_CHANNELS if depth == 0 else ROOT_CHANNELS[3:]
        lines.extend([f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {name}", pad + "{",
                      f"{pad}  OFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}",
                      f"{pad}  CHANNELS {len(chans)} {' '.join(chans)}"])
        columns.extend(f"{name}:{c}" for c in chans)
        for child, _, child_offset in children.get(name, []):
            emit(child, child_offset, depth + 1)
        if name not in children:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0 {5 * scale:.6f} 0", pad + "  }"])
        lines.append(pad + "}")

    root = children[None][0]
    emit(root[0], root[2], 0)
    frames = frames or [{}, {}]
    lines += ["MOTION", f"Frames: {len(frames)}", "Frame Time: 0.0333333"]
    lines += [" ".join(f"{f.get(c, 0.0):.6f}" for c in columns) for f in frames]
    return "\n".join(lines) + "\n"


def rig(**kwargs):
    return parse_bvh(rig_text(**kwargs))


@pytest.mark.parametrize("convention", sorted(RIGS))
def test_each_convention_detected(convention):
    mapping = detect_mapping(rig(convention=convention))
    assert mapping.convention == convention
    assert mapping.joints["l_upperarm"] == EXPECTED_UPPERARM[convention]
    assert set(mapping.joints) == {"head", "r_upperarm", "r_forearm", "r_hand", "l_upperarm", "l_forearm",
                                   "l_hand", "r_thigh", "r_shin", "r_foot", "l_thigh", "l_shin", "l_foot"}


def test_named_joints_per_convention():
    asf = detect_mapping(rig(convention="cmu_asf")).joints
    assert (asf["r_hand"], asf["r_thigh"], asf["r_foot"]) == ("rwrist", "rfemur", "rfoot")  # lwrist before lhand
    cc = detect_mapping(rig(convention="character_creator")).joints
    assert (cc["head"], cc["l_shin"]) == ("CC_Base_Head", "CC_Base_L_Calf")
    mh = detect_mapping(rig(convention="makehuman_cmu")).joints
    assert (mh["r_forearm"], mh["l_foot"]) == ("rForeArm", "lFoot")


def test_left_shoulder_is_upper_arm_or_clavicle_by_topology():
    cgspeed = detect_mapping(rig(convention="cmu_cgspeed")).joints
    assert (cgspeed["l_upperarm"], cgspeed["l_forearm"]) == ("LeftShoulder", "LeftElbow")
    mixamo = detect_mapping(rig(convention="motionbuilder_mixamo")).joints
    assert (mixamo["l_upperarm"], mixamo["l_forearm"]) == ("LeftArm", "LeftForeArm")
    # A LeftShoulder whose chain continues to LeftForeArm is never taken for the upper arm.
    assert "LeftShoulder" not in mixamo.values()


def test_prefixed_mixamo_rig():
    mapping = detect_mapping(rig(prefix="mixamorig:"))
    assert mapping.convention == "motionbuilder_mixamo"
    assert mapping.joints["r_hand"] == "mixamorig:RightHand"
    assert detect_mapping(rig(prefix="Armature|")).joints["l_shin"] == "Armature|LeftLeg"


def test_missing_hand_names_the_role_and_suggests_joint_map():
    bvh = rig(rename={"LeftHand": "LeftPalm"})
    with pytest.raises(JointMapError) as err:
        detect_mapping(bvh)
    message = str(err.value)
    assert "l_hand" in message and "--joint-map" in message
    assert "r_hand" not in message and "l_forearm" not in message


def test_unknown_rig_names_every_role():
    bvh = parse_bvh(rig_text().replace("Left", "Port").replace("Right", "Starboard").replace("Head", "Skull"))
    with pytest.raises(JointMapError) as err:
        detect_mapping(bvh)
    for role in ("head", "r_upperarm", "l_hand", "r_thigh", "l_foot"):
        assert f"{role}:" in str(err.value)


def test_toml_override_fixes_incomplete_rig(tmp_path):
    path = tmp_path / "map.toml"
    path.write_text('unit = "cm"\nup_axis = "y"\n[joints]\nl_hand = "LeftPalm"\n')
    loaded = load_joint_map_file(path)
    assert (loaded.joints, loaded.unit, loaded.up_axis) == ({"l_hand": "LeftPalm"}, "cm", "y")
    mapping = detect_mapping(rig(rename={"LeftHand": "LeftPalm"}), loaded.joints)
    assert mapping.joints["l_hand"] == "LeftPalm"
    assert mapping.convention == "motionbuilder_mixamo + joint map"


# The mixamo rig's joints under 3ds Max Biped names (spaces inside), and a joint map naming every role.
_BIPED_LIMBS = {"Shoulder": "Clavicle", "Arm": "UpperArm", "ForeArm": "Forearm", "Hand": "Hand",
                "HandIndex1": "Finger0", "UpLeg": "Thigh", "Leg": "Calf", "Foot": "Foot", "ToeBase": "Toe0"}
BIPED_NAMES = {"Hips": "Bip01 Pelvis", "Spine": "Bip01 Spine", "Spine1": "Bip01 Spine1", "Neck": "Bip01 Neck",
               "Head": "Bip01 Head", **{f"{side}{mixamo}": f"Bip01 {side[0]} {biped}" for side in ("Left", "Right")
                                        for mixamo, biped in _BIPED_LIMBS.items()}}
BIPED_MAP = """[joints]
head = "Bip01 Head"
l_upperarm = "Bip01 L UpperArm"
l_forearm = "Bip01 L Forearm"
l_hand = "Bip01 L Hand"
r_upperarm = "Bip01 R UpperArm"
r_forearm = "Bip01 R Forearm"
r_hand = "Bip01 R Hand"
l_thigh = "Bip01 L Thigh"
l_shin = "Bip01 L Calf"
l_foot = "Bip01 L Foot"
r_thigh = "Bip01 R Thigh"
r_shin = "Bip01 R Calf"
r_foot = "Bip01 R Foot"
"""
MOVE = [{}, {"Hips:Yrotation": 40.0, "LeftArm:Zrotation": 30.0, "RightLeg:Xrotation": 25.0, "Hips:Xposition": 7.0}]


def _mapped(bvh):
    """``bvh`` and its detected mapping (the first arguments of ``extract_keypoints``, ``describe``)."""
    return bvh, detect_mapping(bvh)


def test_biped_names_with_spaces_through_a_joint_map(tmp_path):
    frames = [{f"{BIPED_NAMES[k.split(':')[0]]}:{k.split(':')[1]}": v for k, v in f.items()} for f in MOVE]
    (tmp_path / "biped.bvh").write_text(rig_text(rename=BIPED_NAMES, frames=frames))
    (tmp_path / "biped.toml").write_text(BIPED_MAP)
    bvh = read_bvh(tmp_path / "biped.bvh")
    assert "Bip01 L Thigh" in bvh.names and "Bip01 L Toe0_End" in bvh.names
    mapping = detect_mapping(bvh, load_joint_map_file(tmp_path / "biped.toml").joints)
    assert mapping.convention == "joint map" and mapping.joints["l_shin"] == "Bip01 L Calf"
    np.testing.assert_allclose(extract_keypoints(bvh, mapping), extract_keypoints(*_mapped(rig(frames=MOVE))),
                               atol=1e-9)


def test_joint_map_example_of_the_docs_works(tmp_path):
    from .conftest import ROOT

    doc = (ROOT / "data_specs" / "joint_conventions.md").read_text(encoding="utf-8")
    example = doc.split("## The joint-map file")[1].split("```toml\n")[1].split("```")[0]
    (tmp_path / "map.toml").write_text(example)
    loaded = load_joint_map_file(tmp_path / "map.toml")
    bvh = rig(rename={"LeftHand": "Bip01 L Palm", "RightHand": "Bip01 R Palm"})
    mapping = detect_mapping(bvh, loaded.joints)
    assert (mapping.joints["l_hand"], mapping.joints["r_hand"]) == ("Bip01 L Palm", "Bip01 R Palm")
    assert np.isfinite(extract_keypoints(bvh, mapping, loaded.unit, loaded.up_axis)).all()


def test_blender_style_position_channels_keep_the_keypoints(tmp_path, capsys):
    from mocapdb.cli.main import main
    from mocapdb.core.formats.bvh import format_bvh

    from .test_bvh import blender_style

    plain = rig(frames=MOVE)
    (tmp_path / "blender.bvh").write_text(format_bvh(blender_style(plain)))
    styled = read_bvh(tmp_path / "blender.bvh")
    np.testing.assert_allclose(extract_keypoints(*_mapped(styled)), extract_keypoints(*_mapped(plain)), atol=1e-5)
    assert "non-root position channels: none" in describe(*_mapped(plain))
    assert main(["inspect", str(tmp_path / "blender.bvh")]) == 0
    assert "non-root position channels: replace the OFFSET (Blender style)" in capsys.readouterr().out


def test_ambiguous_candidates_are_listed_and_override_resolves():
    bvh = rig(extra_child=("mixamorig:LeftHand", "LeftHand"))
    with pytest.raises(JointMapError) as err:
        detect_mapping(bvh)
    assert "l_hand: ambiguous" in str(err.value)
    assert "LeftHand, mixamorig:LeftHand" in str(err.value)
    assert detect_mapping(bvh, {"l_hand": "LeftHand"}).joints["l_hand"] == "LeftHand"


def test_override_breaking_the_chain_is_an_error():
    with pytest.raises(JointMapError, match="parent→descendant"):
        detect_mapping(rig(), {"l_hand": "RightHand"})


def test_left_and_right_chains_must_be_disjoint():
    same = {"l_upperarm": "RightArm", "l_forearm": "RightForeArm", "l_hand": "RightHand"}
    with pytest.raises(JointMapError, match="separate chains"):
        detect_mapping(rig(), same)


def test_override_errors_list_valid_names():
    with pytest.raises(JointMapError, match="valid roles: head, r_upperarm"):
        detect_mapping(rig(), {"l_wrist": "LeftHand"})
    with pytest.raises(JointMapError, match="not in the file.*LeftForeArm"):
        detect_mapping(rig(), {"l_hand": "NoSuchJoint"})


@pytest.mark.parametrize("text, message", [
    ("[joints\nl_hand = 'x'\n", "not a valid TOML"),
    ("[joints]\nleft_hand = 'LeftHand'\n", "valid roles"),
    ("[joints]\nl_hand = 3\n", "role = "),
    ("unit = 'furlong'\n", "unit 'furlong'"),
    ("up_axis = 'w'\n", "up_axis 'w'"),
    ("joint = {}\n", "unknown key"),
])
def test_bad_joint_map_file(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(JointMapError, match=message) as err:
        load_joint_map_file(path)
    assert str(path) in str(err.value)


def test_missing_joint_map_file(tmp_path):
    with pytest.raises(JointMapError, match="cannot read"):
        load_joint_map_file(tmp_path / "none.toml")


@pytest.mark.parametrize("unit", ["m", "cm", "mm", "in", "cmu"])
def test_unit_detected_from_leg_length(unit):
    bvh = rig(scale=0.01 / UNITS[unit])
    mapping = detect_mapping(bvh)
    assert detect_unit(bvh, mapping) == unit
    legs = extract_keypoints(bvh, mapping)[0, [KP["l_hip"], KP["l_ankle"]], 1]
    assert legs[0] - legs[1] == pytest.approx(LEG_CM / 100)


def test_implausible_size_names_the_length():
    bvh = rig(scale=0.05)
    with pytest.raises(JointMapError, match="4.35 file units"):
        detect_unit(bvh, detect_mapping(bvh))


def test_t_pose_keypoints_hand_computed():
    # Frame 1 turns the head 90° about y (towards the subject's left, +x): the nose turns with it.
    bvh = rig(frames=[{}, {"Head:Yrotation": 90.0}])
    points = extract_keypoints(bvh, detect_mapping(bvh))
    expected = {
        "head": (0, 1.62, 0.10), "neck": (0, 1.45, 0), "pelvis": (0, 0.95, 0),
        "r_shoulder": (-0.18, 1.45, 0), "r_elbow": (-0.46, 1.45, 0), "r_wrist": (-0.71, 1.45, 0),
        "l_shoulder": (0.18, 1.45, 0), "l_elbow": (0.46, 1.45, 0), "l_wrist": (0.71, 1.45, 0),
        "r_hip": (-0.10, 0.95, 0), "r_knee": (-0.10, 0.50, 0), "r_ankle": (-0.10, 0.08, 0),
        "l_hip": (0.10, 0.95, 0), "l_knee": (0.10, 0.50, 0), "l_ankle": (0.10, 0.08, 0),
    }
    assert points.shape == (2, N_POINTS, 3) and points.dtype == np.float64
    np.testing.assert_allclose(points[0], [expected[k] for k in KEYPOINTS], atol=1e-9)
    np.testing.assert_allclose(points[1, KP["head"]], (0.10, 1.62, 0.0), atol=1e-9)


def test_up_axis_rotations_are_proper():
    for axis, matrix in _TO_Y_UP.items():
        assert np.linalg.det(matrix) == pytest.approx(1.0)
        unit = np.zeros(3)
        unit["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
        np.testing.assert_allclose(matrix @ unit, [0, 1, 0], atol=1e-12)
    assert set(_TO_Y_UP) == set(UP_AXES)


@pytest.mark.parametrize("channel, angle, axis", [
    (None, 0.0, "y"), ("Xrotation", 90.0, "z"), ("Xrotation", -90.0, "-z"),
    ("Zrotation", -90.0, "x"), ("Zrotation", 90.0, "-x"), ("Zrotation", 180.0, "-y")])
def test_up_axis_detected_and_turned_to_y(channel, angle, axis):
    upright = rig(frames=[{}, {"LeftArm:Zrotation": 30.0}])
    reference = extract_keypoints(upright, detect_mapping(upright))
    turn = {f"Hips:{channel}": angle} if channel else {}
    bvh = rig(frames=[turn, {**turn, "LeftArm:Zrotation": 30.0}])
    mapping = detect_mapping(bvh)
    idx = [bvh.index(mapping.joints[r]) for r in ("r_upperarm", "l_upperarm", "r_foot", "l_foot")]
    assert detect_up_axis(forward_kinematics(bvh)[0], idx[:2], idx[2:]) == axis
    points = extract_keypoints(bvh, mapping)
    rel, ref = (p - p[:, KP["pelvis"]][:, None] for p in (points, reference))
    # Same pose up to a turn about the vertical: heights and horizontal distances agree.
    np.testing.assert_allclose(rel[..., 1], ref[..., 1], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(rel[..., [0, 2]], axis=-1),
                               np.linalg.norm(ref[..., [0, 2]], axis=-1), atol=1e-9)


def test_lying_body_has_no_up_axis():
    positions = np.array([[[1.0, 1.0, 0.0], [0.0, 0.0, 0.0]]])
    with pytest.raises(JointMapError, match="near no world axis"):
        detect_up_axis(positions, [0], [1])


def test_describe_lists_roles_and_sources():
    bvh = rig()
    text = describe(bvh, detect_mapping(bvh), up_axis="y")
    assert "convention:  motionbuilder_mixamo" in text
    assert "unit:        cm (detected)" in text and "up axis:     y (given)" in text
    assert "l_hand      LeftHand" in text and "leg length:  0.870 m" in text


REAL_FILES = ["001_01.bvh", "002_01.bvh"]


@needs(SHARED_BVH)
@pytest.mark.parametrize("name", REAL_FILES)
def test_real_character_creator_file(name):
    bvh = read_bvh(SHARED_BVH / name)
    mapping = detect_mapping(bvh)
    assert mapping.convention == "character_creator"
    assert detect_unit(bvh, mapping) == "cm"
    points = extract_keypoints(bvh, mapping)
    assert points.shape == (bvh.n_frames, N_POINTS, 3) and np.all(np.isfinite(points))
    nose, neck, pelvis = points[:, KP["head"]], points[:, KP["neck"]], points[:, KP["pelvis"]]
    ankles = points[:, [KP["r_ankle"], KP["l_ankle"]]].mean(axis=1)
    assert 1.4 <= np.median(nose[:, 1] - ankles[:, 1]) <= 1.9
    left_minus_right = points[:, KP["l_shoulder"]] - points[:, KP["r_shoulder"]]
    forward = np.cross(left_minus_right, neck - pelvis)
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    assert np.median(np.sum((nose - neck) * forward, axis=-1)) > 0.05
    # Independent of the shoulders: the eyes give the facing. Turned to face +z, the left
    # shoulder must be on +x (FK here is y up and in cm, as detected).
    pos, _ = forward_kinematics(bvh)
    eyes = (pos[:, bvh.index("CC_Base_L_Eye")] + pos[:, bvh.index("CC_Base_R_Eye")]) / 2
    face = eyes - pos[:, bvh.index("CC_Base_Head")]
    yaw = np.arctan2(face[:, 0], face[:, 2])  # facing angle from +z towards +x
    x_after_turn = np.cos(yaw) * left_minus_right[:, 0] - np.sin(yaw) * left_minus_right[:, 2]
    assert np.mean(x_after_turn > 0) > 0.95


@pytest.mark.parametrize("unit", ["m", "cm"])
def test_universal_rig_round_trip(tmp_path, unit):
    """A BVH of mocapdb's own rig (`mocapdb stereo`, `track_*.bvh`) maps back onto the same 15 points."""
    from mocapdb.core.clips import ClipOptions, process_clip
    from mocapdb.core.formats.bvh import write_bvh
    from mocapdb.core.motion import Motion
    from mocapdb.core.outputs import motion_bvh
    from mocapdb.core.skeleton import PELVIS, pose_from_rotations

    from .conftest import SAMPLE_BVH

    clip = process_clip(SAMPLE_BVH / "002_01.bvh", SAMPLE_BVH, ClipOptions(fps=30.0))
    quats = clip.quaternions[:40].astype(np.float64)
    expected = pose_from_rotations(quats, clip.positions[:40, PELVIS])
    path = tmp_path / "universal.bvh"
    write_bvh(path, motion_bvh(Motion(quats, expected[:, PELVIS], 30.0), unit))
    bvh = read_bvh(path)
    mapping = detect_mapping(bvh)
    assert mapping.convention == "mocapdb_universal"
    assert (mapping.joints["head"], mapping.joints["l_hand"], mapping.joints["r_foot"]) == \
        ("neck_End", "l_elbow_End", "r_knee_End")
    assert detect_unit(bvh, mapping) == unit
    np.testing.assert_allclose(extract_keypoints(bvh, mapping), expected, atol=1e-5)
    # `mocapdb build` takes it like any other source.
    rebuilt = process_clip(path, tmp_path, ClipOptions(fps=30.0))
    assert rebuilt.convention == "mocapdb_universal" and np.all(np.isfinite(rebuilt.positions))
