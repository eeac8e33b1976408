"""Blend shapes' smoothing (face_shapes.BlendSmoother): a blink of 120 ms at 30 fps still reaches 0.8, a
steady value is unchanged, the release follows exp(-dt/FALL_S) by hand, the weight follows the frames' times
(frame-rate aware), and NaN (no face) passes and restarts the filter."""
from __future__ import annotations

import math

import numpy as np
import pytest

from mocapdb.core.face_shapes import FALL_S, RISE_S, BlendSmoother


def _run(values: np.ndarray, times_s: np.ndarray) -> np.ndarray:
    smoother = BlendSmoother()
    return np.array([smoother(v, t) for v, t in zip(values, times_s)])


@pytest.mark.parametrize("fps", [25.0, 30.0])
@pytest.mark.parametrize("phase", [0.0, 0.3, 0.7])
def test_short_blink_survives(fps: float, phase: float) -> None:
    times = np.arange(60) / fps
    start = 1.0 + phase / fps
    blink = ((times >= start) & (times < start + 0.120)).astype(float)
    values = np.column_stack([blink, np.zeros_like(blink), np.full_like(blink, 0.3)])
    out = _run(values, times)
    assert out[:, 0].max() >= 0.8
    # the first closed frame by hand: 1 - exp(-dt / RISE_S)
    first = int(np.argmax(blink))
    assert out[first, 0] == pytest.approx(1.0 - math.exp(-1.0 / fps / RISE_S))
    # the eye reopens: one frame later its value by hand, and it is back near 0 within 0.3 s
    last = first + int(blink.sum())
    assert out[last, 0] == pytest.approx(out[last - 1, 0] * math.exp(-1.0 / fps / FALL_S))
    assert out[last + int(0.3 * fps), 0] < 0.01
    np.testing.assert_allclose(out[:, 1:], values[:, 1:])   # steady values unchanged


def test_frame_rate_aware() -> None:
    """The release seen at 15 and 60 fps falls by the same share in the same time: exp(-0.2 s / FALL_S) in 0.2 s."""
    slow, fast = np.arange(15), np.arange(60)   # frames of 1 s; the eye opens at 0.4 s
    out_slow = _run(np.where(slow >= 6, 0.0, 1.0)[:, None], slow / 15)
    out_fast = _run(np.where(fast >= 24, 0.0, 1.0)[:, None], fast / 60)
    expected = math.exp(-0.2 / FALL_S)
    assert out_slow[9, 0] / out_slow[6, 0] == pytest.approx(expected)
    assert out_fast[36, 0] / out_fast[24, 0] == pytest.approx(expected)


def test_absent_face_restarts() -> None:
    smoother = BlendSmoother()
    smoother(np.array([1.0]), 0.0)
    assert np.isnan(smoother(np.array([np.nan]), 0.033)[0])
    assert smoother(np.array([0.2]), 0.066)[0] == 0.2   # the face back: its value, not a fall from the old one
