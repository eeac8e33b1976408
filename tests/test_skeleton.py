"""Retargeting onto the universal skeleton: bone lengths, directions, rotations, BVH output."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocapdb.core.formats.bvh import format_bvh, forward_kinematics, parse_bvh
from mocapdb.core.motion import Motion
from mocapdb.core.motion_ops import resample
from mocapdb.core.outputs import motion_bvh
from mocapdb.core.skeleton import (
    BONE_LENGTHS_M,
    KP,
    N_RIG_JOINTS,
    PELVIS,
    RIG_JOINTS,
    global_rotations,
    pose_from_rotations,
    rest_positions_m,
    retarget,
    swing_matrices,
)

LIMBS = [("r_hip", "r_knee", "thigh"), ("r_knee", "r_ankle", "shin"), ("l_hip", "l_knee", "thigh"),
         ("l_knee", "l_ankle", "shin"), ("r_shoulder", "r_elbow", "upper_arm"),
         ("r_elbow", "r_wrist", "forearm"), ("l_shoulder", "l_elbow", "upper_arm"),
         ("l_elbow", "l_wrist", "forearm"), ("pelvis", "neck", "torso")]


def _noisy_people(n_frames: int, seed: int = 0) -> np.ndarray:
    """Rest poses of other proportions, turned and jittered: a stand-in for any source rig."""
    rng = np.random.default_rng(seed)
    rest = rest_positions_m() * rng.uniform(0.8, 1.2, size=(n_frames, 1, 3))
    turn = Rotation.random(n_frames, random_state=seed).as_matrix()
    return np.einsum("fab,fjb->fja", turn, rest + rng.normal(scale=0.05, size=rest.shape)) + 1.0


def test_swing_is_scipys_smallest_rotation_and_a_half_turn_for_opposites():
    """swing_matrices against SciPy's align_vectors (the smallest rotation taking a to b), broadcast
    against one b; opposite vectors give a half turn about an axis perpendicular to a."""
    rng = np.random.default_rng(3)
    a = rng.normal(size=(20, 3))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b = rng.normal(size=(20, 3))
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    expected = [Rotation.align_vectors(b[i:i + 1], a[i:i + 1])[0].as_matrix() for i in range(20)]
    np.testing.assert_allclose(swing_matrices(a, b), expected, atol=1e-12)
    up = np.array([0.0, 1.0, 0.0])
    np.testing.assert_allclose(swing_matrices(a, up) @ a[..., None], np.broadcast_to(up[:, None], (20, 3, 1)),
                               atol=1e-12)
    assert swing_matrices(a[0], up).shape == (3, 3)
    for v in (a[0], np.array([0.95, np.sqrt(1 - 0.95 ** 2), 0.0])):
        half = swing_matrices(v, -v)
        np.testing.assert_allclose(half @ v, -v, atol=1e-12)
        assert abs(Rotation.from_matrix(half).magnitude() - np.pi) < 1e-9


def test_global_rotations_chain_each_parent_as_scipy_composes_them():
    """global_rotations against SciPy: each joint's global rotation is its parent's composed with its
    own, the parents found by name in the rig's forward kinematics (a bone's end turns with it)."""
    quats = Rotation.random(3 * N_RIG_JOINTS, random_state=4).as_quat()[:, [3, 0, 1, 2]].reshape(3, N_RIG_JOINTS, 4)
    glob = global_rotations(quats)
    local = Rotation.from_quat(quats[..., [1, 2, 3, 0]].reshape(-1, 4)).as_matrix().reshape(3, N_RIG_JOINTS, 3, 3)
    spine, neck = RIG_JOINTS.index("spine"), RIG_JOINTS.index("neck")
    np.testing.assert_allclose(glob[:, 0], local[:, 0], atol=1e-12)
    np.testing.assert_allclose(glob[:, neck], glob[:, spine] @ local[:, neck], atol=1e-12)
    points = pose_from_rotations(quats, np.zeros((3, 3)))
    rest = rest_positions_m()
    for joint, end in (("r_hip", "r_knee"), ("l_knee", "l_ankle"), ("r_elbow", "r_wrist")):
        bone = rest[KP[end]] - rest[KP[joint]]
        np.testing.assert_allclose(points[:, KP[end]] - points[:, KP[joint]], glob[:, RIG_JOINTS.index(joint)] @ bone,
                                   atol=1e-9)


def test_rest_pose_has_identity_rotations():
    quats, pos = retarget(rest_positions_m()[None])
    np.testing.assert_allclose(np.abs(quats[0, :, 0]), 1.0, atol=1e-12)
    np.testing.assert_allclose(pos[0], rest_positions_m(), atol=1e-12)


def test_bone_lengths_constant_and_directions_kept():
    source = _noisy_people(300)
    _, pos = retarget(source)
    for a, b, bone in LIMBS:
        seg = pos[:, KP[b]] - pos[:, KP[a]]
        np.testing.assert_allclose(np.linalg.norm(seg, axis=-1), BONE_LENGTHS_M[bone], atol=1e-9)
        src = source[:, KP[b]] - source[:, KP[a]]
        cos = np.sum(seg * src, -1) / np.linalg.norm(seg, axis=-1) / np.linalg.norm(src, axis=-1)
        np.testing.assert_allclose(cos, 1.0, atol=1e-9)
    np.testing.assert_allclose(pos[:, PELVIS], source[:, PELVIS], atol=1e-12)


def test_universal_source_is_reproduced_exactly():
    quats = Rotation.from_rotvec(np.random.default_rng(1).normal(scale=0.4, size=(50 * N_RIG_JOINTS, 3)))
    quats = quats.as_quat()[:, [3, 0, 1, 2]].reshape(50, N_RIG_JOINTS, 4)
    source = pose_from_rotations(quats, np.zeros((50, 3)))
    _, pos = retarget(source)
    np.testing.assert_allclose(pos, source, atol=1e-9)


def test_bent_elbow_plane_sets_upper_arm_twist():
    pose = rest_positions_m().copy()
    pose[KP["r_wrist"]] = pose[KP["r_elbow"]] + [0, 0, 0.26]  # forearm bent forward 90°
    quats, pos = retarget(pose[None])
    np.testing.assert_allclose(pos[0], pose, atol=1e-12)
    # Bending forward is the rest bend direction: upper arm untwisted, elbow turned 90° about y.
    shoulder, elbow = quats[0, RIG_JOINTS.index("r_shoulder")], quats[0, RIG_JOINTS.index("r_elbow")]
    assert abs(shoulder[0]) == pytest.approx(1.0)
    assert 2 * np.degrees(np.arccos(abs(elbow[0]))) == pytest.approx(90.0)
    assert abs(elbow[2]) == pytest.approx(np.sin(np.radians(45)))  # about the y axis


def test_resample_matches_linear_interpolation():
    t60 = np.arange(61) / 60.0
    signal = np.stack([np.sin(3 * t60), t60 ** 2], axis=-1)
    out = resample(signal, 60.0, 24.0)
    t24 = np.arange(25) / 24.0
    np.testing.assert_allclose(out[:, 0], np.interp(t24, t60, signal[:, 0]), atol=1e-12)
    np.testing.assert_allclose(out[:, 1], np.interp(t24, t60, signal[:, 1]), atol=1e-12)


@pytest.mark.parametrize("unit, scale, body", [("m", 1.0, 1.0), ("cm", 100.0, 1.0), ("m", 1.0, 0.9)])
def test_universal_bvh_reproduces_positions(unit, scale, body):
    quats, pos = retarget(_noisy_people(40, seed=3))
    pos = pose_from_rotations(quats, pos[:, PELVIS], scale=body)
    np.testing.assert_allclose(np.linalg.norm(pos[:, KP["r_knee"]] - pos[:, KP["r_hip"]], axis=-1),
                               body * BONE_LENGTHS_M["thigh"], atol=1e-9)
    bvh = parse_bvh(format_bvh(motion_bvh(Motion(quats, pos[:, PELVIS], 30.0, scale=body), unit)))
    fk, _ = forward_kinematics(bvh)
    names = ["r_hip", "r_knee", "r_knee_End", "l_elbow_End", "neck_End", "pelvis"]
    points = ["r_hip", "r_knee", "r_ankle", "l_wrist", "head", "pelvis"]
    for name, point in zip(names, points):
        np.testing.assert_allclose(fk[:, bvh.index(name)] / scale, pos[:, KP[point]], atol=2e-6)
    assert bvh.fps == pytest.approx(30.0)
