"""The held-out renderer's simulated detector 3D (evaluation/heldout.detector_world) against the
engine's reading of world landmarks (runtime/world_prior.view_joints) and against its own SDs."""
import numpy as np
import pytest

from mocapdb.core.skeleton import KP
from mocapdb.evaluation.heldout import WORLD_ACROSS_SHARE, Scenario, detector_world, project, render
from mocapdb.runtime.world.detector_prior import view_joints


def _people(rng: np.random.Generator, frames: int) -> np.ndarray:
    """Camera-aligned joints ``[F, 15, 3]`` of a body-sized cloud 6 m away, off the optical axis."""
    return rng.normal(size=(frames, 15, 3)) * 0.4 + [1.0, -0.5, 6.0]


def test_error_free_landmarks_read_back_as_the_truth():
    """With no error the engine's reading of the simulated landmarks is the truth about the hips
    (within 1 cm: the engine turns them by the hips' pixel, the mid-point's projection's neighbour)."""
    rng = np.random.default_rng(0)
    cam = _people(rng, 6)
    world = detector_world(cam, 1e-12, np.zeros(6, dtype=bool), rng)
    px = project(cam[:, :14], 1000.0, (1920, 1080))
    for f in range(6):
        joints, _ = view_joints(world[f], px[f], np.full(14, 0.9), 1000.0, (960.0, 540.0))
        hips = 0.5 * (cam[f, KP["r_hip"]] + cam[f, KP["l_hip"]])
        np.testing.assert_allclose(joints[:14], (cam[f, :14] - hips) * [1.0, 1.0, -1.0], atol=0.01)


def test_errors_have_their_sd_along_and_across_the_ray_and_swap_with_the_keypoints():
    rng = np.random.default_rng(1)
    cam = np.repeat(_people(rng, 1), 4000, axis=0)      # one still pose: the errors alone move it
    exact = detector_world(cam, 1e-12, np.zeros(4000, dtype=bool), rng)
    error = detector_world(cam, 0.08, np.zeros(4000, dtype=bool), np.random.default_rng(2)) - exact
    assert error[..., 2].std() == pytest.approx(0.08, rel=0.15)
    assert error[..., :2].std() == pytest.approx(0.08 * WORLD_ACROSS_SHARE, rel=0.15)
    lag = np.corrcoef(error[1:, :, 2].ravel(), error[:-1, :, 2].ravel())[0, 1]
    assert 0.85 < lag < 0.97                            # slow: correlated over ~12 frames
    swapped = np.zeros(4000, dtype=bool)
    swapped[5] = True
    mirrored = detector_world(cam, 1e-12, swapped, rng)
    np.testing.assert_allclose(mirrored[5, KP["r_wrist"]], exact[5, KP["l_wrist"]], atol=1e-9)


def test_render_carries_landmarks_only_when_asked():
    rng = np.random.default_rng(3)
    cam = _people(rng, 3)
    assert all(f.people[0].world_m is None for f in render(cam, Scenario("2D"), 1000.0, (1920, 1080), rng))
    frames = render(cam, Scenario("3D", world_sd_m=0.05), 1000.0, (1920, 1080), rng)
    assert all(f.people[0].world_m.shape == (14, 3) for f in frames)
