"""Synthetic BVH rigs in many exporters' naming styles, written as real BVH text for the tests.

One body in centimetres, y up, T-pose facing +z (the character's left on +x), with a spine,
clavicles, twist bones, fingers, toes, a prop in the right hand and, per style, extra bones (IK
targets, more props). A style
names each body key (``None`` drops the joint: its children hang from its parent, the geometry
unchanged) and may hang a key from another parent (3ds Max Biped's clavicles hang from the neck).
"""
from __future__ import annotations

import random
from dataclasses import dataclass, field

import numpy as np

# key, parent key, offset (cm) from the parent; "{side}" keys exist for l and r, the right mirrors x.
BODY = [
    ("base", None, (0, 0, 0)), ("pelvis", "base", (0, 95, 0)),
    ("{side}_hipjoint", "pelvis", (5, -1, 0)), ("{side}_thigh", "{side}_hipjoint", (5, -1, 0)),
    ("{side}_thigh_twist", "{side}_thigh", (0, -20, 0)), ("{side}_shin", "{side}_thigh", (0, -43, 0)),
    ("{side}_shin_twist", "{side}_shin", (0, -20, 0)), ("{side}_foot", "{side}_shin", (0, -42, 0)),
    ("{side}_toe", "{side}_foot", (0, -6, 13)),
    ("spine1", "pelvis", (0, 10, 0)), ("spine2", "spine1", (0, 12, 0)), ("chest", "spine2", (0, 13, 0)),
    ("neck", "chest", (0, 17, 0)), ("head", "neck", (0, 10, 0)), ("headtop", "head", (0, 18, 0)),
    ("nose", "head", (0, 2, 10)),
    ("{side}_clavicle", "chest", (3, 12, 0)), ("{side}_upperarm", "{side}_clavicle", (15, 3, 0)),
    ("{side}_upperarm_twist", "{side}_upperarm", (14, 0, 0)), ("{side}_forearm", "{side}_upperarm", (28, 0, 0)),
    ("{side}_forearm_twist", "{side}_forearm", (12, 0, 0)), ("{side}_hand", "{side}_forearm", (25, 0, 0)),
    ("{side}_finger", "{side}_hand", (8, 0, 0)), ("{side}_thumb", "{side}_hand", (3, 0, 4)),
]
LEG_CM = 85.0
# The 15 keypoints of frame 0 (metres; KEYPOINTS order), worked out by hand from BODY: the nose is
# the head joint + 0.10 m forward and 0.02 m up.
T_POSE_KEYPOINTS_M = {
    "head": (0, 1.59, 0.10), "neck": (0, 1.45, 0), "r_shoulder": (-0.18, 1.45, 0), "r_elbow": (-0.46, 1.45, 0),
    "r_wrist": (-0.71, 1.45, 0), "l_shoulder": (0.18, 1.45, 0), "l_elbow": (0.46, 1.45, 0),
    "l_wrist": (0.71, 1.45, 0), "r_hip": (-0.10, 0.93, 0), "r_knee": (-0.10, 0.50, 0), "r_ankle": (-0.10, 0.08, 0),
    "l_hip": (0.10, 0.93, 0), "l_knee": (0.10, 0.50, 0), "l_ankle": (0.10, 0.08, 0), "pelvis": (0, 0.93, 0),
}
ROLE_KEYS = {"head": "head", "upperarm": "upperarm", "forearm": "forearm", "hand": "hand", "thigh": "thigh",
             "shin": "shin", "foot": "foot"}


@dataclass
class Style:
    """An exporter's names: ``names`` key → template (``{s}`` the side word), ``sides`` its (left,
    right) words, ``parents`` key → other parent key, ``extras`` (name, parent key or name, key whose
    position it takes)."""

    sides: tuple[str, str]
    names: dict[str, str | None]
    parents: dict[str, str] = field(default_factory=dict)
    extras: list[tuple[str, str, str]] = field(default_factory=list)

    def name(self, key: str) -> str | None:
        """The joint name of a body key (``l_hand``, ``chest``), or None when the style has none."""
        side, part = (key[0], key[2:]) if key[1:2] == "_" else (None, key)
        template = self.names.get(part)
        if template is None:
            return None
        return template.format(s=self.sides["lr".index(side)]) if side else template

    def expected(self) -> dict[str, str]:
        """Role → the joint name the style gives it (the answer a recogniser must find)."""
        roles = {"head": self.name("head")}
        for side in "lr":
            roles.update({f"{side}_{part}": self.name(f"{side}_{key}") for part, key in ROLE_KEYS.items()
                          if part != "head"})
        return roles


def _style(sides, base=None, pelvis="Hips", hipjoint=None, thigh=None, thigh_twist=None, shin=None,
           shin_twist=None, foot=None, toe=None, spine1="Spine", spine2="Spine1", chest="Spine2", neck="Neck",
           head="Head", headtop=None, nose=None, clavicle=None, upperarm=None, upperarm_twist=None, forearm=None,
           forearm_twist=None, hand=None, finger=None, thumb=None, parents=None, extras=None) -> Style:
    names = {k: v for k, v in locals().items() if k not in ("sides", "parents", "extras")}
    return Style(sides, names, parents or {}, extras or [])


# MotionBuilder's names, which Mixamo (prefix "mixamorig:") and HumanIK ("Character1_") keep.
MOTIONBUILDER = dict(pelvis="Hips", spine1="Spine", spine2="Spine1", chest="Spine2", neck="Neck", head="Head",
                     headtop="HeadTop_End", clavicle="{s}Shoulder", upperarm="{s}Arm", forearm="{s}ForeArm",
                     hand="{s}Hand", finger="{s}HandIndex1", thumb="{s}HandThumb1", thigh="{s}UpLeg", shin="{s}Leg",
                     foot="{s}Foot", toe="{s}ToeBase")


def _prefixed(prefix: str, names: dict[str, str | None]) -> Style:
    return _style(("Left", "Right"), **{k: prefix + v if v else None for k, v in names.items()})


STYLES: dict[str, Style] = {
    "unreal": _style(
        ("l", "r"), base="root", pelvis="pelvis", spine1="spine_01", spine2="spine_02", chest="spine_03",
        neck="neck_01", head="head", clavicle="clavicle_{s}", upperarm="upperarm_{s}",
        upperarm_twist="upperarm_twist_01_{s}", forearm="lowerarm_{s}", forearm_twist="lowerarm_twist_01_{s}",
        hand="hand_{s}", finger="index_01_{s}", thumb="thumb_01_{s}", thigh="thigh_{s}",
        thigh_twist="thigh_twist_01_{s}", shin="calf_{s}", shin_twist="calf_twist_01_{s}", foot="foot_{s}",
        toe="ball_{s}",
        extras=[("ik_foot_root", "base", "base"), ("ik_foot_l", "ik_foot_root", "l_foot"),
                ("ik_foot_r", "ik_foot_root", "r_foot"), ("ik_hand_root", "base", "base"),
                ("ik_hand_gun", "ik_hand_root", "r_hand"), ("ik_hand_l", "ik_hand_gun", "l_hand"),
                ("ik_hand_r", "ik_hand_gun", "r_hand")]),
    "blender_rigify": _style(
        ("L", "R"), pelvis="spine", spine1="spine.001", spine2="spine.002", chest="spine.003", neck="neck",
        head="head", clavicle="shoulder.{s}", upperarm="upper_arm.{s}", upperarm_twist="upper_arm.{s}.001",
        forearm="forearm.{s}", forearm_twist="forearm.{s}.001", hand="hand.{s}", finger="f_index.01.{s}",
        thumb="thumb.01.{s}", hipjoint="pelvis.{s}", thigh="thigh.{s}", thigh_twist="thigh.{s}.001",
        shin="shin.{s}", foot="foot.{s}", toe="toe.{s}"),
    "game_engine": _style(
        ("L", "R"), pelvis="Hips", spine1="Spine", spine2="Chest", chest="UpperChest", clavicle="Shoulder_{s}",
        upperarm="UpperArm_{s}", upperarm_twist="UpperArmTwist_{s}", forearm="LowerArm_{s}", hand="Hand_{s}",
        finger="Index1_{s}", thumb="Thumb1_{s}", thigh="UpperLeg_{s}", shin="LowerLeg_{s}", foot="Foot_{s}",
        toe="Toes_{s}", extras=[("Prop_R", "r_hand", "r_finger")]),
    "left_prefix": _style(
        ("Left", "Right"), clavicle="{s}_Shoulder", upperarm="{s}_UpperArm", forearm="{s}_Forearm",
        forearm_twist="{s}_ForearmRoll", hand="{s}_Hand", finger="{s}_Index1", thigh="{s}_Thigh",
        shin="{s}_Calf", foot="{s}_Foot", toe="{s}_Toe"),
    "l_prefix": _style(
        ("L", "R"), pelvis="Root_Hips", clavicle="{s}_Clavicle", upperarm="{s}_UpperArm", forearm="{s}_Elbow",
        hand="{s}_Wrist", finger="{s}_Index1", thumb="{s}_Thumb1", thigh="{s}_Thigh",
        thigh_twist="{s}_ThighTwist", shin="{s}_Knee", foot="{s}_Ankle", toe="{s}_Toe"),
    "armature_namespace": _style(
        ("L", "R"), pelvis="Armature|Hips", spine1="Armature|Spine", spine2="Armature|Spine1",
        chest="Armature|Chest", neck="Armature|Neck", head="Armature|Head", clavicle="Armature|Collar.{s}",
        upperarm="Armature|UpperArm.{s}", forearm="Armature|ForeArm.{s}", hand="Armature|Hand.{s}",
        finger="Armature|Finger.{s}", thigh="Armature|UpLeg.{s}", shin="Armature|Leg.{s}",
        foot="Armature|Foot.{s}", toe="Armature|Toe.{s}"),
    "motionbuilder_humanik": _prefixed("Character1_", {
        **MOTIONBUILDER, "base": "Reference", "headtop": None, "upperarm_twist": "{s}ArmRoll",
        "forearm_twist": "{s}ForeArmRoll", "thigh_twist": "{s}UpLegRoll", "shin_twist": "{s}LegRoll"}),
    "mixamo": _prefixed("mixamorig:", MOTIONBUILDER),
    "cmu_asf": _style(
        ("l", "r"), pelvis="root", spine1="lowerback", spine2="upperback", chest="thorax", neck="lowerneck",
        head="head", headtop="upperhead", clavicle="{s}clavicle", upperarm="{s}humerus", forearm="{s}radius",
        hand="{s}wrist", finger="{s}fingers", thumb="{s}thumb", hipjoint="{s}hipjoint", thigh="{s}femur",
        shin="{s}tibia", foot="{s}foot", toe="{s}toes"),
    "cmu_cgspeed": _style(
        ("Left", "Right"), spine1="LowerBack", spine2="Spine", chest="Spine1", clavicle="{s}Collar",
        upperarm="{s}Shoulder", forearm="{s}Elbow", hand="{s}Wrist", finger="{s}Fingers", thumb="{s}Thumb",
        thigh="{s}Hip", shin="{s}Knee", foot="{s}Ankle", toe="{s}Toe"),
    "character_creator": _style(
        ("L", "R"), base="RL_BoneRoot", pelvis="CC_Base_Hip", hipjoint=None, spine1="CC_Base_Waist",
        spine2="CC_Base_Spine01", chest="CC_Base_Spine02", neck="CC_Base_NeckTwist01", head="CC_Base_Head",
        clavicle="CC_Base_{s}_Clavicle", upperarm="CC_Base_{s}_Upperarm",
        upperarm_twist="CC_Base_{s}_UpperarmTwist01", forearm="CC_Base_{s}_Forearm",
        forearm_twist="CC_Base_{s}_ElbowShareBone", hand="CC_Base_{s}_Hand", finger="CC_Base_{s}_Mid1",
        thumb="CC_Base_{s}_Thumb1", thigh="CC_Base_{s}_Thigh", thigh_twist="CC_Base_{s}_ThighTwist01",
        shin="CC_Base_{s}_Calf", shin_twist="CC_Base_{s}_KneeShareBone", foot="CC_Base_{s}_Foot",
        toe="CC_Base_{s}_ToeBase"),
    "max_biped": _style(
        ("L", "R"), base="Bip01", pelvis="Bip01 Pelvis", spine1="Bip01 Spine", spine2="Bip01 Spine1",
        chest="Bip01 Spine2", neck="Bip01 Neck", head="Bip01 Head", headtop="Bip01 HeadNub",
        clavicle="Bip01 {s} Clavicle", upperarm="Bip01 {s} UpperArm", upperarm_twist="Bip01 {s}UpArmTwist",
        forearm="Bip01 {s} Forearm", forearm_twist="Bip01 {s}ForeTwist", hand="Bip01 {s} Hand",
        finger="Bip01 {s} Finger0", thigh="Bip01 {s} Thigh", shin="Bip01 {s} Calf", foot="Bip01 {s} Foot",
        toe="Bip01 {s} Toe0", parents={"clavicle": "neck"}),
    "rokoko": _style(
        ("Left", "Right"), spine1="Spine1", spine2="Spine2", chest="Spine4", clavicle="{s}Shoulder",
        upperarm="{s}Arm", forearm="{s}ForeArm", hand="{s}Hand", finger="{s}IndexProximal",
        thumb="{s}ThumbProximal", thigh="{s}Thigh", shin="{s}Shin", foot="{s}Foot", toe="{s}Toe",
        extras=[("Prop1", "pelvis", "r_hand")]),
    "makehuman": _style(
        ("l", "r"), pelvis="hip", spine1="abdomen", spine2="abdomen2", chest="chest", neck="neck", head="head",
        clavicle="{s}Collar", upperarm="{s}Shldr", forearm="{s}ForeArm", hand="{s}Hand", finger="{s}Index1",
        thigh="{s}Thigh", shin="{s}Shin", foot="{s}Foot", toe="{s}Toe"),
    "lf_rt": _style(
        ("Lf", "Rt"), pelvis="Pelvis", spine1="Spine_Lo", spine2="Spine_Mid", chest="Spine_Hi", head="Head",
        clavicle="{s}_Clav", upperarm="{s}_UpArm", upperarm_twist="{s}_UpArm_Roll", forearm="{s}_LoArm",
        hand="{s}_Hand", finger="{s}_Finger1", thigh="{s}_UpLeg", shin="{s}_LoLeg", foot="{s}_Foot",
        toe="{s}_Toe"),
}
CHANNELS = ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]


def _world() -> dict[str, tuple[np.ndarray, str | None]]:
    """Body key → (world position cm, default parent key)."""
    world: dict[str, tuple[np.ndarray, str | None]] = {}
    for key, parent, offset in BODY:
        for side, mirror in ((("l", 1.0), ("r", -1.0)) if "{side}" in key else ((None, 1.0),)):
            k, p = key.format(side=side), parent.format(side=side) if parent else None
            world[k] = (np.array(offset, float) * [mirror, 1, 1] + (world[p][0] if p else 0.0), p)
    return world


def _nodes(style: Style) -> list[tuple[str, str | None, np.ndarray]]:
    """(name, parent name, world cm) of the style's joints, parents before children."""
    world = _world()

    def parent_of(key: str) -> str | None:
        side, part = (key[0], key[2:]) if key[1:2] == "_" else (None, key)
        if part not in style.parents:
            return world[key][1]
        other = style.parents[part]
        return f"{side}_{other}" if side and f"{side}_{other}" in world else other

    nodes = []
    for key in world:
        p = parent_of(key)
        while p is not None and style.name(p) is None:
            p = parent_of(p)
        if style.name(key) is not None:
            nodes.append((style.name(key), style.name(p) if p else None, world[key][0]))
    names = {n for n, _, _ in nodes}
    for name, parent, at in [*style.extras, ("Sword", "r_hand", "r_finger")]:  # every rig holds a prop
        nodes.append((name, parent if parent in names else style.name(parent), world[at][0]))
        names.add(name)
    return nodes


def rig_text(style: Style, shuffle_seed: int | None = None, frames: int = 6,
             rename: dict[str, str] | None = None) -> str:
    """BVH text of the body named in ``style``; siblings shuffled with ``shuffle_seed``; ``frames``
    frames turning the body and swinging the arms; ``rename`` renames joints afterwards."""
    rename = rename or {}
    nodes = [(rename.get(n, n), rename.get(p, p), w) for n, p, w in _nodes(style)]
    world = {n: w for n, _, w in nodes}
    children: dict[str | None, list[str]] = {}
    for name, parent, _ in nodes:
        children.setdefault(parent, []).append(name)
    rng = random.Random(shuffle_seed)
    if shuffle_seed is not None:
        for kids in children.values():
            rng.shuffle(kids)
    lines, columns = ["HIERARCHY"], []

    def emit(name: str, parent: str | None, depth: int) -> None:
        pad, chans = "\t" * depth, CHANNELS if parent is None else CHANNELS[3:]
        offset = world[name] - (world[parent] if parent else 0.0)
        lines.extend([f"{pad}{'ROOT' if parent is None else 'JOINT'} {name}", pad + "{",
                      f"{pad}\tOFFSET {offset[0]:.4f} {offset[1]:.4f} {offset[2]:.4f}",
                      f"{pad}\tCHANNELS {len(chans)} {' '.join(chans)}"])
        columns.extend((name, c) for c in chans)
        for child in children.get(name, []):
            emit(child, name, depth + 1)
        if name not in children:
            tip = offset / 2 if np.linalg.norm(offset) > 0 else np.array([0.0, 3.0, 0.0])
            lines.extend([f"{pad}\tEnd Site", pad + "\t{", f"{pad}\t\tOFFSET {tip[0]:.4f} {tip[1]:.4f} {tip[2]:.4f}",
                          pad + "\t}"])
        lines.append(pad + "}")

    root, = children[None]
    emit(root, None, 0)
    moving = {rename.get(n, n) for n in (style.name("l_upperarm"), style.name("r_forearm"), style.name("l_shin"))}
    lines += ["MOTION", f"Frames: {frames}", "Frame Time: 0.0333333"]
    for f in range(frames):
        values = [(2.0 * f if c == "Xposition" and n == root else 0.0) + (12.0 * f if c == "Yrotation" and n == root
                  else 0.0) + (4.0 * f if c == "Zrotation" and n in moving else 0.0) for n, c in columns]
        lines.append(" ".join(f"{v:.4f}" for v in values))
    return "\n".join(lines) + "\n"


def swapped_sides(style: Style) -> dict[str, str]:
    """A rename that gives every left joint its right twin's name and back (a mirrored naming)."""
    pairs = {}
    for key, _, _ in BODY:
        if "{side}" in key:
            left, right = style.name(key.format(side="l")), style.name(key.format(side="r"))
            if left is not None:
                pairs.update({left: right, right: left})
    return pairs
