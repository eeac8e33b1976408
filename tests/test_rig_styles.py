"""Rigs read without a map: 15 exporters' naming styles written as BVH files, shuffled and with
extra bones; what makes a rig refused; the words of a name; `mocapdb inspect`'s evidence."""
import numpy as np
import pytest

from mocapdb.cli.main import main
from mocapdb.core.formats.bvh import read_bvh
from mocapdb.core.joint_map import JointMapError, detect_mapping, detect_unit, extract_keypoints
from mocapdb.core.rig_words import read_joint_name
from mocapdb.core.skeleton import KEYPOINTS

from .rig_styles import STYLES, T_POSE_KEYPOINTS_M, Style, rig_text, swapped_sides

LABELS = {"mixamo": "motionbuilder_mixamo", "cmu_asf": "cmu_asf", "cmu_cgspeed": "cmu_cgspeed",
          "character_creator": "character_creator", "makehuman": "makehuman_cmu",
          "game_engine": "detected (UpperArm_L, UpperLeg_L)", "max_biped": "detected (Bip01 L UpperArm, Bip01 L Thigh)"}


def _written(tmp_path, text: str, name: str = "rig.bvh"):
    path = tmp_path / name
    path.write_text(text)
    return read_bvh(path)


@pytest.mark.parametrize("shuffle_seed", [None, 7], ids=["file order", "shuffled"])
@pytest.mark.parametrize("style", sorted(STYLES))
def test_every_style_is_read_without_a_map(tmp_path, style, shuffle_seed):
    bvh = _written(tmp_path, rig_text(STYLES[style], shuffle_seed))
    mapping = detect_mapping(bvh)
    assert mapping.joints == STYLES[style].expected()
    assert mapping.convention == LABELS.get(style, mapping.convention)
    assert detect_unit(bvh, mapping) == "cm"
    points = extract_keypoints(bvh, mapping)[0]
    np.testing.assert_allclose(points, [T_POSE_KEYPOINTS_M[k] for k in KEYPOINTS], atol=1e-6)


def test_shuffling_changes_the_file_not_the_answer(tmp_path):
    plain, shuffled = (rig_text(STYLES["unreal"], seed) for seed in (None, 7))
    joints = [[line.strip() for line in text.splitlines() if "JOINT" in line] for text in (plain, shuffled)]
    assert joints[0] != joints[1] and sorted(joints[0]) == sorted(joints[1])
    assert detect_mapping(_written(tmp_path, shuffled)).joints == STYLES["unreal"].expected()


@pytest.mark.parametrize("style", ["game_engine", "cmu_cgspeed", "max_biped"])
def test_names_swapped_against_the_poses_are_refused(tmp_path, style):
    bvh = _written(tmp_path, rig_text(STYLES[style], 3, rename=swapped_sides(STYLES[style])))
    with pytest.raises(JointMapError, match="left and right do not match the poses") as err:
        detect_mapping(bvh)
    assert "facing from the toes" in str(err.value) and "lies on the character's right" in str(err.value)
    assert "found: head" in str(err.value) and "--joint-map" in str(err.value)


def _without_toes(style: Style, nose: str | None = None) -> Style:
    return Style(style.sides, {**style.names, "toe": None, "headtop": None, "nose": nose}, style.parents,
                 style.extras)


def test_without_toes_the_face_gives_the_facing(tmp_path):
    style = _without_toes(STYLES["l_prefix"], nose="Nose")
    assert "sides: facing from the face" in detect_mapping(_written(tmp_path, rig_text(style))).notes[-1]
    with pytest.raises(JointMapError, match=r"do not match the poses \(facing from the face\)"):
        detect_mapping(_written(tmp_path, rig_text(style, rename=swapped_sides(style)), "swapped.bvh"))


def test_without_toes_or_face_the_arms_and_legs_must_agree(tmp_path):
    style = _without_toes(STYLES["game_engine"])
    assert "sides: from the names" in "\n".join(detect_mapping(_written(tmp_path, rig_text(style))).notes)
    arms = {style.name(f"{s}_{k}"): style.name(f"{'rl'['lr'.index(s)]}_{k}") for s in "lr"
            for k in ("upperarm", "forearm", "hand", "finger", "thumb", "clavicle", "upperarm_twist")}
    bvh = _written(tmp_path, rig_text(style, rename={k: v for k, v in arms.items() if k}), "arms.bvh")
    with pytest.raises(JointMapError, match="left arm and the left leg on opposite sides"):
        detect_mapping(bvh)


def test_two_equal_candidates_are_refused_with_both_named(tmp_path):
    style = STYLES["game_engine"]
    twin = Style(style.sides, style.names, style.parents, style.extras + [("Hand_L2", "l_forearm", "l_hand")])
    with pytest.raises(JointMapError, match="l_hand: ambiguous, candidates Hand_L, Hand_L2"):
        detect_mapping(_written(tmp_path, rig_text(twin)))


def test_nonsense_names_are_refused_role_by_role(tmp_path):
    style = STYLES["game_engine"]
    rename = {name: f"J{i:02d}" for i, name in enumerate(style.expected().values())}
    with pytest.raises(JointMapError) as err:
        detect_mapping(_written(tmp_path, rig_text(style, rename=rename)))
    assert "l_hand: no joint's name reads as a left hand (hand, wrist)" in str(err.value)
    assert "head: no joint's name reads as a head" in str(err.value)


def test_a_head_outside_the_chest_is_refused(tmp_path):
    style = STYLES["rokoko"]
    stray = Style(style.sides, {**style.names, "head": "Skull"}, style.parents, [("Head", "pelvis", "head")])
    with pytest.raises(JointMapError, match=r"the head \(Head\) does not hang from the chest \(Spine4"):
        detect_mapping(_written(tmp_path, rig_text(stray)))


@pytest.mark.parametrize("name, side, part", [
    ("upperarm_l", "l", "upperarm"), ("upper_arm.L", "l", "upperarm"), ("UpperArm_L", "l", "upperarm"),
    ("Left_UpperArm", "l", "upperarm"), ("LEFT_FOREARM", "l", "forearm"), ("L_Thigh", "l", "thigh"),
    ("thigh_l", "l", "thigh"), ("Lf_UpArm", "l", "upperarm"), ("Rt_LoLeg", "r", "shin"), ("lhumerus", "l", "upperarm"),
    ("rtibia", "r", "shin"), ("mixamorig:RightForeArm", "r", "forearm"), ("Armature|hand.R", "r", "hand"),
    ("Character1_LeftUpLeg", "l", "thigh"), ("CC_Base_R_Calf", "r", "shin"), ("Bip01 L Calf", "l", "shin"),
    ("lowerarm_r", "r", "forearm"), ("RightShin", "r", "shin"), ("LeftAnkle", "l", "foot"), ("Head", None, "head"),
    # Not roles: twist, roll, share bones, fingers, toes, hip joints, clavicles, IK targets, props.
    ("upperarm_twist_01_l", "l", None), ("Character1_LeftForeArmRoll", "l", None),
    ("CC_Base_L_KneeShareBone", "l", None), ("LeftHandIndex1", "l", None), ("Prop_Sword", None, None),
    ("ball_r", "r", None), ("LHipJoint", "l", None), ("clavicle_l", "l", None),
    ("ik_hand_l", "l", None), ("HeadTop_End", None, None), ("RL_BoneRoot", None, None), ("Hips", None, None),
])
def test_words_of_a_name(name, side, part):
    words = read_joint_name(name)
    assert (words.side, words.part) == (side, part)


def test_shoulder_is_a_weaker_upper_arm_than_arm():
    assert (read_joint_name("LeftShoulder").strength, read_joint_name("LeftArm").strength) == (1, 2)


def test_inspect_prints_the_evidence(tmp_path, capsys):
    (tmp_path / "biped.bvh").write_text(rig_text(STYLES["max_biped"], 2))
    assert main(["inspect", str(tmp_path / "biped.bvh")]) == 0
    out = capsys.readouterr().out
    assert "convention:  detected (Bip01 L UpperArm, Bip01 L Thigh)" in out
    assert 'l_upperarm  Bip01 L UpperArm  left + "upper arm"' in out
    assert "structure: legs meet at Bip01 Pelvis (pelvis), arms at Bip01 Neck (chest)" in out
    assert "sides: facing from the toes; left arm on the character's left (cosine 1.00)" in out
