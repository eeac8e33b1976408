"""How the take's world (runtime/world/fuse.py) grows with the people and their contacts.

    python tools/bench_world.py

People walk 2 m across in front of one camera (1.5 m high, pitched 8 deg), each with N planted-ankle
contacts and, in the last column, the image's vertical planes of 256 frames
(``runtime/world/image_vertical.py``); the world is estimated with the camera height given and with
nothing given. Prints the milliseconds per estimate: it is O(T·H·P) for T tilts, H heights and P
people (contacts enter through at most 64 per person, planes through at most 256), so it grows
linearly with the people and not with the take's length.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mocapdb.core.skeleton import ANKLE_HEIGHT_M, UNIVERSAL_HEIGHT_M  # noqa: E402
from mocapdb.runtime.world.fuse import TrackEvidence, estimate_world  # noqa: E402
from mocapdb.runtime.world.image_vertical import MAX_PLANES  # noqa: E402

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


def with_planes(e: TrackEvidence, rng: np.random.Generator) -> TrackEvidence:
    """``e`` with the image's vertical planes of :data:`MAX_PLANES` frames: each through its up and a
    random direction, turned by up to 2 deg."""
    normals = np.cross(e.up, rng.normal(size=(MAX_PLANES, 3))) + rng.normal(0.0, 0.02, (MAX_PLANES, 3))
    return replace(e, vertical_planes=normals / np.linalg.norm(normals, axis=1, keepdims=True), vertical_sd_deg=2.0)


def milliseconds(evidence: list[TrackEvidence], camera_height_m: float | None) -> float:
    """One :func:`estimate_world` after a warm-up, in milliseconds."""
    estimate_world(evidence, camera_height_m)
    start = time.perf_counter()
    estimate_world(evidence, camera_height_m)
    return 1000.0 * (time.perf_counter() - start)


def main() -> None:
    rng = np.random.default_rng(0)
    print("| people | contacts each | camera height given (ms) | nothing given (ms) | nothing given, planes (ms) |")
    print("|---|---|---|---|---|")
    for people, contacts in ((1, 100), (3, 100), (3, 1000), (10, 100), (30, 100)):
        evidence = [person(i, rng.uniform(1.5, 1.9), rng.uniform(-3, 3), rng.uniform(4, 12), contacts, rng)
                    for i in range(people)]
        planes = [with_planes(e, rng) for e in evidence]
        print(f"| {people} | {contacts} | {milliseconds(evidence, CAMERA_HEIGHT_M):.0f} | "
              f"{milliseconds(evidence, None):.0f} | {milliseconds(planes, None):.0f} |")


if __name__ == "__main__":
    main()
