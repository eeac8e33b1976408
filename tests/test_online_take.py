"""The online whole take: every frame out once, in order, L frames late; smoothed around it; a planted
foot held where it was put down while the per-frame root wanders in depth; pops held to the speed limits."""
import json
import re
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are
from scipy.stats import theilslopes

from mocapdb.core.geometry import quat_geodesic
from mocapdb.core.outputs import CAMERA_FROM_VIEW, Match, PersonPose
from mocapdb.core.skeleton import (
    KP,
    N_RIG_JOINTS,
    RIG_JOINTS,
    bone_lengths_m,
    pose_from_rotations,
    universal_bone_lengths_m,
)
from mocapdb.runtime.online_take import JOINT_SPEED_DEG_S, OnlineParams, OnlineTake, OnlineTrack, _robust_speeds
from mocapdb.runtime.take_params import TakeParams

MATCH = Match("clip", 0, 0.0, 0.1)
FOCAL, CENTRE = 1000.0, np.array([540.0, 960.0])


def _keypoints(joints_cam: np.ndarray) -> np.ndarray:
    """The 14 body keypoints ``[14, 3]`` (pixels, confidence 1) of camera-aligned joints ``[15, 3]``."""
    px = FOCAL * joints_cam[:14, :2] / joints_cam[:14, 2:] * [1.0, -1.0] + CENTRE
    return np.column_stack([px, np.ones(14)])


def _pose(track: int, root: np.ndarray, angle: float = 0.0, keypoints: np.ndarray | None = None,
          image: bool = True) -> PersonPose:
    """A person at ``root`` (camera-aligned), the left hip turned by ``angle``; its keypoints those of the
    pose (or ``keypoints``; none without ``image``: no contacts can be seen)."""
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (N_RIG_JOINTS, 1))
    quats[3] = [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]
    root = np.asarray(root, dtype=np.float64)
    joints = pose_from_rotations(quats[None], (root * CAMERA_FROM_VIEW)[None])[0] * CAMERA_FROM_VIEW
    return PersonPose(track, joints, quats, root, MATCH, 1.75, universal_bone_lengths_m(),
                      keypoints_px=None if not image else _keypoints(joints) if keypoints is None else keypoints)


def test_frames_come_out_once_in_order_lag_frames_late():
    take = OnlineTake(30.0, OnlineParams(lag_frames=3))
    out = []
    for t in range(10):
        due = take.push(t, t / 30.0, [_pose(0, [0.0, 0.0, 5.0])])
        assert [f[0] for f in due] == ([t - 3] if t >= 3 else [])
        out += due
    out += take.flush()
    assert [f[0] for f in out] == list(range(10))
    short = OnlineTake(30.0, OnlineParams(lag_frames=5))
    assert short.push(0, 0.0, []) == [] and [f[0] for f in short.flush()] == [0]  # fewer frames than the lag
    causal = OnlineTake(30.0)
    assert [f[0] for f in causal.push(0, 0.0, [_pose(0, [0.0, 0.0, 5.0])])] == [0]


def test_smoothing_is_centred_calms_jitter_and_keeps_each_person_apart():
    """The smoothing alone (no keypoints: no contacts)."""
    rng = np.random.default_rng(0)
    n, fps = 120, 30.0
    truth = np.column_stack([np.linspace(-1, 1, n), np.zeros(n), np.full(n, 5.0)])   # a steady walk
    noisy = truth + rng.normal(scale=0.03, size=truth.shape)
    take = OnlineTake(fps, OnlineParams(lag_frames=6))
    out = []
    for t in range(n):
        people = [_pose(0, noisy[t], 0.3 * np.sin(t / 10), image=False), _pose(1, [2.0, 0.0, 6.0], image=False)]
        if t % 4 == 0:
            people = people[:1]  # person 1 missed in some frames
        out += take.push(t, t / fps, people)
    out += take.flush()
    roots = np.array([f[2][0].root_m for f in out])
    assert np.abs(roots - truth)[10:-10].mean() < 0.6 * np.abs(noisy - truth)[10:-10].mean()  # depth: causal 1€
    assert abs(np.mean((roots - truth)[10:-10, 0])) < 0.005   # no lag: no trailing offset along the walk
    other = [p for f in out for p in f[2] if p.track == 1]
    np.testing.assert_allclose([p.root_m for p in other], np.broadcast_to([2.0, 0.0, 6.0], (len(other), 3)),
                               atol=1e-9)
    # the joints are the person's skeleton at the smoothed pose: its bones, its root
    pose = out[50][2][0]
    np.testing.assert_allclose(pose.joints_m[14], pose.root_m, atol=1e-12)
    np.testing.assert_allclose(bone_lengths_m(pose.joints_m), universal_bone_lengths_m(), atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(pose.quaternions, axis=-1), 1.0)


@pytest.mark.parametrize("lag", [0, 6])
def test_a_still_foot_is_planted_and_held_while_the_depth_wanders(lag):
    """A person standing still: the image (keypoints) does not move, the per-frame root wanders 10 cm
    in depth (a body-size error). The planted ankles stay put within millimetres; the per-frame
    ankles move with the root. The foot lifts off (contacts end) when its keypoint moves."""
    fps, n = 60.0, 240
    depth = 4.0 + 0.1 * np.sin(np.arange(n) / 7.0)
    still = _pose(0, [0.0, 0.0, 4.0]).keypoints_px
    take = OnlineTake(fps, OnlineParams(lag_frames=lag))
    out = []
    for t in range(n):
        kp = still.copy()
        if t >= 180:   # the right foot lifted and carried forward: its ankle keypoint moves 5 px a frame
            kp[KP["r_ankle"], 1] -= 5.0 * (t - 179)
        out += take.push(t, t / fps, [_pose(0, [0.0, 0.0, depth[t]], keypoints=kp)])
    out += take.flush()
    ankles = np.array([f[2][0].joints_m[[KP["r_ankle"], KP["l_ankle"]]] for f in out])
    contacts = np.array([f[2][0].contacts for f in out])
    assert contacts[30:170].all()                                      # both planted while still
    steady = ankles[30:170]
    speed = np.linalg.norm(np.diff(steady, axis=0), axis=-1) * fps
    assert speed.max() <= OnlineParams.anchor_follow_mps + 1e-6          # sliding no faster than the anchors follow …
    assert np.abs(steady - steady[0]).max() < 0.02                      # … and within 2 cm
    per_frame = np.array([[0.0, 0.0, d] for d in depth])
    assert np.ptp(per_frame[30:170, 2]) > 0.15                          # … while the evidence moved 20 cm
    assert not contacts[200:, 0].any() and contacts[200:, 1].all()     # the lifted foot released, the other not
    assert out[100][2][0].floor_offset_m is not None


def test_a_new_track_stands_on_its_feet_from_its_first_frame_until_the_image_says_otherwise():
    """At lag 0 a speed needs 3 frames. A person standing still, first seen at frame 0, whose per-frame
    root wanders 10 cm in depth: both feet are planted from frame 0 at full weight (no output before it
    to blend from), so the ankles move no faster than the anchors follow (2 cm/s) from the first frame
    on (they moved with the root before: the contact began at frame 2 and blended in). A right foot
    moving 15 px a frame from frame 0 is presumed planted too and released at frame 2, its speed's first
    frame, where it faces the planting test (not the release test); no contact is presumed without
    keypoints."""
    fps, n = 60.0, 30
    depth = 4.0 + 0.1 * np.sin(np.arange(n) / 2.0)
    still = _pose(0, [0.0, 0.0, 4.0]).keypoints_px
    for moving in (False, True):
        take, out = OnlineTake(fps), []
        for t in range(n):
            kp = still.copy()
            kp[KP["r_ankle"], 0] += 15.0 * t * moving
            out += take.push(t, t / fps, [_pose(0, [0.0, 0.0, depth[t]], keypoints=kp)])
        contacts = np.array([f[2][0].contacts for f in out])
        if moving:
            assert contacts[:2, 0].all() and not contacts[2:, 0].any() and contacts[:, 1].all()
        else:
            ankles = np.array([f[2][0].joints_m[[KP["r_ankle"], KP["l_ankle"]]] for f in out])
            assert contacts.all()
            speed = np.linalg.norm(np.diff(ankles, axis=0), axis=-1) * fps
            assert speed.max() <= OnlineParams.anchor_follow_mps + 1e-6
    blind = OnlineTake(fps)
    assert not any(blind.push(t, t / fps, [_pose(0, [0.0, 0.0, 4.0], image=False)])[0][2][0].contacts[0]
                   for t in range(3))


def _stepping(moving, rising: np.ndarray, fps: float = 60.0, lag: int = 0):
    """A person standing 4 m away whose right ankle keypoint moves 5 px a frame upwards in the
    frames where ``moving [n]`` and whose per-frame fit turns the right hip by ``rising [n]`` (rad,
    about the camera's axis: the foot raised sideways) — the image and the fit disagreeing where
    one moves and the other not. Returns each frame's output right ankle ``[n, 3]`` (camera-aligned,
    m) and its contact ``[n]``."""
    still = _pose(0, [0.0, 0.0, 4.0]).keypoints_px
    take = OnlineTake(fps, OnlineParams(lag_frames=lag))
    out, shift = [], 0.0
    for t, (move, angle) in enumerate(zip(moving, rising)):
        shift += 5.0 * move
        kp = still.copy()
        kp[KP["r_ankle"], 1] -= shift
        pose = _pose(0, [0.0, 0.0, 4.0], keypoints=kp)
        quats = pose.quaternions.copy()
        quats[RIG_JOINTS.index("r_hip")] = [np.cos(angle / 2), 0.0, 0.0, np.sin(angle / 2)]
        out += take.push(t, t / fps, [PersonPose(0, pose.joints_m, quats, pose.root_m, MATCH, 1.75,
                                                 universal_bone_lengths_m(), keypoints_px=kp)])
    out += take.flush()
    return (np.array([f[2][0].joints_m[KP["r_ankle"]] for f in out]),
            np.array([f[2][0].contacts[0] for f in out]))


def test_a_foot_that_stops_is_planted_within_the_contact_window_and_held():
    """At lag 0 the right ankle's keypoint moves 5 px a frame (30 box heights … 0.75 box heights per
    second: far above the planting speed) for 40 frames, then stops: the foot is planted within
    the contact window's 8 frames back (the slope of the last 9 frames falls below 0.25 box/s),
    and from then on its ankle moves less than 1 mm in all."""
    n, stop = 120, 40
    ankle, planted = _stepping(np.arange(120) < stop, np.zeros(n))
    assert not planted[10:stop].any()                       # moving: never planted
    first = stop + int(np.argmax(planted[stop:]))
    assert planted[stop:].any() and first - stop <= 8 and planted[first:].all()
    assert np.abs(ankle[first:] - ankle[first]).max() < 0.001


def test_a_planted_foot_is_released_when_its_image_moves_not_when_the_fit_alone_raises_it():
    """A foot planted at lag 0 whose fit raises it 15 cm (the right hip turned 0.6 rad: 0.85 m ×
    (1 − cos 0.6)) for 30 frames (0.5 s) while its keypoint stays still keeps its contact (a lag-0
    fit's pop, not a step) and its place, its anchor following the fit at ``anchor_follow_mps`` at
    most; raised the same way while its keypoint moves 5 px a frame (the foot lifted as the image
    shows), it is released within 6 frames (the speed crossing 0.5 box/s in the last 9 frames)."""
    n, lift = 150, 60
    rising = np.where((np.arange(n) >= lift) & (np.arange(n) < lift + 30), 0.6, 0.0)
    ankle, planted = _stepping(np.zeros(n, dtype=bool), rising)
    assert planted[20:].all()
    speed = np.linalg.norm(np.diff(ankle[20:], axis=0), axis=-1) * 60.0
    assert speed.max() <= OnlineParams.anchor_follow_mps + 1e-5      # held: its anchor follows the fit no faster
    assert np.linalg.norm(ankle[20:] - ankle[20], axis=-1).max() < OnlineParams.anchor_follow_mps * 0.5 + 0.001
    ankle, planted = _stepping(np.arange(n) >= lift, rising)
    assert planted[20:lift].all() and not planted[lift + 6:].any()


def test_robust_speeds_are_theil_sen_and_ignore_a_swapped_frame():
    """A keypoint moving 2 px a frame to the right, one frame of 9 swapped 300 px away (the other foot's
    place): its speed is exactly 2 px/frame (28 of the 36 pairs give it; the least-squares slope is
    pulled off), per axis the median of the pairwise slopes as SciPy's ``theilslopes`` gives it; fewer
    than 3 seen positions: inf."""
    frames = np.arange(9, dtype=np.float64)
    points = np.zeros((9, 2, 3))
    points[:, 0] = np.column_stack([100.0 + 2.0 * frames, np.full(9, 500.0), np.ones(9)])
    points[6, 0, :2] += [300.0, -40.0]                                       # the swap
    rng = np.random.default_rng(3)
    points[:, 1] = np.column_stack([rng.normal(size=(9, 2)) * 5.0, (np.arange(9) % 3 > 0).astype(float)])
    speeds = _robust_speeds(frames, points)
    assert speeds[0] == pytest.approx(2.0, abs=1e-12)
    seen = points[:, 1, 2] > 0
    reference = np.hypot(*(theilslopes(points[seen, 1, axis], frames[seen]).slope for axis in (0, 1)))
    assert speeds[1] == pytest.approx(reference, rel=1e-12)
    least_squares = np.polyfit(frames, points[:, 0, :2], 1)[0]
    assert abs(np.linalg.norm(least_squares) - 2.0) > 1.0
    points[3:, 1, 2] = 0.0
    assert _robust_speeds(frames, points)[1] == np.inf                     # 2 seen of 9


def _carrying(left_px_per_frame: np.ndarray, right_swings: np.ndarray, fps: float = 60.0,
              left_raised_rad: float = 0.0) -> np.ndarray:
    """A person standing 4 m away (both ankles at one height in the fit, unless its left hip is turned
    ``left_raised_rad`` about the camera's axis: the foot raised sideways) whose left foot's ankle, heel and
    big toe drift sideways ``left_px_per_frame [n]`` and whose right foot's sweep 15 px a frame (the foot
    in the air) where ``right_swings [n]``, else stand; each frame's left contact ``[n]`` at lag 0."""
    pose = _pose(0, [0.0, 0.0, 4.0])
    pose = replace(pose, quaternions=_pose(0, [0.0, 0.0, 4.0], left_raised_rad).quaternions)
    still = pose.keypoints_px
    feet = np.zeros((8, 3))
    feet[:4] = np.vstack([still[KP["r_ankle"]], still[KP["r_ankle"]], still[KP["l_ankle"]], still[KP["l_ankle"]]])
    feet[:4, 1] += [20.0, 20.0, 20.0, 20.0]
    feet[[1, 3], 0] += [-30.0, 30.0]                                        # the big toes ahead of the heels
    take, out, shift = OnlineTake(fps), [], np.zeros(2)
    for t, (left, swings) in enumerate(zip(left_px_per_frame, right_swings)):
        shift += [15.0 * swings, left]
        kp, ends = still.copy(), feet.copy()
        kp[KP["r_ankle"], 0] += shift[0]
        kp[KP["l_ankle"], 0] += shift[1]
        ends[:2, 0] += shift[0]
        ends[2:4, 0] += shift[1]
        out += take.push(t, t / fps, [replace(pose, keypoints_px=kp, extremities_px=ends)])
    out += take.flush()
    return np.array([f[2][0].contacts[1] for f in out])


def test_the_slower_foot_carries_the_body_while_the_other_swings():
    """The whole take's carrying rule at lag 0: after 10 frames of 2 box heights a second (the contact
    presumed at the track's first frame released), the left foot drifting 0.4 box/s (above the
    planting speed, 0.25, below ``carrying_box_per_s``, 0.5) is planted while the right foot's heel and
    toe sweep (1.4 box/s), and not while the right foot stands; once carrying, drifting 0.8 box/s
    (below twice the carrying speed) keeps it planted until the right foot stops swinging (the slope
    over the last 9 frames falls below the planting speed within 9 frames), then it is released."""
    box = np.ptp(_pose(0, [0.0, 0.0, 4.0]).keypoints_px[:, 1])
    start, slow, fast = (v * box / 60.0 for v in (2.0, 0.4, 0.8))        # px a frame
    n, t = 120, np.arange(120)
    drift = np.where(t < 10, start, slow)
    assert not _carrying(drift, np.zeros(n, dtype=bool))[20:].any()
    assert _carrying(drift, np.ones(n, dtype=bool))[20:].all()
    planted = _carrying(np.where(t < 40, drift, fast), t < 80)
    assert planted[20:80].all() and not planted[89:].any()


def test_a_flat_foot_is_planted_whatever_its_height_while_the_other_moves():
    """The whole take's flat-foot rule at lag 0: a foot whose heel and toe stand still in the image but
    which the fit raises 15 cm (the left hip turned 0.6 rad: 0.85 m × (1 − cos 0.6)) is planted while
    the other foot's heel and toe move (it carries the body), not while the other stands still too (a
    foot held still in the air)."""
    n = 60
    assert _carrying(np.zeros(n), np.ones(n, dtype=bool), left_raised_rad=0.6)[10:].all()
    assert not _carrying(np.zeros(n), np.zeros(n, dtype=bool), left_raised_rad=0.6).any()


def test_the_root_carried_by_shaking_legs_is_steadied_and_the_feet_stay_planted():
    """Standing still, the per-frame fit's hips shaking 3° (SD, about the camera's axis, the image
    still): the root the planted feet carry follows the legs' rotations. Through the carried root's
    filter its second difference is less than half of what it is when the filter passes the
    carried root through (``carried_root_sd_m`` 1 µm), and the planted ankles slide, with it and without,
    no faster than their anchors follow the shaken fit (2 cm/s) and a straight leg's IK at its full reach
    holds them (1 cm/s more)."""
    rng = np.random.default_rng(1)
    fps, n = 60.0, 180
    shake = np.radians(3.0) * rng.standard_normal((n, 2))
    out = {}
    for sd in (OnlineParams.carried_root_sd_m, 1e-6):
        take, frames = OnlineTake(fps, OnlineParams(carried_root_sd_m=sd)), []
        for t in range(n):
            pose = _pose(0, [0.0, 0.0, 4.0])
            quats = pose.quaternions.copy()
            for k, hip in enumerate(("r_hip", "l_hip")):
                quats[RIG_JOINTS.index(hip)] = [np.cos(shake[t, k] / 2), 0.0, 0.0, np.sin(shake[t, k] / 2)]
            frames += take.push(t, t / fps, [PersonPose(0, pose.joints_m, quats, pose.root_m, MATCH, 1.75,
                                                        universal_bone_lengths_m(), keypoints_px=pose.keypoints_px)])
        out[sd] = frames[30:]
    roots = {sd: np.array([f[2][0].root_m for f in frames]) for sd, frames in out.items()}
    jerk = {sd: np.linalg.norm(np.diff(r, 2, axis=0), axis=-1).mean() for sd, r in roots.items()}
    assert jerk[OnlineParams.carried_root_sd_m] < 0.5 * jerk[1e-6]
    assert all(f[2][0].contacts == (True, True) for f in out[OnlineParams.carried_root_sd_m])
    slide = {sd: np.linalg.norm(np.diff([f[2][0].joints_m[[KP["r_ankle"], KP["l_ankle"]]] for f in frames],
                                        axis=0), axis=-1).max() * fps for sd, frames in out.items()}
    assert max(slide.values()) < OnlineParams.anchor_follow_mps + 0.01


def test_the_carried_roots_filter_is_looser_along_the_viewing_ray():
    """The carried root's filter weighs a measurement by ``carried_root_sd_m`` across the viewing ray
    and ``carried_root_depth_m`` along it (the legs' depth: the pose's least sure): after a still root
    its steady-state gain on a 1 mm step is, per direction, the constant-velocity model's (SciPy's
    discrete Riccati solution, the velocity's SD growing ``4 m/s² · dt`` a frame)."""
    fps, params = 60.0, OnlineParams()
    dt = 1.0 / fps
    transition = np.array([[1.0, dt], [0.0, 1.0]])
    noise = np.diag([0.0, (TakeParams().root_accel_mps2 * dt) ** 2])
    still = np.array([0.0, 0.0, 4.0])
    for sd, step in ((params.carried_root_sd_m, [0.001, 0.0, 0.0]), (params.carried_root_depth_m, [0.0, 0.0, 0.001])):
        prior = solve_discrete_are(transition.T, np.array([[1.0], [0.0]]), noise, np.array([[sd ** 2]]))
        gain = prior[0, 0] / (prior[0, 0] + sd ** 2)
        track = OnlineTrack(fps, params)
        for t in range(600):
            track.carried(t, still)
        moved = track.carried(600, still + step) - still
        assert moved @ step / 0.001 ** 2 == pytest.approx(gain, rel=1e-6)
        assert np.linalg.norm(moved - gain * np.array(step)) < 1e-3 * 0.001   # the ray turned by the step


def test_a_remeasured_body_is_eased_in_without_a_jump():
    """The engine re-measures a body in steps: the forearms of a still person (no image: no contacts)
    lengthened by 5 cm at once follow as two exponentials of time constant ``body_ease_s``: at the
    ``k``-th frame of the new length the output's forearm is short of it by the step times
    ``(1 − α)^k (1 + k α)``, ``α = 1 − exp(−1 / (fps τ))``; so the wrist's largest second difference is
    ``α²`` of the step (8 % at 60 fps), where passed through (τ → 0) it is the step. The stream's
    ``bones`` are its joints'."""
    fps, step_m = 60.0, 0.05
    bones = universal_bone_lengths_m()
    longer = bones.copy()
    longer[3] += step_m                                   # MEASURED_BONE_NAMES[3]: the forearm
    out = {}
    for tau in (OnlineParams.body_ease_s, 1e-6):
        take = OnlineTake(fps, OnlineParams(body_ease_s=tau))
        frames = []
        for t in range(90):
            pose = replace(_pose(0, [0.0, 0.0, 4.0], image=False), bones_m=longer if t >= 30 else bones)
            frames += take.push(t, t / fps, [pose])
        out[tau] = [f[2][0] for f in frames]
    eased = out[OnlineParams.body_ease_s]
    forearm = np.array([bone_lengths_m(p.joints_m)[3] for p in eased])
    np.testing.assert_allclose([p.bones_m[3] for p in eased], forearm, atol=1e-9)   # the stream's bones: its joints'
    alpha = 1.0 - np.exp(-1.0 / (fps * OnlineParams.body_ease_s))
    k = np.arange(1, 61)
    np.testing.assert_allclose(forearm[30:], longer[3] - step_m * (1 - alpha) ** k * (1 + k * alpha), atol=1e-9)
    wrist = {tau: np.linalg.norm(np.diff([p.joints_m[KP["r_wrist"]] for p in poses], 2, axis=0), axis=-1).max()
             for tau, poses in out.items()}
    assert wrist[1e-6] == pytest.approx(step_m, rel=1e-6)     # passed through: a 5 cm jump
    assert wrist[OnlineParams.body_ease_s] == pytest.approx(alpha ** 2 * step_m, rel=1e-6)   # eased: α² of it, at most


def test_a_planted_leg_keeps_the_level_pull_and_lowers_the_root_into_its_reach_by_its_weight():
    """The steadied root's level pull (the carried filter 30 cm to the side) with the right leg straight
    and vertical under its anchor (length ``L``): at IK weight 1 the root keeps the pull's direction
    and the leg reaches its anchor exactly, ``d L / √(d² + L²)`` across and ``L − L² / √(d² + L²)``
    lower for a free pull ``d`` (the sphere of the leg's reach); at weight ``w`` the leg's length is
    ``w`` of the way from the free pull's to ``L``, along the same line from the anchor; at weight 0
    the pull passes whole and level (no jump as a foot blends in or out)."""
    quats = np.tile([1.0, 0.0, 0.0, 0.0], (N_RIG_JOINTS, 1))
    body = pose_from_rotations(quats[None], np.zeros((1, 3)))[0]             # about the root, legs straight
    root, up = np.array([0.0, 0.0, 4.0]), np.array([0.0, 1.0, 0.0])
    hip, ankle = body[KP["r_hip"]], body[KP["r_ankle"]]
    length = np.linalg.norm(hip - ankle)
    np.testing.assert_allclose((hip - ankle) / length, up, atol=1e-12)     # the rest leg: straight and vertical
    moved = {}
    for weight in (0.0, 0.01, 0.5, 1.0):
        track = OnlineTrack(60.0, OnlineParams())
        track.carried(0, np.array([0.3, 0.0, 4.0]))                       # the filter 30 cm to the side
        track.feet.weight[0], track.feet.anchor[0] = weight, root + ankle
        moved[weight] = track._steadied(1, root.copy(), body, up) - root
    free = moved[0.0]
    d = np.linalg.norm(free)
    assert d > 0.01 and abs(free @ up) < 1e-12
    across = free - (free @ up) * up
    np.testing.assert_allclose(moved[1.0] - (moved[1.0] @ up) * up, across * length / np.hypot(d, length), atol=1e-12)
    assert moved[1.0] @ up == pytest.approx(length ** 2 / np.hypot(d, length) - length, abs=1e-12)
    for weight in (0.01, 0.5):
        leg = moved[weight] + hip - ankle                                  # anchor → hip
        free_leg = free + hip - ankle
        expected = (1 - weight) * np.linalg.norm(free_leg) + weight * length
        assert np.linalg.norm(leg) == pytest.approx(expected, abs=1e-12)
        np.testing.assert_allclose(np.cross(leg, free_leg), 0.0, atol=1e-12)


def test_a_pop_is_held_to_the_joint_speed_limit():
    fps = 60.0
    take = OnlineTake(fps)
    out = []
    for t in range(30):
        angle = np.pi / 2 if t == 15 else 0.0   # one frame's retrieval flips the left hip by 90°
        out += take.push(t, t / fps, [_pose(0, [0.0, 0.0, 4.0], angle)])
    quats = np.array([f[2][0].quaternions for f in out])
    turn_deg = np.degrees(2 * quat_geodesic(quats[1:], quats[:-1]))    # per frame, per joint
    limit = np.array([JOINT_SPEED_DEG_S[j] for j in RIG_JOINTS]) / fps
    assert (turn_deg <= limit + 1e-6).all()
    assert turn_deg[:, RIG_JOINTS.index("l_hip")].max() < 90.0 / 2


@pytest.mark.parametrize("bad", [dict(lag_frames=-1), dict(smoothing_hz=0.0), dict(release_factor=0.5),
                                 dict(root_speed_mps=float("nan")), dict(body_ease_s=0.0)])
def test_online_take_refuses_bad_settings(bad):
    with pytest.raises(ValueError):
        OnlineParams(**bad)
    with pytest.raises(ValueError):
        OnlineTake(0.0)


def test_reconstruct_stream_through_the_online_take_is_steadier_and_says_its_lag(small_db_path, tmp_path):
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    common = [str(SAMPLE_KEYPOINTS), "--db", str(small_db_path), "--fps", "60", "--image-size", "1088x1920",
              "--focal", "1681", "--per-frame"]
    joints, headers = {}, {}
    for name, flags in (("per-frame", ["--per-frame-stream"]), ("lag8", ["--lag-frames", "8"])):
        out = tmp_path / name
        assert main(["reconstruct", *common, "--out", str(out), *flags]) == 0
        text = (out / "result.jsonl").read_text().splitlines()
        headers[name] = json.loads(text[0])
        lines = [json.loads(x) for x in text[1:]]
        assert [x["frame"] for x in lines] == sorted(x["frame"] for x in lines) and len(lines) == 100
        joints[name] = np.array([p["joints"] for x in lines for p in x["people"] if p["track"] == 1])
    accel = {name: np.linalg.norm(np.diff(j, 2, axis=0), axis=-1).mean() for name, j in joints.items()}
    assert accel["lag8"] < 0.5 * accel["per-frame"]
    assert headers["lag8"]["stream"] == "online-take" and headers["lag8"]["lag_frames"] == 8
    assert headers["per-frame"]["stream"] == "per-frame" and "lag_frames" not in headers["per-frame"]
    assert main(["reconstruct", *common, "--out", str(tmp_path / "bad"), "--lag-frames", "-1"]) == 2
    assert main(["reconstruct", *common, "--out", str(tmp_path / "bad2"), "--lag-frames", "3",
                 "--per-frame-stream"]) == 2


def test_eval_live_scores_the_stream_beside_the_whole_take(small_db_path, capsys):
    """`mocapdb eval --live` on the bundled take's two cameras: every variant scored, the online take
    steadier and its feet stiller than the per-frame stream, the latency the lag plus the compute."""
    from mocapdb.cli.main import main

    from .conftest import SAMPLE_KEYPOINTS

    folders = [str(SAMPLE_KEYPOINTS), str(SAMPLE_KEYPOINTS.parent / "pose2sim_cam04")]
    calibration = str(SAMPLE_KEYPOINTS.parent / "calibration.toml")
    args = ["eval", "--db", str(small_db_path), "--live", *folders, "--calibration", calibration,
            "--cameras", "cam_01", "cam_04", "--fps", "60", "--lags", "0,6"]
    assert main(args) == 0
    table = capsys.readouterr().out
    rows = {line.split("|")[1].strip(): [c.strip() for c in line.split("|")[2:-1]]
            for line in table.splitlines() if line.startswith("| ") and "variant" not in line}
    assert set(rows) == {"published method (per-frame, no refinement)", "per-frame stream (before)",
                         "whole take (track files)", "online take, L = 0", "online take, L = 6"}
    floor = float(re.search(r"Database floor [^:]*: MPJPE ([0-9.]+) cm", table).group(1))
    # the published method outputs database poses: no closer than the database's own floor
    assert 0.0 < floor <= float(rows["published method (per-frame, no refinement)"][4])
    accel = {name: float(cells[0].split()[0]) for name, cells in rows.items()}
    planted = {name: float(cells[2]) for name, cells in rows.items()}
    assert accel["online take, L = 6"] < accel["online take, L = 0"] < accel["per-frame stream (before)"]
    assert planted["online take, L = 0"] < 0.5 * planted["per-frame stream (before)"]
    latency_p50 = float(rows["online take, L = 6"][6].split("/")[0])
    assert 100.0 <= latency_p50 < 150.0                                    # 6 frames at 60 fps, plus the compute
    assert main([*args[:-2], "--lags", "0,x"]) == 2
    assert main(["eval", "--db", str(small_db_path), "--live", *folders]) == 2   # no calibration


def test_eval_live_scores_world_landmarks_as_the_others(small_db, tmp_path):
    """Keypoints that carry world landmarks get the "BlazePose world landmarks (raw)" row, scored as the
    other variants: here the reference itself, put in camera 1's frame (y down, hips-centred) on every
    person of camera 1's files, scores ~0; motion figures are not given (no root). The person is the
    one the main track follows: a second person's landmarks (another pose) are not taken."""
    from mocapdb.core.cameras import read_calibration_toml
    from mocapdb.core.formats.keypoint_layouts import SOURCE_INDEX
    from mocapdb.evaluation.live import SCORED, WORLD_LANDMARKS, evaluate_live, reference_joints

    from .conftest import SAMPLE_KEYPOINTS

    folders = [SAMPLE_KEYPOINTS, SAMPLE_KEYPOINTS.parent / "pose2sim_cam04"]
    calibration = SAMPLE_KEYPOINTS.parent / "calibration.toml"
    cams = read_calibration_toml(calibration)
    cam = cams["cam_01"]
    truth, names = reference_joints(folders, [cam, cams["cam_04"]])
    hips = truth[:, [names.index("r_hip"), names.index("l_hip")]].mean(axis=1, keepdims=True)
    in_camera = (truth - hips) @ cam.R.T   # the world's axes → the OpenCV camera's (x right, y down, z away)
    body25b = SOURCE_INDEX["body25b"]
    copy = tmp_path / "cam01"
    copy.mkdir()
    files = sorted(SAMPLE_KEYPOINTS.glob("cam01.*.json"))
    for t, path in enumerate(files):
        frame = json.loads(path.read_text())
        for i, person in enumerate(frame["people"]):
            world = np.zeros((25, 3))
            for joint in SCORED:
                world[body25b[KP[joint]]] = in_camera[t, names.index(joint)]
            if not np.isfinite(world).all():
                continue
            if i > 0:
                world = world[:, [1, 0, 2]]   # someone else: another pose
            person["pose_world_landmarks_3d"] = world.ravel().tolist() if len(person["pose_keypoints_2d"]) else []
        (copy / path.name).write_text(json.dumps(frame))
    report = evaluate_live(small_db, [copy, folders[1]], calibration, (0,),
                           names=["cam_01", "cam_04"], fps=60.0)
    row = report["variants"][WORLD_LANDMARKS]
    assert row["mpjpe_cm"] < 0.05 and row["pa_mpjpe_cm"] < 0.05 and row["frames_with_output"] > 0.8 * len(files)
    assert np.isnan(row["acceleration_mm_per_frame2"]) and np.isnan(row["planted_feet_cm_per_s"])
    assert list(report["variants"])[:2] == ["published method (per-frame, no refinement)", WORLD_LANDMARKS]
