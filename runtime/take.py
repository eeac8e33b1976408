"""The whole take: one track's per-frame fits turned into animation once the take is over.

The per-frame engine is causal: each frame is fitted from the past alone, so detector noise shows
as jitter, a wrong retrieval as a pop, and the depth (read from the body's image size) wanders,
which makes planted feet slide. With the whole track at hand (`mocapdb reconstruct`, and the BVH
`mocapdb live` writes when a track ends), :func:`fit_take` works on the unfiltered per-frame fits
(``EngineConfig.keep_take``), the detector's left/right labels first made consistent over the take
(:mod:`mocapdb.runtime.side_labels`) and the fits of the frames whose labels were exchanged bridged over
(:func:`~mocapdb.runtime.take_smoothing.bridged_frames`: a fit to a detector's flip counts as none):

1. **Rotations**: made sign-continuous, single-frame pops removed by a running median over
   :attr:`TakeParams.pop_frames` frames, then smoothed without lag by a zero-phase Gaussian whose
   cut-off is :attr:`TakeParams.smoothing_hz` (the one smoothing control, in hertz: motion slower
   than it passes, jitter faster than it goes); then fitted again to the keypoints, de-popped and
   smoothed alike (:func:`smoothed_keypoints`: the offline counterpart of the stream's 2D clean-up,
   without its lag), on the track's final body, near the smoothed pose (:func:`refit_to_image`, the
   per-frame refinement with :attr:`TakeParams.refit_prior` times its pull to the prior; the
   detector's 3D is not pulled towards a second time: the per-frame fits it started from did), and
   smoothed once more.
2. **Contacts**: an ankle is planted where its keypoint stands still in the image (speed under
   :attr:`TakeParams.planted_box_per_s` box heights per second: the slope of a line fitted over
   :data:`CONTACT_WINDOW_S` to its running median, which a detector's one-frame swaps and misses
   do not move; gaps up to :data:`GAP_S` closed) and it is within
   :attr:`TakeParams.planted_height_m` of the other ankle's height or below it (along the estimated
   up; comparing the two feet of one frame cancels the depth's error, which moves both alike).
   Where the layout gives a foot's heel and big toe, its phase (:func:`foot_phases`: flat, heel
   strike, toe-off, in the air) decides instead: a flat foot is planted when it is the lower one
   or the other foot is off the floor.
3. **Root path**: one sparse linear least-squares problem over all frames: near the per-frame root
   across the viewing ray (the image fixes it: SD :attr:`TakeParams.root_across_m`) and, much more
   loosely, along it (the depth from the body's size: :attr:`TakeParams.root_depth_m`), smooth
   (root acceleration SD :attr:`TakeParams.root_accel_mps2`), and each planted ankle at one place
   (its anchor) for its whole contact (SD :attr:`TakeParams.contact_m` across the viewing ray,
   :attr:`TakeParams.contact_depth_m` along it: a pose's legs are least sure in depth, and a
   stride short in depth, held rigidly, would drag the root along the walk away from the depth
   the body's image size gives).
   **Planted feet**: each leg's hip and knee are then turned (two-bone IK, the knee kept in its
   bending plane) so that a planted ankle is exactly at its anchor, eased in and out of the contact;
   where a stretched leg cannot reach it, the root first moves by the shortfall (:func:`within_reach`).
4. **Floor**: the plane through the planted ankles, lowered by the ankle height (:func:`floor_plane`:
   fitted to the contacts when they lie on one plane and span about 1 m both ways; along a straight
   walk, the camera's estimated up made perpendicular to it; else that up; its height that of the
   lowest contacts, so a step or platform climbed on is not the floor); no ankle goes below it
   (the root is lifted where one would).
5. **One world**: every track of a take on one floor, each with its own size
   (:mod:`mocapdb.runtime.world.fuse`).
6. **Feet and hands** (layouts with heels, big toes and knuckles): the humanoid rig's feet and
   hands turned to the directions the image gives them (:func:`end_rotations`), a planted foot
   flat on the floor; where the hand landmark model saw a hand (``detect --hands``), its direction and
   its palm's twist from its own points, and its 15 finger bones (:func:`finger_rotations`;
   :mod:`mocapdb.runtime.hand_pose`). **Head** (layouts with face points): the head's rotation fitted to them
   (:mod:`mocapdb.runtime.head_pose`), smoothed as the rotations (:func:`head_rotation`).

The settings: :mod:`mocapdb.runtime.take_params`; the contacts (step 2):
:mod:`mocapdb.runtime.foot_contacts`; the floor (step 4): :mod:`mocapdb.runtime.world.contact_floor`.

Costs O(F) per track (the least-squares system is banded, the re-fit ~70 µs a frame): thousands of
frames per second.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy import sparse
from scipy.ndimage import gaussian_filter1d
from scipy.sparse.linalg import spsolve

from mocapdb.core.formats.keypoint_layouts import N_FEET_HANDS
from mocapdb.core.geometry import matrix_to_quat, quat_to_matrix
from mocapdb.core.motion import Motion
from mocapdb.core.outputs import CAMERA_FROM_VIEW, TrackRecording
from mocapdb.core.skeleton import (
    ANKLE_HEIGHT_M,
    N_RIG_JOINTS,
    NODE_NAMES,
    NODE_OFFSETS_M,
    RIG_JOINTS,
    body_offsets_m,
    pose_from_rotations,
    swing_matrices,
)
from mocapdb.runtime.end_branches import continuous_directions
from mocapdb.runtime.end_joints import (
    end_frames,
    end_locals,
    knuckle_thumb_sides,
    levelled_feet,
    measured_candidates,
    sign_references,
    standing_directions,
    wrist_depths_m,
)
from mocapdb.runtime.foot_contacts import (
    ANKLES,
    box_height_px,
    foot_phases,
    interpolated,
    planted_ankles,
    true_runs,
)
from mocapdb.runtime.hand_pose import (
    eased_smoothed,
    finger_rotations,
    hand_twist_deg,
    hands_seen,
    palm_frames,
    shortest_turn_axes,
    steadiness,
    track_hand_points,
    twisted,
)
from mocapdb.runtime.head_pose import chest_relative_head, face_points, head_local
from mocapdb.runtime.mesh_head import eased_presence, mesh_model, mesh_observations
from mocapdb.runtime.refine import JointLimits, RefineParams, Refiner
from mocapdb.runtime.side_labels import BODY_PAIRS, EXTREMITY_PAIRS, consistent_sides
from mocapdb.runtime.take_params import TakeParams
from mocapdb.runtime.take_smoothing import bridged_frames, smooth_rotations, smoothed_keypoints, zero_phase_smoothed
from mocapdb.runtime.world.contact_floor import above_floor, floor_plane
from mocapdb.runtime.world.detector_prior import track_up
from mocapdb.runtime.world.image_vertical import vertical_planes


@dataclass
class TakeResult:
    """What :func:`fit_take` found besides the motion: contacts ``[F, 2]`` (right, left ankle), the
    planted ankles ``[N, 3]`` (view frame, metres), the floor plane ``normal · p = offset`` (view
    frame, metres; None without contacts), the body's own up (view frame, unit) and its error
    (degrees; :func:`~mocapdb.runtime.world.detector_prior.track_up`: what the track's floor started from),
    each foot's phase ``[F, 2]`` (:func:`foot_phases`; None without heels and toes) and the image's
    vertical planes ``[N, 3]`` (:func:`~mocapdb.runtime.world.image_vertical.vertical_planes`; None without
    the camera)."""

    planted: np.ndarray
    planted_ankles_m: np.ndarray
    floor_normal: np.ndarray | None
    floor_offset_m: float | None
    body_up: np.ndarray
    body_up_sd_deg: float
    phases: np.ndarray | None = None
    vertical_planes: np.ndarray | None = None


def fit_take(rec: TrackRecording, fps: float, params: TakeParams = TakeParams()) -> tuple[TrackRecording, TakeResult]:
    """The whole-take fit of a recording made with ``EngineConfig.keep_take``; returns a recording
    whose rotations and root are the fitted motion (one body scale, the track's last) and what was
    found. ``fps``: the take's frame rate (Hz)."""
    if not len(rec) or len(rec.column("fit_quaternions")) != len(rec):
        raise ValueError(f"track {rec.track}: no per-frame fits kept (EngineConfig.keep_take)")
    scales = rec.scales
    scale = float(scales[-1])
    keypoints, exchanged = consistent_sides(rec.column("keypoints"), BODY_PAIRS, fps)
    root = rec.column("fit_root_view_m") * (scale / scales)[:, None]
    fits, root = bridged_frames(rec.column("fit_quaternions"), root, np.any(exchanged, axis=1))   # fits to a flip: none
    quats = smooth_rotations(fits, fps, params)
    offsets = None if rec.proportions_m is None else body_offsets_m(rec.proportions_m)
    if params.refit_prior > 0 and rec.camera_px is not None:
        quats = refit_to_image(quats, root, smoothed_keypoints(keypoints, fps, params), scale, offsets,
                               rec.camera_px, params.refit_prior)
        quats = smooth_rotations(quats, fps, replace(params, pop_frames=1))
    up, up_sd_deg = track_up(rec)
    relative = pose_from_rotations(quats, np.zeros_like(root), scale, offsets)[:, ANKLES]  # ankles − root
    extremities = rec.column("extremities")
    if len(extremities):
        extremities = consistent_sides(extremities, EXTREMITY_PAIRS, fps)[0]
    ends = bool(len(extremities)) and bool((extremities[:, :N_FEET_HANDS, 2] > 0).any()) and rec.camera_px is not None
    phases = foot_phases(extremities, box_height_px(keypoints), fps, params) if ends else None
    planted = planted_ankles(keypoints, root[:, None] + relative, up, fps, params, phases)
    root, anchors = fit_root_path(root, relative, planted, fps, params)
    weights, targets = contact_targets(planted, anchors)
    reached = pose_from_rotations(plant_feet(quats, root, scale, offsets, weights, targets), root, scale, offsets)
    root = within_reach(root, reached[:, ANKLES], planted, anchors)
    quats = plant_feet(quats, root, scale, offsets, weights, targets)
    relative = pose_from_rotations(quats, np.zeros_like(root), scale, offsets)[:, ANKLES]
    normal, offset = None, None
    if params.floor and planted.any():
        normal, offset = floor_plane(root[:, None] + relative, planted, up, ANKLE_HEIGHT_M * scale)
        root = above_floor(root, relative, normal, offset, ANKLE_HEIGHT_M * scale)
    floor_up = up if normal is None else normal
    hands = track_hand_points(rec)
    palms = None if hands is None else palm_frames(hands)
    end_quats = None
    if ends and rec.camera_px is not None:
        end_quats = end_rotations(quats, root, scale, offsets, keypoints, extremities, rec.camera_px,
                                  planted, floor_up, fps, params, palms)
    head = None if not len(extremities) or rec.camera_px is None else head_rotation(
        quats, root, scale, offsets, face_points(keypoints, extremities), rec.camera_px, fps, params,
        rec.column("face_world_m"), rec.column("mesh_px"))
    fingers = None if hands is None or palms is None else finger_rotations(hands, palms, fps, params)
    motion = Motion(quats, root, fps, "view", rec.first_frame, scale, rec.proportions_m, _ends(end_quats, head),
                    fingers)
    out = replace(rec.with_motion(motion), up_view=floor_up, floor_offset_m=offset,
                  hands_seen=None if hands is None else hands_seen(hands))
    planes = None if rec.camera_px is None else vertical_planes(keypoints, rec.camera_px,
                                                                float(np.median(-root[:, 2])), up)
    return out, TakeResult(planted, (root[:, None] + relative)[planted], normal, offset, up, up_sd_deg, phases, planes)


def take_joints(fitted: TrackRecording, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fitted track (:func:`fit_takes`) at ``fps`` Hz as frame indices ``[F]``, keypoints
    ``[F, 15, 3]`` and roots ``[F, 3]`` in the camera-aligned frame (metres; as
    ``PersonPose.joints_m``/``root_m``)."""
    motion = fitted.motion(fps)
    frames = motion.first_frame + np.arange(len(motion))
    return frames, motion.joints_m() * CAMERA_FROM_VIEW, motion.root_m * CAMERA_FROM_VIEW


def refit_to_image(quats: np.ndarray, root_m: np.ndarray, keypoints: np.ndarray, scale: float,
                   offsets_m: np.ndarray | None, camera_px: tuple[float, float, float], prior: float) -> np.ndarray:
    """``quats [F, R, 4]`` (smoothed) fitted again to each frame's keypoints ``[F, 14, 3]`` on the
    track's final body (``scale``, ``offsets_m``): the per-frame refinement
    (:class:`~mocapdb.runtime.refine.Refiner`) with the smoothed pose as its prior, ``prior`` times
    the per-frame weights, no previous pose and no joint limits (the smoothed pose keeps within
    them). The per-frame fits were made on the body known so far; this fits the one body of the
    whole take. ``root_m [F, 3]``: the roots (view frame, metres; only the starting point);
    ``camera_px``: focal, principal point (pixels). Frames without keypoints are kept."""
    per_frame = RefineParams()
    refiner = Refiner(replace(per_frame, prior_root=prior * per_frame.prior_root, previous=0.0, limits=0.0,
                              prior_joint=prior * per_frame.prior_joint), _NO_LIMITS)
    focal_px, cx, cy = camera_px
    out = np.ascontiguousarray(quats.copy())
    points = np.ascontiguousarray(keypoints[..., :2])
    confidence = np.ascontiguousarray(keypoints[..., 2])
    for f in np.flatnonzero((confidence > 0).any(axis=1)):
        refiner(out[f], root_m[f].copy(), scale, points[f], confidence[f], quats[f], None, focal_px, (cx, cy),
                offsets_m)
    return out


_NO_LIMITS = JointLimits(np.full((N_RIG_JOINTS, 3), -np.inf), np.full((N_RIG_JOINTS, 3), np.inf))


def end_rotations(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
                  keypoints: np.ndarray, extremities: np.ndarray, camera_px: tuple[float, float, float],
                  planted: np.ndarray, up: np.ndarray, fps: float, params: TakeParams,
                  palms: np.ndarray | None = None) -> np.ndarray:
    """Local rotations ``[F, 4, 4]`` of the feet and hands (:data:`~mocapdb.core.skeleton.END_JOINTS`)
    of the fitted motion (``quats [F, R, 4]``, ``root_m [F, 3]`` view frame, body ``scale`` and
    ``offsets_m``): each turned from where its parent (shank, forearm) points it to the measured
    direction, heel → big toe for a foot, wrist → mid-knuckles for a hand
    (:func:`~mocapdb.runtime.end_joints.measured_candidates`, each frame's depth the cheapest path's:
    :func:`~mocapdb.runtime.end_branches.continuous_directions`); gaps interpolated,
    smoothed as the rotations (:attr:`TakeParams.smoothing_hz`); a ``planted [F, 2]`` foot flat
    on the floor (perpendicular to ``up`` but for the standing foot's slope,
    :data:`~mocapdb.core.skeleton.HEEL_TO_TOE_SLOPE_DEG`); a foot's lateral axis level
    (:func:`~mocapdb.runtime.end_joints.levelled_feet`); never seen: not turned. ``keypoints [F, 14, 3]``,
    ``extremities [F, 8, 3]``: x px, y px, confidence; ``camera_px``: the pinhole (focal, cx, cy: pixels). ``palms
    [F, 2, 3, 3]`` (:func:`~mocapdb.runtime.hand_pose.palm_frames` of the hand model's points; NaN: unseen):
    a hand's direction where seen, and its palm's twist about it, eased to none where unseen."""
    parents, reference = end_frames(quats)
    candidates = measured_candidates(quats, root_m, scale, offsets_m, keypoints, extremities, camera_px)
    direction = continuous_directions(candidates, sign_references(quats), fps)
    if palms is not None:
        direction[:, 2:] = np.where(np.isfinite(palms[..., 0, :]), palms[..., 0, :], direction[:, 2:])
    seen = np.isfinite(direction).all(axis=-1)
    direction = np.where(seen.any(axis=0)[None, :, None], interpolated(direction), reference)
    flat = np.concatenate([planted, np.zeros_like(planted)], axis=1)
    direction = np.where(flat[..., None], standing_directions(direction, up), direction)
    direction = zero_phase_smoothed(direction, fps, params.smoothing_hz)
    local = end_locals(parents, reference, direction)
    local = np.where(seen.any(axis=0)[None, :, None], levelled_feet(parents, local, up), local)
    knuckles = hand_twist_deg(parents[:, 2:], local[:, 2:], knuckle_thumb_sides(
        direction[:, 2:], extremities, camera_px, wrist_depths_m(quats, root_m, scale, offsets_m), scale,
        shortest_turn_axes(parents[:, 2:], local[:, 2:])[..., 1]))
    weights = np.array([steadiness(knuckles[:, hand]) for hand in range(2)])
    twist = np.where(weights > 0, weights * knuckles, np.nan)
    if palms is not None:
        twist = np.where(np.isfinite(palms[..., 1, 0]), hand_twist_deg(parents[:, 2:], local[:, 2:], palms[..., 1, :]),
                         twist)
    local[:, 2:] = twisted(local[:, 2:], eased_smoothed(twist, np.isfinite(twist), 0.0, fps, params))
    return local


def head_rotation(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
                  face_px: np.ndarray, camera_px: tuple[float, float, float], fps: float, params: TakeParams,
                  face_world_m: np.ndarray | None = None, mesh_px: np.ndarray | None = None) -> np.ndarray | None:
    """``[F, 4]`` the humanoid ``Head``'s local rotation of the fitted motion (``quats [F, R, 4]``, ``root_m``
    view frame, body ``scale``, ``offsets_m``) from the face points ``face_px [F, 7, 3]``, the detector's
    ``face_world_m [F, 11, 3]`` and the face mesh's head vertices ``mesh_px [F, N_HEAD, 3]`` if recorded
    (:func:`~mocapdb.runtime.head_pose.chest_relative_head`; the person's face from the take's meshes,
    :func:`~mocapdb.runtime.mesh_head.mesh_model`): gaps interpolated, de-popped and smoothed as the
    rotations, the mesh's frames carried whole (:func:`~mocapdb.runtime.mesh_head.eased_presence`); None
    when no frame's face fixes it."""
    model = None if mesh_px is None or not len(mesh_px) else mesh_model(mesh_px, scale)
    mesh = None if model is None or mesh_px is None else (mesh_observations(mesh_px), model)
    relative, from_mesh = chest_relative_head(quats, root_m, scale, offsets_m, face_px, camera_px, face_world_m,
                                              mesh)
    if not np.isfinite(relative).any():
        return None
    relative = smooth_rotations(interpolated(relative)[:, None], fps, params)[:, 0]
    return head_local(quats, relative, eased_presence(from_mesh, fps) if from_mesh.any() else None)


def _ends(feet_hands: np.ndarray | None, head: np.ndarray | None) -> np.ndarray | None:
    """The end joints' rotations ``[F, 5, 4]`` of the feet's and hands' ``[F, 4, 4]`` and the head's
    ``[F, 4]`` (None: not turned, identity); None when neither turns."""
    present = feet_hands if feet_hands is not None else head
    if present is None:
        return None
    n = len(present)
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return np.concatenate([np.repeat(identity[:, None], 4, axis=1) if feet_hands is None else feet_hands,
                           (identity if head is None else head)[:, None]], axis=1)


def fit_root_path(root_m: np.ndarray, ankle_offsets_m: np.ndarray, planted: np.ndarray, fps: float,
                  params: TakeParams) -> tuple[np.ndarray, np.ndarray]:
    """The root path ``[F, 3]`` (view frame) of the least-squares problem in the module docstring,
    and each planted frame's ankle anchor ``[F, 2, 3]`` (NaN where not planted). ``root_m [F, 3]``
    the per-frame roots, ``ankle_offsets_m [F, 2, 3]`` the ankles relative to the root,
    ``planted [F, 2]``."""
    n = len(root_m)
    contacts = [(k, start, stop) for k in range(planted.shape[1]) for start, stop in true_runs(planted[:, k])]
    n_unknowns = 3 * n + 3 * len(contacts)
    rows: list[np.ndarray] = []
    cols: list[np.ndarray] = []
    vals: list[np.ndarray] = []
    rhs: list[np.ndarray] = []

    def add(r_cols: np.ndarray, r_vals: np.ndarray, target: np.ndarray) -> None:
        """Rows ``Σ vals · x[cols] = target`` (``r_cols``, ``r_vals``: [m, terms])."""
        first = sum(len(t) for t in rhs)
        rows.append(np.repeat(first + np.arange(len(target)), r_cols.shape[1]))
        cols.append(r_cols.ravel())
        vals.append(r_vals.ravel())
        rhs.append(target)

    # data: per frame, three rows along an orthonormal basis (ray, two across), weighted
    ray = root_m / np.maximum(np.linalg.norm(root_m, axis=-1, keepdims=True), 1e-9)
    basis = np.stack([ray, *_perpendiculars(ray)], axis=1)                           # [F, 3 (rows), 3]
    weight = np.array([1.0 / params.root_depth_m, 1.0 / params.root_across_m, 1.0 / params.root_across_m])
    w_basis = basis * weight[None, :, None]
    frame_cols = 3 * np.arange(n)[:, None, None] + np.arange(3)[None, None, :]       # [F, 1, 3]
    add(np.broadcast_to(frame_cols, (n, 3, 3)).reshape(-1, 3), w_basis.reshape(-1, 3),
        np.einsum("fij,fj->fi", w_basis, root_m).ravel())
    # smoothness: second differences of each axis
    if n >= 3:
        w = 1.0 / (params.root_accel_mps2 / fps ** 2)
        t = np.arange(1, n - 1)
        for a in range(3):
            add(np.stack([3 * (t - 1) + a, 3 * t + a, 3 * (t + 1) + a], axis=1),
                np.tile([w, -2.0 * w, w], (len(t), 1)), np.zeros(len(t)))
    # contacts: root + ankle offset − anchor = 0 over each contact, along the ray and across it
    c_basis = basis * (1.0 / np.array([params.contact_depth_m, params.contact_m, params.contact_m]))[None, :, None]
    for c, (k, start, stop) in enumerate(contacts):
        t = np.arange(start, stop)
        w_rows = c_basis[t].reshape(-1, 3)                                           # [3·len(t), 3]
        root_cols = np.repeat(3 * t, 3)[:, None] + np.arange(3)[None, :]
        anchor_cols = np.broadcast_to(3 * n + 3 * c + np.arange(3), root_cols.shape)
        add(np.concatenate([root_cols, anchor_cols], axis=1), np.concatenate([w_rows, -w_rows], axis=1),
            -np.einsum("fij,fj->fi", c_basis[t], ankle_offsets_m[t, k]).ravel())
    a_matrix = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                 shape=(sum(len(t) for t in rhs), n_unknowns))
    b = np.concatenate(rhs)
    solution = spsolve((a_matrix.T @ a_matrix).tocsc(), a_matrix.T @ b)
    anchors = np.full((n, planted.shape[1], 3), np.nan)
    for c, (k, start, stop) in enumerate(contacts):
        anchors[start:stop, k] = solution[3 * n + 3 * c:3 * n + 3 * c + 3]
    return solution[:3 * n].reshape(n, 3), anchors


BLEND_FRAMES = 3  # frames over which a foot eases into and out of its contact


def plant_feet(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
               weights: np.ndarray, targets_m: np.ndarray) -> np.ndarray:
    """``quats [F, R, 4]`` with each leg's hip and knee turned (two-bone IK, the knee kept in its
    bending plane) so that an ankle moves towards its target ``targets_m [F, 2, 3]`` (view frame;
    right, left) by its weight ``weights [F, 2]`` (0: not at all, 1: onto it)."""
    quats = quats.copy()
    offsets = NODE_OFFSETS_M if offsets_m is None else offsets_m
    pelvis_rot = quat_to_matrix(quats[:, 0])
    for k, side in enumerate(("r", "l")):
        weight, target = weights[:, k], targets_m[:, k]
        active = weight > 0
        if not active.any():
            continue
        hip_j, knee_j = RIG_JOINTS.index(f"{side}_hip"), RIG_JOINTS.index(f"{side}_knee")
        hip_off, knee_off, ankle_off = (scale * offsets[NODE_NAMES.index(f"{side}_{part}")]
                                        for part in ("hip", "knee", "ankle"))
        g_hip = pelvis_rot @ quat_to_matrix(quats[:, hip_j])
        g_knee = g_hip @ quat_to_matrix(quats[:, knee_j])
        hip = root_m + pelvis_rot @ hip_off
        knee = hip + g_hip @ knee_off
        ankle = knee + g_knee @ ankle_off
        goal = ankle + weight[:, None] * (np.nan_to_num(target) - ankle)
        new_knee, new_ankle = _two_bone(hip, knee, ankle, goal)
        turn_hip = swing_matrices(_unit(knee - hip), _unit(new_knee - hip))
        g_hip_new = turn_hip @ g_hip
        turned_shank = np.einsum("fij,fj->fi", turn_hip, ankle - knee)
        g_knee_new = swing_matrices(_unit(turned_shank), _unit(new_ankle - new_knee)) @ turn_hip @ g_knee
        local_hip = np.swapaxes(pelvis_rot, -1, -2) @ g_hip_new
        local_knee = np.swapaxes(g_hip_new, -1, -2) @ g_knee_new
        quats[active, hip_j] = matrix_to_quat(local_hip[active])
        quats[active, knee_j] = matrix_to_quat(local_knee[active])
    return quats


REACH_SMOOTHING_FRAMES = 2.0  # the shortfall's smoothing (Gaussian SD, frames): no kink where a contact starts


def within_reach(root_m: np.ndarray, ankles_m: np.ndarray, planted: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """The root path ``[F, 3]`` moved by what a planted leg, fully stretched, falls short of its
    anchor (``ankles_m [F, 2, 3]`` after the IK, ``anchors [F, 2, 3]`` of the ``planted [F, 2]``
    frames; the mean of both feet's shortfalls), interpolated linearly between planted frames and
    smoothed over :data:`REACH_SMOOTHING_FRAMES`: the root path's depth slack can leave an anchor a
    few centimetres beyond the leg's reach, and the foot would slide."""
    shortfall = np.where(planted[..., None], anchors - ankles_m, np.nan)
    any_planted = planted.any(axis=1)
    if not any_planted.any():
        return root_m
    mean = np.nanmean(shortfall[any_planted], axis=1)
    frames = np.arange(len(root_m))
    shift = np.column_stack([np.interp(frames, frames[any_planted], mean[:, a]) for a in range(3)])
    return root_m + gaussian_filter1d(shift, REACH_SMOOTHING_FRAMES, axis=0, mode="nearest")


def contact_targets(planted: np.ndarray, anchors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per frame and foot the IK weight ``[F, 2]`` (1 in a contact, easing to 0 over
    :data:`BLEND_FRAMES` frames around it) and the target ``[F, 2, 3]`` (the contact's anchor, or the
    nearest contact's) of ``planted [F, 2]`` and the planted frames' ``anchors [F, 2, 3]``."""
    n = len(planted)
    weight, target = np.zeros(planted.shape), np.full(planted.shape + (3,), np.nan)
    for k in range(planted.shape[1]):
        for start, stop in true_runs(planted[:, k]):
            for t in range(max(start - BLEND_FRAMES, 0), min(stop + BLEND_FRAMES, n)):
                gap = max(start - t, t - (stop - 1), 0)
                w = 1.0 - gap / (BLEND_FRAMES + 1)
                if w > weight[t, k]:
                    weight[t, k], target[t, k] = w, anchors[start, k]
    return weight, target


def _two_bone(hip: np.ndarray, knee: np.ndarray, ankle: np.ndarray, goal: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Knee and ankle ``[F, 3]`` with the ankle at ``goal`` (or as near as the leg reaches), bone
    lengths kept, the knee on the side it bends to now."""
    thigh = np.linalg.norm(knee - hip, axis=-1)
    shank = np.linalg.norm(ankle - knee, axis=-1)
    reach = goal - hip
    dist = np.clip(np.linalg.norm(reach, axis=-1), np.abs(thigh - shank) + 1e-6, thigh + shank - 1e-6)
    u = _unit(reach)
    bend = (knee - hip) - np.sum((knee - hip) * u, axis=-1, keepdims=True) * u
    fallback = _unit(np.cross(u, np.cross(_unit(ankle - hip), u) + [1e-6, 0.0, 0.0]))
    bend = np.where(np.linalg.norm(bend, axis=-1, keepdims=True) > 1e-6, bend, fallback)
    along = (thigh ** 2 - shank ** 2 + dist ** 2) / (2.0 * dist)
    across = np.sqrt(np.maximum(thigh ** 2 - along ** 2, 0.0))
    new_knee = hip + along[:, None] * u + across[:, None] * _unit(bend)
    return new_knee, hip + dist[:, None] * u


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _perpendiculars(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``[F, 3]`` perpendicular to unit ``u [F, 3]`` and to each other."""
    helper = np.where(np.abs(u[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    a = np.cross(u, helper)
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    return a, np.cross(u, a)
