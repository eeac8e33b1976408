"""A detector's 2D quality without 2D ground truth (issue 28, item 5): the triangulation and its residuals
against hand-made cases and OpenCV, both keypoint layouts read, and the per-joint table of a tiny take."""
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from mocapdb.core.cameras import CameraModel
from mocapdb.core.errors import UsageError
from mocapdb.evaluation import detector_quality as dq
from mocapdb.evaluation.stereo import look_at
from mocapdb.evaluation.stereo_pairs import triangulate_views

FOCAL_PX = 1000.0
# A standing body (y-up world, metres): each compared joint's place; +x is the body's right.
BODY_M = {"nose": (0.0, 1.6, 0.08), "shoulder": (0.18, 1.45, 0.0), "elbow": (0.22, 1.15, 0.0),
          "wrist": (0.24, 0.9, 0.05), "hip": (0.1, 0.95, 0.0), "knee": (0.1, 0.5, 0.03),
          "ankle": (0.1, 0.08, 0.0), "heel": (0.1, 0.03, -0.05), "toe": (0.1, 0.02, 0.15)}


def _body(shift_m: np.ndarray) -> dict[str, np.ndarray]:
    """Every compared joint of a body moved by ``shift_m [3]``."""
    out = {}
    for part, (x, y, z) in BODY_M.items():
        for side, sign in (("r_", 1.0), ("l_", -1.0)):
            out["nose" if part == "nose" else side + part] = np.array([sign * x, y, z]) + shift_m
    return out


def _cameras(count: int) -> list[CameraModel]:
    """``count`` cameras 4 m around the origin, 1.2 m high, looking at the body's middle."""
    target = np.array([0.0, 0.9, 0.0])
    return [look_at(np.array([4 * np.sin(a), 1.2, -4 * np.cos(a)]), target, f"cam{k}")
            for k, a in enumerate(np.radians(np.linspace(-60, 80, count)), start=1)]


def _raw(layout: str, body: dict[str, np.ndarray], cam: CameraModel) -> np.ndarray:
    """The body in ``layout`` seen by ``cam``: ``[K, 3]`` (px, confidence 0.9; points it does not
    compare at the nose)."""
    points = np.repeat(body["nose"][None], len(dq.LAYOUTS[layout]), axis=0)
    for joint, index in dq.joint_sources(layout).items():
        points[index] = body[joint]
    return np.concatenate([cam.project(points), np.full((len(points), 1), 0.9)], axis=1)


def _write_take(root: Path, layout: str, cams: list[CameraModel], frames: int = 40,
                offsets: dict[tuple[int, str], tuple[float, float]] | None = None) -> list[Path]:
    """A folder per camera of OpenPose JSON: a swaying body, a bystander 3 m behind seen by the first
    two cameras, and ``offsets[(camera, joint)]`` px added to the body's detections."""
    folders = []
    for k, cam in enumerate(cams):
        folder = root / f"{layout}_{cam.name}"
        folder.mkdir()
        for t in range(frames):
            sway = np.array([0.05 * np.sin(t / 5), 0.0, 0.1 * t / frames])
            body = _raw(layout, _body(sway), cam)
            for (view, joint), shift in (offsets or {}).items():
                if view == k:
                    body[dq.joint_sources(layout)[joint], :2] += shift
            people = [body] + ([_raw(layout, _body(np.array([1.5, 0.0, 3.0])), cam)] if k < 2 else [])
            text = json.dumps({"people": [{"pose_keypoints_2d": p.ravel().tolist()} for p in people[::-1]]})
            (folder / f"{cam.name}_{t:012d}_keypoints.json").write_text(text)
        folders.append(folder)
    return folders


def test_triangulation_of_exact_views_has_no_residual_and_matches_opencv():
    cams = _cameras(2)
    points = np.array(list(_body(np.zeros(3)).values()))                      # [J, 3]
    px = [cam.project(points) for cam in cams]
    seen = [np.ones(len(points), dtype=bool)] * 2
    found = triangulate_views(px, seen, cams)
    np.testing.assert_allclose(found, points, atol=1e-9)
    homogeneous = cv2.triangulatePoints(*(cam.P for cam in cams), *(p.T for p in px))
    np.testing.assert_allclose((homogeneous[:3] / homogeneous[3]).T, found, atol=1e-6)
    det = dq.Detections("coco18", tuple(_body(np.zeros(3))), np.array(px)[:, None], np.full((2, 1, len(points)), 0.9),
                        np.zeros((2, 1), dtype=bool))
    _, offset, height_px = dq.residuals(det, cams, 0.3)
    assert np.abs(offset).max() < 1e-6
    assert 300 < height_px.min() < 500   # 1.52 m at about 4 m with a 1000 px focal length


def test_an_offset_across_the_epipolar_lines_splits_between_two_views():
    """Two cameras side by side (the epipolar lines horizontal), points straight ahead: 6 px up in one
    view leave a residual of 3 px in each (the triangulation halves it), as OpenCV's DLT finds too."""
    k = np.array([[FOCAL_PX, 0.0, 500.0], [0.0, FOCAL_PX, 500.0], [0.0, 0.0, 1.0]])
    cams = [CameraModel(k, np.zeros(4), np.eye(3), np.array([x, 0.0, 0.0]), (1000, 1000), f"cam{i}")
            for i, x in enumerate((0.5, -0.5))]
    points = np.stack([np.zeros(5), np.linspace(-0.8, 0.8, 5), np.full(5, 4.0)], axis=1)
    px = np.array([cam.project(points) for cam in cams])
    px[1, :, 1] -= 6.0
    seen = [np.ones(5, dtype=bool)] * 2
    found = triangulate_views(list(px), seen, cams)
    residual = np.linalg.norm(np.array([cam.project(found) for cam in cams]) - px, axis=-1)
    np.testing.assert_allclose(residual, 3.0, atol=0.02)
    homogeneous = cv2.triangulatePoints(cams[0].P, cams[1].P, px[0].T, px[1].T)
    np.testing.assert_allclose((homogeneous[:3] / homogeneous[3]).T, found, atol=1e-4)


def test_both_layouts_are_read_with_their_joints(tmp_path):
    cams = _cameras(3)
    coco = dq.read_detections(_write_take(tmp_path, "coco18", cams, 5), cams, 0.3)
    blaze = dq.read_detections(_write_take(tmp_path, "mediapipe33", cams, 5), cams, 0.3)
    assert (coco.layout, blaze.layout) == ("coco18", "mediapipe33")
    assert coco.joints == dq.BODY_JOINTS and blaze.joints == dq.BODY_JOINTS + tuple(dq.FOOT_JOINTS)
    body = _body(np.array([0.0, 0.0, 0.0]))
    for det in (coco, blaze):
        np.testing.assert_allclose(det.points_px[:, 0], [cam.project(np.array([body[j] for j in det.joints]))
                                                        for cam in cams], atol=0.01)   # the body, not the bystander
        assert det.confidence.min() == pytest.approx(0.9) and not det.mirrored.any()


def test_frames_must_correspond(tmp_path):
    cams = _cameras(2)
    folders = _write_take(tmp_path, "coco18", cams, 5)
    next(folders[1].iterdir()).unlink()
    with pytest.raises(UsageError, match="frame counts differ"):
        dq.read_detections(folders, cams, 0.3)


def _expected_residual_px(cams: list[CameraModel], point_m: np.ndarray, view: int, offset_px: np.ndarray) -> float:
    """Mean residual over the views of a point whose detection in ``view`` moved by ``offset_px``: the
    linearised least-squares fit (finite-difference Jacobians of the projections)."""
    jac = np.array([[(cam.project(point_m + d) - cam.project(point_m - d)) / 2e-6 for d in 1e-6 * np.eye(3)]
                    for cam in cams]).transpose(0, 2, 1)                                      # [V, 2, 3]
    error = np.zeros((len(cams), 2))
    error[view] = offset_px
    step = np.linalg.solve(np.einsum("vki,vkj->ij", jac, jac), np.einsum("vki,vk->i", jac, error))
    return float(np.linalg.norm(jac @ step - error, axis=-1).mean())


def test_per_joint_table_of_a_tiny_take(tmp_path):
    """Clean detections: no residual; 12 px on one view's right wrist: a residual there only, the mean
    over the views that of the least-squares fit."""
    cams = _cameras(4)
    detectors = {"clean": _write_take(tmp_path, "mediapipe33", cams),
                 "wrist": _write_take(tmp_path, "coco18", cams, offsets={(2, "r_wrist"): (12.0, 0.0)})}
    report = dq.evaluate(detectors, cams, 30.0)
    clean, wrist = report["detectors"]["clean"], report["detectors"]["wrist"]
    assert clean["body"]["mean_px"] < 0.01 and clean["feet"]["mean_px"] < 0.01 and wrist["feet"] is None
    assert clean["frames_triangulated"] == 40 and clean["joints"]["r_heel"]["mean_views"] == 4
    assert max(s["mean_px"] for j, s in wrist["joints"].items() if j != "r_wrist") < 0.01
    expected = np.mean([_expected_residual_px(cams, _body(np.array([0.05 * np.sin(t / 5), 0.0, 0.1 * t / 40]))[
        "r_wrist"], 2, np.array([12.0, 0.0])) for t in range(40)])
    assert wrist["joints"]["r_wrist"]["mean_px"] == pytest.approx(expected, rel=0.03)
    assert report["planted_from"]["detector"] == "clean"
    table = dq.format_table(report)
    assert "| joint | clean | wrist |" in table and "| r_heel | 0.0 / 0.0 px (0.00 / 0.00 %, 4.0 views) | – |" in table
    assert table.count("\n| ") == len(dq.BODY_JOINTS) + len(dq.FOOT_JOINTS) + 2   # joints, body, feet


def test_reconstruction_of_camera_one_is_scored(tmp_path, small_db_path):
    """With a database, camera 1 goes through `mocapdb reconstruct` and its main track's slide and
    acceleration are reported."""
    cams = _cameras(3)
    detectors = {"coco": _write_take(tmp_path, "coco18", cams, 60)}
    report = dq.evaluate(detectors, cams, 30.0, db=small_db_path, work=tmp_path / "rec")
    rec = report["detectors"]["coco"]["reconstruction"]
    assert rec["frames_with_output"] > 30 and np.isfinite(rec["acceleration_mps2"])
    assert "camera 1 alone through `mocapdb reconstruct`" in dq.format_table(report)
