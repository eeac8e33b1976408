"""The online root filter against the whole take's batch least squares (one model, two solvers)."""
import numpy as np

from mocapdb.runtime.root_filter import RESTART_GAP_S, RootFilter
from mocapdb.runtime.take import fit_root_path
from mocapdb.runtime.take_params import TakeParams

FPS = 60.0


def _walk(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A root walking away from the camera while swaying (view frame: z towards the camera), and its
    measurements: 1 cm noise across the ray, 15 cm along it (the model's own)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FPS
    truth = np.stack([0.3 * np.sin(2 * t), 0.1 * np.cos(3 * t), -4.0 - 0.5 * t], axis=1)
    ray = truth / np.linalg.norm(truth, axis=1, keepdims=True)
    measured = truth + rng.normal(0, 0.01, (n, 3)) + ray * rng.normal(0, 0.15, (n, 1))
    return truth, measured


def _batch_last(measured: np.ndarray) -> np.ndarray:
    n = len(measured)
    path, _ = fit_root_path(measured, np.zeros((n, 2, 3)), np.zeros((n, 2), dtype=bool), FPS, TakeParams())
    return path[-1]


def test_each_estimate_is_the_last_frame_of_the_batch_path_so_far():
    _, measured = _walk(90)
    root_filter = RootFilter(FPS)
    filtered = np.array([root_filter(i, measured[i]) for i in range(len(measured))])
    for t in (10, 30, 60, 89):   # the batch knows no first velocity: the filter's 2 m/s SD has faded by then
        assert np.linalg.norm(filtered[t] - _batch_last(measured[:t + 1])) < 0.005


def test_it_calms_the_depth_and_keeps_the_path():
    truth, measured = _walk(240, seed=1)
    root_filter = RootFilter(FPS)
    filtered = np.array([root_filter(i, measured[i]) for i in range(len(measured))])
    error_in = np.linalg.norm(measured - truth, axis=1)[60:].mean()
    error_out = np.linalg.norm(filtered - truth, axis=1)[60:].mean()
    assert error_out < 0.5 * error_in
    across = np.abs(filtered[60:, :2] - truth[60:, :2]).mean()
    assert across < 0.02      # the image's precise direction is kept


def test_a_pop_pulls_no_harder_than_the_gate():
    _, measured = _walk(120, seed=2)
    popped = measured.copy()
    popped[80] += [0.0, 0.0, 3.0]     # a 3 m depth pop for one frame
    clean, gated = RootFilter(FPS), RootFilter(FPS)
    a = np.array([clean(i, measured[i]) for i in range(120)])
    b = np.array([gated(i, popped[i]) for i in range(120)])
    ungated_pull = 3.0 * 0.12       # about the steady position gain × the pop, had it been taken at face value
    assert np.linalg.norm(b[80] - a[80]) < 0.5 * ungated_pull


def test_a_gap_restarts_the_path_at_the_new_measurement():
    root_filter = RootFilter(FPS)
    for i in range(20):
        root_filter(i, np.array([0.0, 0.0, -3.0]))
    later = int(20 + RESTART_GAP_S * FPS + 2)
    assert np.allclose(root_filter(later, np.array([1.0, 0.0, -5.0])), [1.0, 0.0, -5.0])


def test_a_non_finite_root_leaves_the_state_as_it_was():
    _, measured = _walk(60, seed=3)
    clean, poked = RootFilter(FPS), RootFilter(FPS)
    a = [clean(i, measured[i]) for i in range(60) if i != 30]
    b = [poked(i, measured[i]) if i != 30 else poked(i, np.array([np.nan, 0.0, -4.0])) for i in range(60)]
    assert not np.isfinite(b[30]).all()
    assert np.allclose(np.array(a), np.array(b[:30] + b[31:]))
