"""`mocapdb eval`: the database floor, camera pitch, reprojection/root errors, engine variants and
the leave-one-subject-out run."""
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mocapdb.builder.config import BuildConfig
from mocapdb.core.clips import ClipOptions, process_clip
from mocapdb.core.errors import UsageError
from mocapdb.core.formats.keypoints import KeypointFrame, Person
from mocapdb.core.geometry import yaw_matrix
from mocapdb.core.skeleton import PELVIS
from mocapdb.evaluation.engine_runs import EngineRun
from mocapdb.evaluation.floor import FloorIndex, database_floor
from mocapdb.evaluation.heldout import Scenario, Truth, camera_distance, camera_view, project, render, scaled_positions
from mocapdb.evaluation.loso import (
    LosoConfig,
    format_table,
    group_by_subject,
    leave_one_subject_out,
    subject_of,
    trial_of,
)
from mocapdb.evaluation.reconstruction import (
    EvalConfig,
    VariantStats,
    View,
    compute_floors,
    evaluate,
    floor_key,
    reprojection_pct,
)

from .conftest import SAMPLE_BVH


@pytest.fixture(scope="module")
def walk_and_dance():
    """Two real clips on the universal skeleton (24 fps): subject 2 walking, subject 5 dancing."""
    cfg = ClipOptions()
    return [process_clip(SAMPLE_BVH / name, SAMPLE_BVH, cfg).positions.astype(np.float64)
            for name in ("002_01.bvh", "005_11.bvh")]


def brute_force_floor(db: np.ndarray, truth: np.ndarray, n_theta: int = 1440) -> np.ndarray:
    """Min over every database frame and a dense grid of turns of the MPJPE (pelvis-relative)."""
    turns = yaw_matrix(np.arange(n_theta) * 360.0 / n_theta)            # [Θ, 3, 3]
    b = db - db[:, PELVIS:PELVIS + 1]
    a = truth - truth[:, PELVIS:PELVIS + 1]
    turned = np.einsum("vij,fkj->vfki", turns, b)                       # [Θ, F, 15, 3]
    return np.array([np.linalg.norm(turned - t, axis=-1).mean(axis=-1).min() for t in a])


# -- the floor ---------------------------------------------------------------------------------------
def test_floor_matches_brute_force_on_real_poses(walk_and_dance):
    walk, dance = walk_and_dance
    db = walk[::2]                                   # ~100 walking frames
    truth = np.concatenate([dance[::15], walk[1::20]])  # unseen dance poses and in-between walking frames
    floor = database_floor(FloorIndex.from_positions(db), truth)
    reference = brute_force_floor(db, truth)
    assert np.all(reference > 0.002)                 # none of them is in the database
    np.testing.assert_allclose(floor.mpjpe_m, reference, atol=1e-4)  # within 0.1 mm
    # the plain version (32 frames at the squared-optimal turn) is an upper bound, further off
    plain = database_floor(FloorIndex.from_positions(db), truth, top_k=32, turn_iterations=0).mpjpe_m
    assert np.all(plain >= floor.mpjpe_m - 1e-12) and np.abs(plain - reference).max() > 1e-3
    # the reported frame and turn reach the reported value
    rel = db[floor.frame] - db[floor.frame, PELVIS:PELVIS + 1]
    turned = np.einsum("fij,fkj->fki", yaw_matrix(floor.yaw_deg), rel)
    direct = np.linalg.norm(turned - (truth - truth[:, PELVIS:PELVIS + 1]), axis=-1).mean(axis=-1)
    np.testing.assert_allclose(direct, floor.mpjpe_m, atol=1e-9)


def test_floor_matches_brute_force_on_random_poses():
    rng = np.random.default_rng(3)
    db = rng.normal(scale=0.3, size=(300, 15, 3))
    truth = db[rng.integers(0, 300, 12)] + rng.normal(scale=0.05, size=(12, 15, 3))
    floor = database_floor(FloorIndex.from_positions(db), truth)
    reference = brute_force_floor(db, truth, 720)
    # an upper bound of the exact floor: never meaningfully below the grid's minimum, and close to it
    assert np.all(floor.mpjpe_m >= reference - 1e-4)
    np.testing.assert_allclose(floor.mpjpe_m, reference, atol=1e-3)


@pytest.mark.parametrize("yaw", [0.0, 37.0, -141.0, 263.5])
def test_floor_is_zero_for_a_database_frame_turned_and_moved(walk_and_dance, yaw):
    db = np.concatenate(walk_and_dance)
    frames = np.array([5, 30, 60, 100])
    truth = (db[frames] - db[frames, PELVIS:PELVIS + 1]) @ yaw_matrix(yaw).T + [2.0, 0.3, -1.0]
    index = FloorIndex.from_positions(db)
    # also with the bare closed form: 2 candidates by squared error, no reweighting of the turn
    for floor in (database_floor(index, truth), database_floor(index, truth, top_k=2, turn_iterations=0)):
        np.testing.assert_allclose(floor.mpjpe_m, 0.0, atol=1e-6)
        np.testing.assert_array_equal(floor.frame, frames)
        np.testing.assert_allclose((floor.yaw_deg - yaw + 180.0) % 360.0 - 180.0, 0.0, atol=1e-4)
    # and frames that are not in the database have a floor above zero
    assert database_floor(FloorIndex.from_positions(np.delete(db, frames, axis=0)), truth).mpjpe_m.min() > 1e-3


def test_floor_of_a_given_height_is_against_the_database_at_that_size(walk_and_dance, small_db):
    truths = [Truth("dance", walk_and_dance[1][::10]),
              Truth("from the database", small_db.positions[::25].astype(np.float64))]
    tall, given, unknown = (Scenario("a"), Scenario("b", subject_height_m=1.55, height_given=True),
                            Scenario("c", subject_height_m=1.55))
    floors = compute_floors(small_db, truths, (tall, given, unknown), EvalConfig(yaws_deg=(6.0,)))
    key = {s.name: (lambda i, s=s: floor_key(i, 0, s)) for s in (tall, given, unknown)}
    base = floors[key["a"](0)]
    np.testing.assert_allclose(floors[key["b"](0)], base * 1.55 / 1.75, rtol=1e-9)
    # database poses: at their size and at a given size they are in the database; a smaller body
    # against the 1.75 m database is not
    np.testing.assert_allclose(floors[key["a"](1)], 0.0, atol=1e-6)
    np.testing.assert_allclose(floors[key["b"](1)], 0.0, atol=1e-6)
    assert floors[key["c"](1)].min() > 0.01


def test_floor_speed_is_seconds_not_minutes():
    rng = np.random.default_rng(0)
    index = FloorIndex.from_positions(rng.normal(scale=0.3, size=(200_000, 15, 3)).astype(np.float32))
    database_floor(index, rng.normal(scale=0.3, size=(16, 15, 3)))  # compile / load the cache
    import time
    t0 = time.perf_counter()
    database_floor(index, rng.normal(scale=0.3, size=(500, 15, 3)))
    assert time.perf_counter() - t0 < 10.0   # 1e8 pairs; ~0.4 s on 2 cores


# -- camera and scenarios ----------------------------------------------------------------------------
def _one_point_clip(point) -> np.ndarray:
    """15 keypoints: the pelvis at (0, 1, 0), keypoint 0 at ``point``, the rest at the pelvis."""
    positions = np.tile([0.0, 1.0, 0.0], (1, 15, 1))
    positions[0, 0] = point
    return positions


def test_pitched_camera_projects_as_computed_by_hand():
    f, pitch, height, distance = 1000.0, 15.0, 1.5, 5.0
    t = math.tan(math.radians(pitch))
    # a point at the camera's height straight ahead sits f·tan(15°) above the image centre
    ahead = _one_point_clip([0.0, height, 0.0])
    cam = camera_view(ahead, 0.0, height, distance, pitch)
    np.testing.assert_allclose(cam[0, 0], [0.0, distance * math.sin(math.radians(pitch)),
                                           distance * math.cos(math.radians(pitch))], atol=1e-12)
    frames = render(cam, Scenario("pitched", pitch_deg=pitch), f, (1920, 1080), np.random.default_rng(0))
    np.testing.assert_allclose(frames[0].people[0].points_px[0], [960.0, 540.0 - f * t], atol=1e-9)
    # a point on the optical axis (5 m ahead, 5·tan 15° below the camera) lands on the image centre,
    # and one 0.5 m to the side at the same depth lands f·0.5/depth to the right
    on_axis = _one_point_clip([0.5, height - distance * t, 0.0])
    px = project(camera_view(on_axis, 0.0, height, distance, pitch), f, (1920, 1080))
    np.testing.assert_allclose(px[0, 0], [960.0 + f * 0.5 / (distance / math.cos(math.radians(pitch))), 540.0],
                               atol=1e-9)
    # without pitch: x right, y up from the camera's height, z the distance
    flat = camera_view(ahead, 0.0, height, distance, 0.0)
    np.testing.assert_allclose(flat[0, [0, PELVIS]], [[0.0, 0.0, distance], [0.0, 1.0 - height, distance]])


def test_subject_height_scales_about_the_floor_under_the_mean_pelvis(walk_and_dance):
    walk = walk_and_dance[0]
    small = scaled_positions(walk, 1.55)
    s = 1.55 / 1.75
    centre = walk[:, PELVIS].mean(axis=0) * [1, 0, 1]
    np.testing.assert_allclose(small, centre + s * (walk - centre))
    np.testing.assert_allclose(small[:, PELVIS].mean(axis=0)[[0, 2]], centre[[0, 2]])
    assert small[..., 1].min() == pytest.approx(s * walk[..., 1].min())
    assert scaled_positions(walk, 1.75) is walk


def test_camera_stays_three_metres_from_a_travelling_clip():
    path = np.zeros((50, 15, 3))
    path[:, :, 2] = np.linspace(-4.0, 4.0, 50)[:, None]   # walks 8 m along +z
    config = EvalConfig()
    assert camera_distance(path, 0.0, config) == pytest.approx(3.0 + 4.0)   # towards the camera
    assert camera_distance(path, 90.0, config) == pytest.approx(5.0)       # across the view
    cam = camera_view(path, 0.0, 1.5, camera_distance(path, 0.0, config))
    assert cam[:, PELVIS, 2].min() == pytest.approx(3.0)


# -- per-frame metrics -------------------------------------------------------------------------------
def _frames(px: np.ndarray, conf: float = 0.9) -> list[KeypointFrame]:
    return [KeypointFrame(i, None, [Person(p, np.full(14, conf))]) for i, p in enumerate(px)]


def test_reprojection_and_root_errors_are_zero_when_the_output_is_the_truth(walk_and_dance):
    config = EvalConfig()
    cam = camera_view(walk_and_dance[0][:30], 51.0, 1.5, 5.0, 15.0)
    clean = project(cam[:, :14], config.focal_px, config.image_size)
    stats = VariantStats()
    run = EngineRun(cam.copy(), cam[:, PELVIS].copy(), cam.copy(), 1.0)
    view = View(cam, 1.5, 5.0, 15.0)
    stats.add(run, view, np.full(30, 0.05), _frames(clean), config)
    s = stats.summary()
    for key in ("mpjpe_cm", "mpjpe13_cm", "pa_mpjpe_cm", "pa_mpjpe13_cm", "bone_error_cm", "reprojection_error_pct",
                "reprojection_error_input_pct", "root_error_m", "root_error_pct_distance", "engine_minus_floor_cm"):
        assert s[key] == pytest.approx(-5.0 if key == "engine_minus_floor_cm" else 0.0, abs=1e-6), key
    assert s["frames_below_floor"] == 1.0 and s["floor_mpjpe_cm"] == 5.0
    # the truth's own feet neither slide nor leave the floor where they are planted, and nothing pops
    assert s["foot_skating_cm_per_s"]["mean"] < 5.0 and s["planted_foot_height_cm"]["mean"] == 0.0
    assert s["frames_with_pop"] == 0.0
    # a 10-pixel offset of the input shows in the input error only, as 10 px over the box height
    shifted = VariantStats()
    shifted.add(run, view, np.zeros(30), _frames(clean + [10.0, 0.0]), config)
    box = np.ptp(clean[..., 1], axis=1)
    assert shifted.summary()["reprojection_error_pct"] == pytest.approx(0.0, abs=1e-6)
    assert shifted.summary()["reprojection_error_input_pct"] == pytest.approx(np.mean(1000.0 / box), rel=1e-3)


def test_root_error_and_reprojection_of_a_displaced_output(walk_and_dance):
    config = EvalConfig()
    cam = camera_view(walk_and_dance[0][:10], 0.0, 1.5, 5.0)
    moved = cam + [0.0, 0.0, 0.5]   # the whole body 0.5 m too far: same pose, smaller image
    stats = VariantStats()
    stats.add(EngineRun(moved, moved[:, PELVIS], moved, 1.0), View(cam, 1.5, 5.0, 0.0), np.zeros(10),
              _frames(np.zeros((10, 14, 2))), config)
    s = stats.summary()
    assert s["mpjpe_cm"] == pytest.approx(0.0, abs=1e-9)
    assert s["root_error_m"] == pytest.approx(0.5)
    assert s["root_error_pct_distance"] == pytest.approx(np.mean(50.0 / cam[:, PELVIS, 2]), abs=0.006)
    assert s["reprojection_error_pct"] > 1.0
    px = project(cam[:, :14], config.focal_px, config.image_size)
    pct = reprojection_pct(moved, px, np.ptp(px[..., 1], axis=1), config.focal_px, config.image_size)
    assert s["reprojection_error_pct"] == pytest.approx(float(pct.mean()), abs=0.01)


# -- single-database evaluation ----------------------------------------------------------------------
def test_single_database_report_has_both_variants_and_the_new_fields(small_db):
    config = EvalConfig(yaws_deg=(51.0,), scenarios=(Scenario("clean"), Scenario("pitched", pitch_deg=15.0)))
    report = evaluate(small_db, [SAMPLE_BVH / "005_01.bvh"], config)
    for sc in report["scenarios"]:
        assert sc["published"]["frames_with_output"] == sc["refined"]["frames_with_output"] > 0
        for variant in ("published", "refined"):
            _check_variant(sc[variant])
        assert sc["published"]["floor_mpjpe_cm"] == sc["refined"]["floor_mpjpe_cm"]
        assert math.isfinite(sc["mpjpe13_change_pct"])
    floors = [sc["published"]["floor_mpjpe_cm"] for sc in report["scenarios"]]
    assert floors[0] == floors[1]   # the floor does not depend on the camera's pitch


VARIANT_FIELDS = ("mpjpe_cm", "mpjpe13_cm", "pa_mpjpe_cm", "pa_mpjpe13_cm", "bone_error_cm", "frames_with_pop",
                  "accel_error_mm_per_frame2", "floor_mpjpe_cm", "engine_minus_floor_cm",
                  "frames_below_floor", "reprojection_error_pct", "reprojection_error_input_pct", "root_error_m",
                  "root_error_pct_distance", "engine_person_frames_per_s")


def _check_variant(v: dict) -> None:
    for key in VARIANT_FIELDS:
        assert isinstance(v[key], float) and math.isfinite(v[key]), (key, v[key])
    assert v["floor_mpjpe_cm"] > 0 and 0.0 <= v["frames_below_floor"] <= 1.0
    assert v["engine_minus_floor_cm"] == pytest.approx(v["mpjpe_cm"] - v["floor_mpjpe_cm"], abs=0.011)
    assert math.isfinite(v["yaw_error_deg"]["mean"])


# -- leave-one-subject-out ---------------------------------------------------------------------------
@pytest.mark.parametrize("name, subject, trial", [
    ("002_05.bvh", 2, 5), ("007_12.bvh", 7, 12), ("15_03.bvh", 15, 3), ("a/b/101_2.BVH", 101, 2),
    ("walk.bvh", None, None), ("abc_01.bvh", None, None), ("002.bvh", None, None)])
def test_subject_and_trial_from_file_names(name, subject, trial):
    assert subject_of(name) == subject
    assert trial_of(name) == trial


def test_files_without_a_subject_number_are_refused():
    assert group_by_subject([Path("005_01.bvh"), Path("002_01.bvh"), Path("002_10.bvh")]) == \
        {2: [Path("002_01.bvh"), Path("002_10.bvh")], 5: [Path("005_01.bvh")]}
    with pytest.raises(UsageError, match="walk.bvh"):
        group_by_subject([Path("002_01.bvh"), Path("walk.bvh")])


def test_leave_one_subject_out_end_to_end(tmp_path, monkeypatch):
    import tempfile

    import mocapdb.evaluation.loso as loso

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    built = []
    real_build = loso.build

    def recording_build(sources, out, config, **kw):
        built.append(sorted(Path(s).name for s in sources))
        return real_build(sources, out, config, **kw)

    monkeypatch.setattr(loso, "build", recording_build)
    files = [str(SAMPLE_BVH / n) for n in ("002_01.bvh", "005_01.bvh", "006_02.bvh")]
    config = LosoConfig.quick(max_frames=60, build=BuildConfig(clusters=20, landmarks=200, workers=1))
    report = leave_one_subject_out(files, config, log=lambda m: None)

    assert built == [["005_01.bvh", "006_02.bvh"], ["002_01.bvh", "006_02.bvh"], ["002_01.bvh", "005_01.bvh"]]
    assert list(tmp_path.iterdir()) == []                      # the fold databases are gone
    assert [f["subject"] for f in report["folds"]] == [2, 5, 6]
    for fold in report["folds"]:
        assert fold["database"]["files"] == 2 and fold["build_seconds"] > 0
        assert len(fold["clips"]) == 1 and fold["clips"][0]["frames"] <= 60
        assert fold["clips"][0]["yaws_deg"] == [6.0, 51.0]
        assert [s["scenario"]["name"] for s in fold["scenarios"]] == [s.name for s in config.eval.scenarios]
        for sc in fold["scenarios"]:
            for variant in ("published", "refined"):
                _check_variant(sc[variant])
            for lag in (0, 3, 6):   # the default stream beside the per-frame one, on the same frames
                assert sc[f"stream, lag {lag}"]["frames_with_output"] == sc["refined"]["frames_with_output"]
                assert np.isfinite(sc[f"stream, lag {lag}"]["mpjpe13_cm"])
    overall = report["overall"]["scenarios"]
    assert len(overall) == 2
    assert overall[0]["refined"]["frames_with_output"] == sum(f["scenarios"][0]["refined"]["frames_with_output"]
                                                              for f in report["folds"])
    table = format_table(report)
    assert "overall" in table and "total wall time" in table and table.count("\n") >= 10
    assert table.split("\n")[0].split()[7:11] == ["L0", "L3", "L6", "take"]


def test_leave_one_subject_out_needs_two_subjects_and_known_subjects():
    two = [str(SAMPLE_BVH / "002_01.bvh"), str(SAMPLE_BVH / "002_02.bvh")]
    with pytest.raises(UsageError, match="at least 2 subjects"):
        leave_one_subject_out(two, LosoConfig())
    with pytest.raises(UsageError, match=r"subject\(s\) \[9\]"):
        leave_one_subject_out([str(SAMPLE_BVH)], replace(LosoConfig(), subjects=(9,)))


def test_eval_command_line_checks(capsys):
    from mocapdb.cli.main import main

    assert main(["eval"]) == 2
    assert "--leave-one-subject-out" in capsys.readouterr().err
    assert main(["eval", "--leave-one-subject-out", str(SAMPLE_BVH), "--db", "x"]) == 2
    assert main(["eval", "--leave-one-subject-out", str(SAMPLE_BVH), "--subjects", "two"]) == 2


def test_eval_out_replaces_only_an_earlier_report(small_db_path, tmp_path, capsys):
    """``eval --out FILE``: written atomically, marked as a report; a later run replaces it, any other
    existing file is refused before any work and kept byte for byte."""
    import json

    from mocapdb.cli.main import main

    report = tmp_path / "report.json"
    args = ["eval", "--db", str(small_db_path), "--bvh", str(SAMPLE_BVH / "002_04.bvh"), "--quick"]
    assert main([*args, "--out", str(report)]) == 0
    assert main([*args, "--out", str(report)]) == 0   # its own earlier report: replaced
    assert json.loads(report.read_text())["format"] == "mocapdb-eval"
    capsys.readouterr()
    mine = tmp_path / "settings.json"
    mine.write_text('{"mine": true}\n')
    assert main([*args, "--out", str(mine)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{mine}: the output (--out) exists and is not a JSON report" in err, err
    assert mine.read_text() == '{"mine": true}\n'
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json", "settings.json"]   # no temporary file
