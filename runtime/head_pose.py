"""The head's own rotation from the face points one camera sees (nose, eyes, ears, mouth corners).

A rigid face model (:data:`FACE_MODEL_M`, in the head's frame: x to the subject's left, y up, z
forwards, origin the ears' mid-point; scaled with the body) is turned and moved across the view so
that its points project onto the detected ones (:func:`fit_head`: Gauss-Newton on the confidence-
weighted re-projection error, robust (Huber) weights, its depth held where the body's nose is). A
weak prior holds it near ``prior`` where the face says little. Layouts give what they have: BlazePose
all seven points, COCO-17 and OpenPose nose, eyes and ears; fewer than :data:`MIN_POINTS` seen points
(nose included) leave the frame unknown. The face's left and right are tried both ways (detectors swap
them), the better fit kept. With the detector's world landmarks (:func:`face_world`: BlazePose's own
metric 3D) the face model is the person's own pattern (:func:`face_model`) and the prior is the head's
turn against the shoulders read off them (:func:`world_relative`). The humanoid ``Head`` carries only
the components in :data:`HEAD_GAINS` (:func:`head_local`).

Contract and decisions: ``data_specs/head.md``.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from mocapdb.core.formats.keypoint_layouts import EXTREMITIES
from mocapdb.core.geometry import euler_to_matrix, matrix_to_euler, matrix_to_quat, quat_to_matrix
from mocapdb.core.kernels import (
    cholesky_solve_into,
    mat3_mul_into,
    quat_exp_into,
    quat_log_into,
    quat_mul_into,
    quat_to_matrix_into,
)
from mocapdb.core.skeleton import FACE_MODEL_M, FACE_NAMES, KP, RIG_JOINTS, global_rotations, pose_from_rotations

# The face points after the nose (skeleton.FACE_NAMES), as rows of the extremities array (keypoint_layouts.EXTREMITIES)
FACE_ROWS = tuple(EXTREMITIES.index(n) for n in FACE_NAMES)
MIN_POINTS = 3            # seen face points (the nose one of them) a frame needs
POINT_SD_M = 0.01         # a face point's detection noise, metres at the head (1 cm)
HUBER_SD = 2.0            # residuals beyond this many SDs weigh less (Huber)
PRIOR_SD_DEG = 40.0       # the prior's pull: the head within about this of it
DEPTH_SD = 0.3            # the head's depth: free to within this share of the body's (the model's size is a guess)
ITERATIONS = 12
# The face rows with the subject's left and right exchanged (nose, eyes, ears, mouth corners)
SWAPPED = (0, 2, 1, 4, 3, 6, 5)
# The world landmarks the head needs (:func:`face_world`): the nose, FACE_NAMES, then the shoulders and hips
WORLD_BODY = tuple(KP[n] for n in ("r_shoulder", "l_shoulder", "r_hip", "l_hip"))
NO_FACE_WORLD = np.full((7 + len(WORLD_BODY), 3), np.nan)
MIN_MODEL_FRAMES = 5      # frames with all seven world face points a person's own face model needs
WORLD_PRIOR_SD_DEG = 15.0  # the world landmarks' head rotation as the fit's prior: within about this
# Which components of the head's own rotation (intrinsic Y-X-Z against the Neck: turn, nod, tilt) the
# humanoid Head carries (1) or leaves to the neck (0): the decision rule of data_specs/head.md
HEAD_GAINS = np.array([0.0, 0.0, 1.0])
_VIEW_OF_WORLD = np.array([1.0, -1.0, -1.0])   # world landmarks (x right, y down, z away) → view (y up, z to camera)
_BODY_SWAP = np.array([-1.0, 1.0, -1.0])   # the chest's x and z flip: Ry(180°) (rows of chest⁻¹ · head)
_FACE_SWAP = np.array([-1.0, -1.0, 1.0])   # the head's x and y flip: Rz(180°) (its columns)


def face_points(keypoints: np.ndarray, extremities: np.ndarray) -> np.ndarray:
    """``[F, 7, 3]`` nose then :data:`FACE_NAMES` (x px, y px, confidence; 0: unseen) of ``keypoints
    [F, 14, 3]`` and ``extremities [F, E, 3]``."""
    return np.concatenate([keypoints[:, :1], extremities[:, list(FACE_ROWS)]], axis=1)


def fit_head(face_px: np.ndarray, nose_view_m: np.ndarray, prior: np.ndarray, scale: float,
             camera_px: tuple[float, float, float], prior_sd_deg: float | np.ndarray = PRIOR_SD_DEG,
             model_m: np.ndarray | None = None, swapped: tuple[int, ...] | None = SWAPPED
             ) -> tuple[np.ndarray, np.ndarray]:
    """The head's global rotations ``[F, 3, 3]`` (view frame; identity: facing +z upright) and which
    frames the face fixed ``[F]`` (the others: ``prior``). ``face_px [F, P, 3]``: :func:`face_points`
    (or another face's points, the nose first, with its ``model_m``);
    ``nose_view_m [F, 3]``: the body's nose (view frame, metres; its depth is the model's);
    ``prior [F, 3, 3]``: where the head would be without the face (the start, held within
    ``prior_sd_deg``, degrees, one or ``[F]``); ``scale``: the body's (height / 1.75 m); ``camera_px``:
    focal, cx, cy (pixels); ``model_m [P, 3]``: the face (metres; default :data:`FACE_MODEL_M` scaled).
    Each frame's face is fitted as labelled and, with ``swapped`` (the rows with left and right exchanged;
    None: not tried), with its left and right exchanged (both in one :func:`_fit_face`: its cost is mostly
    per call, a stream fits one frame at a time); the lower cost wins."""
    model = FACE_MODEL_M * scale if model_m is None else model_m
    seen = (face_px[..., 2] > 0) & np.isfinite(face_px[..., :2]).all(axis=-1)
    fixed = seen[:, 0] & (seen.sum(axis=1) >= MIN_POINTS)
    rotation = prior.copy()
    if not fixed.any():
        return rotation, fixed
    count = int(fixed.sum())
    sd = np.broadcast_to(np.radians(prior_sd_deg), fixed.shape)[fixed]
    pixel_sd = camera_px[0] * POINT_SD_M * scale / -nose_view_m[fixed, 2]
    if swapped is None:
        rotation[fixed] = _fit_face(face_px[fixed], nose_view_m[fixed], prior[fixed], sd, pixel_sd, model, camera_px)[0]
        return rotation, fixed
    both_ways = np.concatenate([face_px[fixed], face_px[fixed][:, list(swapped)]])
    nose2, prior2, sd2, pixel_sd2 = (np.concatenate([a, a]) for a in (nose_view_m[fixed], prior[fixed], sd, pixel_sd))
    fitted, cost = _fit_face(both_ways, nose2, prior2, sd2, pixel_sd2, model, camera_px)
    rotation[fixed] = np.where((cost[count:] < cost[:count])[:, None, None], fitted[count:], fitted[:count])
    return rotation, fixed


def _fit_face(face_px: np.ndarray, nose: np.ndarray, base: np.ndarray, prior_sd_rad: np.ndarray,
              pixel_sd: np.ndarray, model: np.ndarray, camera_px: tuple[float, float, float]
              ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`fit_head`'s Gauss-Newton on frames the face fixes: rotations ``[n, 3, 3]`` and their costs
    ``[n]`` (Huber re-projection cost in SDs², confidence-weighted, plus the prior's)."""
    seen = (face_px[..., 2] > 0) & np.isfinite(face_px[..., :2]).all(axis=-1)
    weight = np.where(seen, face_px[..., 2], 0.0)
    rotation, cost = np.empty((len(face_px), 3, 3)), np.empty(len(face_px))
    _fit_face_kernel(np.nan_to_num(face_px[..., :2]), weight, nose, np.ascontiguousarray(base), 1.0 / prior_sd_rad,
                     pixel_sd, np.ascontiguousarray(model, dtype=np.float64), *camera_px, rotation, cost)
    return rotation, cost


@njit(cache=True)
def _fit_face_kernel(observed: np.ndarray, weight: np.ndarray, nose: np.ndarray, base: np.ndarray,
                     prior_weight: np.ndarray, pixel_sd: np.ndarray, model: np.ndarray, focal: float, cx: float,
                     cy: float, rotation: np.ndarray, cost: np.ndarray) -> None:
    """:func:`_fit_face` per frame: ``observed [n, P, 2]`` pixels, their ``weight [n, P]`` (0: unseen), the
    body's ``nose [n, 3]`` (m, view frame), the prior ``base [n, 3, 3]`` and its weight ``[n]`` (1 / SD,
    radians), ``pixel_sd [n]``, ``model [P, 3]`` (m); fills ``rotation [n, 3, 3]`` (the turn away from
    ``base``, a unit quaternion, times ``base``) and ``cost [n]``. Each of :data:`ITERATIONS` steps: the
    normal equations of the turn (rotation vector, left-multiplied) and the centre's move, one Cholesky solve."""
    n_points = len(model)
    q, step_turn, turned, turn = np.empty(4), np.empty(4), np.empty(4), np.empty((3, 3))
    offsets, points, residual = np.empty((n_points, 3)), np.empty((n_points, 3)), np.empty((n_points, 2))
    size, away = np.empty(n_points), np.empty(3)
    normal, gradient, step = np.empty((6, 6)), np.empty(6), np.empty(6)
    for f in range(len(observed)):
        q[:] = (1.0, 0.0, 0.0, 0.0)
        rotation[f] = base[f]
        centre = nose[f] - base[f] @ model[0]
        start_depth = centre[2]
        depth_weight2, prior_weight2 = 1.0 / (DEPTH_SD * start_depth) ** 2, prior_weight[f] ** 2
        for _ in range(ITERATIONS):
            _face_residuals(rotation[f], centre, model, observed[f], pixel_sd[f], focal, cx, cy, offsets, points,
                            residual, size)
            _normal_equations(points, offsets, residual, size, weight[f], focal / pixel_sd[f], normal, gradient)
            quat_log_into(q, away)
            for i in range(3):
                normal[i, i] += prior_weight2
                gradient[i] += prior_weight2 * away[i]
            normal[5, 5] += depth_weight2
            gradient[5] += depth_weight2 * (centre[2] - start_depth)
            if not cholesky_solve_into(normal, -gradient, 6, step):
                break
            quat_exp_into(step[:3], step_turn)
            quat_mul_into(step_turn, q, turned)
            q[:] = turned
            quat_to_matrix_into(q, turn)
            mat3_mul_into(turn, base[f], rotation[f])
            centre += step[3:]
        _face_residuals(rotation[f], centre, model, observed[f], pixel_sd[f], focal, cx, cy, offsets, points,
                        residual, size)
        quat_log_into(q, away)
        cost[f] = 0.5 * prior_weight2 * (away[0] ** 2 + away[1] ** 2 + away[2] ** 2)
        for p in range(n_points):
            huber = 0.5 * size[p] ** 2 if size[p] < HUBER_SD else HUBER_SD * (size[p] - 0.5 * HUBER_SD)
            cost[f] += weight[f, p] * huber


@njit(cache=True)
def _normal_equations(points: np.ndarray, offsets: np.ndarray, residual: np.ndarray, size: np.ndarray,
                      weight: np.ndarray, focal_sd: float, normal: np.ndarray, gradient: np.ndarray) -> None:
    """``normal [6, 6]`` (JᵀWJ, plus 1e-9 on the diagonal) and ``gradient [6]`` (JᵀWr) of one frame's face
    points: :func:`_face_residuals`' outputs, ``weight [P]`` times the Huber weights of the residuals' ``size``."""
    jac = np.empty((2, 6))
    normal[:] = 0.0
    gradient[:] = 0.0
    for p in range(len(points)):
        w = weight[p] * min(1.0, HUBER_SD / max(size[p], 1e-12))
        _point_jacobian(points[p], offsets[p], focal_sd, jac)
        for k in range(2):
            for i in range(6):
                gradient[i] += w * jac[k, i] * residual[p, k]
                for j in range(6):
                    normal[i, j] += w * jac[k, i] * jac[k, j]
    for i in range(6):
        normal[i, i] += 1e-9


@njit(cache=True)
def _face_residuals(rotation: np.ndarray, centre: np.ndarray, model: np.ndarray, observed: np.ndarray,
                    pixel_sd: float, focal: float, cx: float, cy: float, offsets: np.ndarray, points: np.ndarray,
                    residual: np.ndarray, size: np.ndarray) -> None:
    """The turned ``model``'s ``offsets`` and ``points [P, 3]`` (view frame), its re-projection ``residual
    [P, 2]`` and their ``size [P]`` (in pixel SDs) against ``observed [P, 2]`` (pixels; y down)."""
    for p in range(len(model)):
        for i in range(3):
            offsets[p, i] = rotation[i, 0] * model[p, 0] + rotation[i, 1] * model[p, 1] + rotation[i, 2] * model[p, 2]
            points[p, i] = centre[i] + offsets[p, i]
        depth = -points[p, 2]
        residual[p, 0] = (cx + focal * points[p, 0] / depth - observed[p, 0]) / pixel_sd
        residual[p, 1] = (cy - focal * points[p, 1] / depth - observed[p, 1]) / pixel_sd
        size[p] = np.sqrt(residual[p, 0] ** 2 + residual[p, 1] ** 2)


@njit(cache=True)
def _point_jacobian(point: np.ndarray, offset: np.ndarray, focal_sd: float, jac: np.ndarray) -> None:
    """``jac [2, 6]``: a point's (= centre + ``offset``) pixels, in pixel SDs (``focal_sd``: focal / SD), by a
    small turn (rotation vector, left-multiplied: d offset = −[offset]× d turn) and a move of the centre."""
    depth = -point[2]
    du_x, du_z = focal_sd / depth, focal_sd * point[0] / depth ** 2
    dv_y, dv_z = -focal_sd / depth, -focal_sd * point[1] / depth ** 2
    ox, oy, oz = offset[0], offset[1], offset[2]
    jac[0, 0], jac[0, 1], jac[0, 2] = du_z * oy, du_x * oz - du_z * ox, -du_x * oy
    jac[1, 0], jac[1, 1], jac[1, 2] = -dv_y * oz + dv_z * oy, -dv_z * ox, dv_y * ox
    jac[0, 3], jac[0, 4], jac[0, 5] = du_x, 0.0, du_z
    jac[1, 3], jac[1, 4], jac[1, 5] = 0.0, dv_y, dv_z


def face_world(world_m: np.ndarray | None, extremities_world_m: np.ndarray | None) -> np.ndarray:
    """``[11, 3]`` the world landmarks (``Person.world_m [14, 3]``, ``Person.extremities_world_m [E, 3]``;
    metres, x right, y down, z away) of the nose, :data:`FACE_NAMES` and :data:`WORLD_BODY`; NaN without."""
    if world_m is None or extremities_world_m is None:
        return NO_FACE_WORLD
    return np.concatenate([world_m[:1], extremities_world_m[list(FACE_ROWS)], world_m[list(WORLD_BODY)]])


def frames_along(x: np.ndarray, hint: np.ndarray, hint_axis: int) -> np.ndarray:
    """Rotations ``[..., 3, 3]`` (columns x, y, z) with x along ``x`` and axis ``hint_axis`` (1: y,
    2: z) along ``hint`` made perpendicular to it; right-handed. NaN where ``x`` is zero or along
    ``hint`` (two landmarks at one place: no frame; callers treat NaN as unseen)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        x = x / np.linalg.norm(x, axis=-1, keepdims=True)
        second = hint - np.sum(hint * x, axis=-1, keepdims=True) * x
        second /= np.linalg.norm(second, axis=-1, keepdims=True)
    third = np.cross(x, second) if hint_axis == 1 else np.cross(second, x)
    return np.stack([x, second, third] if hint_axis == 1 else [x, third, second], axis=-1)


def _world_head(face_view: np.ndarray) -> np.ndarray:
    """``[..., 3, 3]`` the head frame (x: right → left ear, z: ears' mid-point → nose) of view-frame
    :func:`face_world` points ``[..., 11, 3]``."""
    mid = 0.5 * (face_view[..., 3, :] + face_view[..., 4, :])
    return frames_along(face_view[..., 4, :] - face_view[..., 3, :], face_view[..., 0, :] - mid, 2)


def face_model(face_world_m: np.ndarray) -> np.ndarray | None:
    """``[7, 3]`` the person's own face (metres, the head frame of :data:`FACE_MODEL_M`): the median over
    frames of their :func:`face_world` points ``[F, 11, 3]`` in the head frame (ears → x, ears'
    mid-point → nose ≈ z); None with fewer than :data:`MIN_MODEL_FRAMES` frames seeing all seven."""
    view = face_world_m[:, :7] * _VIEW_OF_WORLD
    whole = view[np.isfinite(view).all(axis=(1, 2))]
    if len(whole) < MIN_MODEL_FRAMES:
        return None
    head = _world_head(whole)
    local = np.einsum("fji,fpj->fpi", head, whole - 0.5 * (whole[:, 3:4] + whole[:, 4:5]))
    return np.median(local, axis=0)


def world_relative(face_world_m: np.ndarray) -> np.ndarray:
    """``[F, 3, 3]`` the head's rotation relative to the chest (x: right → left shoulder, y: hips →
    shoulders) of :func:`face_world` points ``[F, 11, 3]`` (NaN where any is missing). A detector that
    swaps the left and right of the body (a half turn of the chest about its up) or of the face (of
    the head about its forwards) against the other: of the four labellings, the smallest rotation."""
    view = face_world_m * _VIEW_OF_WORLD
    r_sh, l_sh, r_hip, l_hip = np.moveaxis(view[:, 7:], 1, 0)
    chest = frames_along(l_sh - r_sh, 0.5 * (r_sh + l_sh - r_hip - l_hip), 1)
    relative = np.swapaxes(chest, -1, -2) @ _world_head(view)
    candidates = np.stack([relative, relative * _BODY_SWAP[:, None], relative * _FACE_SWAP,
                           relative * _BODY_SWAP[:, None] * _FACE_SWAP])             # [4, F, 3, 3]
    best = np.argmax(np.trace(candidates, axis1=-2, axis2=-1), axis=0)
    return candidates[best, np.arange(len(relative))]


def chest_relative_head(quats: np.ndarray, root_m: np.ndarray, scale: float, offsets_m: np.ndarray | None,
                        face_px: np.ndarray, camera_px: tuple[float, float, float],
                        face_world_m: np.ndarray | None = None,
                        mesh: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``[F, 4]`` the head's rotation relative to the chest (the ``spine`` joint's frame; w ≥ 0, NaN
    where neither the face nor the world landmarks fix it) of a motion (``quats [F, R, 4]``, ``root_m
    [F, 3]`` view frame, body ``scale`` and ``offsets_m``) seen as ``face_px [F, 7, 3]``
    (:func:`face_points`), with the detector's ``face_world_m [F, 11, 3]`` (:func:`face_world`) if any,
    and the frames the face mesh fixed ``[F]``: with ``mesh`` (its head vertices as points ``[F, H, 3]``,
    :func:`~mocapdb.runtime.mesh_head.mesh_observations`, and the person's model ``[H, 3]``) the head is
    fitted to the mesh where it is present (the prior as the face points', held within
    :data:`PRIOR_SD_DEG`), to the face points elsewhere."""
    chest = global_rotations(quats)[:, RIG_JOINTS.index("spine")]
    nose = pose_from_rotations(quats, root_m, scale, offsets_m)[:, KP["head"]]
    prior, known, model = chest, np.zeros(len(chest), dtype=bool), None
    sd: float | np.ndarray = PRIOR_SD_DEG
    if face_world_m is not None and len(face_world_m):
        measured = world_relative(face_world_m)
        known = np.isfinite(measured).all(axis=(1, 2))
        prior = np.where(known[:, None, None], chest @ np.nan_to_num(measured), chest)
        sd = np.where(known, WORLD_PRIOR_SD_DEG, PRIOR_SD_DEG)
        model = face_model(face_world_m)
    from_mesh = np.zeros(len(chest), dtype=bool)
    if mesh is not None:
        on_mesh, from_mesh = fit_head(mesh[0], nose, prior, scale, camera_px, PRIOR_SD_DEG, mesh[1], swapped=None)
        face_px = np.where(from_mesh[:, None, None], 0.0, face_px)          # the face points where no mesh is
    head, fixed = fit_head(face_px, nose, prior, scale, camera_px, sd, model)
    if mesh is not None:
        head = np.where(from_mesh[:, None, None], on_mesh, head)
    relative = matrix_to_quat(np.swapaxes(chest, -1, -2) @ head)
    relative *= np.where(relative[:, :1] < 0, -1.0, 1.0)
    return np.where((fixed | known | from_mesh)[:, None], relative, np.nan), from_mesh


def head_local(quats: np.ndarray, chest_relative: np.ndarray, mesh_weight: np.ndarray | None = None
               ) -> np.ndarray:
    """``[F, 4]`` the humanoid ``Head``'s local rotation (relative to the ``Neck``, which carries the
    universal ``neck`` joint) that puts the head at ``chest_relative [F, 4]`` from the chest in the
    components :data:`HEAD_GAINS` keeps (intrinsic Y-X-Z angles against the chest: turn, nod, tilt) and
    where the neck holds it (the head rigid on the neck) in the others; by ``mesh_weight [F]`` (0-1: how
    much the face mesh fixed the frame, eased in and out) every component is kept (the mesh's rotation
    whole: data_specs/head.md, "Decision rule")."""
    rotations = global_rotations(quats)
    chest, neck = rotations[:, RIG_JOINTS.index("spine")], rotations[:, RIG_JOINTS.index("neck")]
    fitted = matrix_to_euler(quat_to_matrix(chest_relative), "YXZ")
    rigid = matrix_to_euler(np.swapaxes(chest, -1, -2) @ neck, "YXZ")
    gains = HEAD_GAINS if mesh_weight is None else HEAD_GAINS + mesh_weight[:, None] * (1.0 - HEAD_GAINS)
    kept = euler_to_matrix(gains * fitted + (1.0 - gains) * rigid, "YXZ")
    return matrix_to_quat(np.swapaxes(neck, -1, -2) @ chest @ kept)
