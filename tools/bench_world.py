"""How the take's world (runtime/world.py) grows with the people and their contacts.

    python tools/bench_world.py

People walk 2 m across in front of one camera (1.5 m high, pitched 8 deg), each with N planted-ankle
contacts; the world is estimated with the camera height given and with nothing given. Prints the
milliseconds per estimate: it is O(T·H·P) for T tilts, H heights and P people (contacts enter
through at most 64 per person), so it grows linearly with the people and not with the take's length.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.skeleton import ANKLE_HEIGHT_M, UNIVERSAL_HEIGHT_M  # noqa: E402
from mocapdb.runtime.world import TrackEvidence, estimate_world  # noqa: E402

CAMERA_HEIGHT_M, PITCH_DEG = 1.5, 8.0


def person(track: int, stature_m: float, x_m: float, depth_m: float, contacts: int,
           rng: np.random.Generator) -> TrackEvidence:
    """A person walking 2 m across at ``depth_m``: its contacts at the nominal 1.75 m size."""
    t = np.radians(PITCH_DEG)
    up = np.array([0.0, np.cos(t), np.sin(t)])
    forward = np.cross(up, [1.0, 0.0, 0.0])
    across = np.cross(forward, up)
    along = np.linspace(-1.0, 1.0, contacts)[:, None] * across
    ankle = ANKLE_HEIGHT_M * stature_m / UNIVERSAL_HEIGHT_M
    true = along + x_m * across + depth_m * forward + (ankle - CAMERA_HEIGHT_M) * up
    nominal = (true + rng.normal(0.0, 0.02, true.shape)) * (UNIVERSAL_HEIGHT_M / stature_m)
    return TrackEvidence(track, UNIVERSAL_HEIGHT_M, nominal, up, 3.0)


def main() -> None:
    rng = np.random.default_rng(0)
    print("| people | contacts each | camera height given (ms) | nothing given (ms) |")
    print("|---|---|---|---|")
    for people, contacts in ((1, 100), (3, 100), (3, 1000), (10, 100), (30, 100)):
        evidence = [person(i, rng.uniform(1.5, 1.9), rng.uniform(-3, 3), rng.uniform(4, 12), contacts, rng)
                    for i in range(people)]
        times = []
        for height in (CAMERA_HEIGHT_M, None):
            estimate_world(evidence, height)  # warm
            start = time.perf_counter()
            estimate_world(evidence, height)
            times.append(1000.0 * (time.perf_counter() - start))
        print(f"| {people} | {contacts} | {times[0]:.0f} | {times[1]:.0f} |")


if __name__ == "__main__":
    main()
