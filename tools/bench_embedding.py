"""Time landmark MDS and k-means on synthetic pose-like data at several database sizes.

Usage: ``python tools/bench_embedding.py [--n 300000 2000000] [--landmarks 2000] [--k 500]``.
First-call JIT compilation (or loading numba's cache) is timed separately on a tiny input.
Peak memory is the process's maximum resident set so far (``resource.getrusage``).
"""
from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from mocapdb.builder.kmeans import kmeans  # noqa: E402
from mocapdb.builder.landmark_mds import landmark_mds  # noqa: E402

# A standing skeleton in OpenPose order (head, neck, arms, legs): unit height, mid-hip at 0, y down.
BASE_POSE = np.array([
    [0.00, -0.50], [0.00, -0.38], [-0.12, -0.37], [-0.15, -0.20], [-0.16, -0.05],
    [0.12, -0.37], [0.15, -0.20], [0.16, -0.05], [-0.07, 0.00], [-0.08, 0.25],
    [-0.08, 0.50], [0.07, 0.00], [0.08, 0.25], [0.08, 0.50]], dtype=np.float32)
CLIP_FRAMES = 500   # frames per synthetic clip
MODES = 8           # random joint-displacement fields the clips move along


def synthetic_poses(n: int, seed: int) -> np.ndarray:
    """``[n, 14, 2]`` float32: the base skeleton plus smooth random perturbations.

    Each clip of ``CLIP_FRAMES`` frames moves along the ``MODES`` displacement fields with
    sinusoidal weights of random frequency and phase (earlier modes move more), plus a little
    per-frame jitter. Built clip by clip so memory stays at the output's size.
    """
    rng = np.random.default_rng(seed)
    fields = rng.normal(scale=0.08, size=(MODES, 14, 2)).astype(np.float32)
    out = np.empty((n, 14, 2), dtype=np.float32)
    frames = np.arange(CLIP_FRAMES)[:, None]
    for start in range(0, n, CLIP_FRAMES):
        clip = out[start:start + CLIP_FRAMES]
        freq, phase = rng.uniform(0.002, 0.05, MODES), rng.uniform(0.0, 2 * np.pi, MODES)
        weights = np.sin(freq * frames[:len(clip)] + phase) / np.sqrt(np.arange(1, MODES + 1))
        clip[:] = BASE_POSE + np.einsum("fm,mjc->fjc", weights, fields)
        clip += rng.normal(scale=0.005, size=clip.shape)
    return out


def peak_mb() -> float:
    """Peak resident memory of this process so far, MB (Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timed(fn, *args, **kwargs):
    start = time.perf_counter()
    result = fn(*args, **kwargs)
    return result, time.perf_counter() - start


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, nargs="+", default=[300_000, 2_000_000], help="database sizes")
    parser.add_argument("--landmarks", type=int, default=2000, help="MDS landmarks")
    parser.add_argument("--dims", type=int, default=5, help="embedding dimensions")
    parser.add_argument("--k", type=int, default=500, help="k-means clusters")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    tiny = synthetic_poses(600, args.seed)
    _, jit_mds = timed(landmark_mds, tiny, args.dims, 100, args.seed)
    _, jit_km = timed(kmeans, np.random.default_rng(args.seed).random((600, args.dims)), 10, args.seed)
    print(f"first-call JIT (compile or cache load): landmark_mds {jit_mds:.2f} s, kmeans {jit_km:.2f} s")

    print(f"{'N':>10} {'MDS s':>8} {'k-means s':>10} {'iters':>6} {'peak MB so far':>15}")
    rows = []
    for n in args.n:
        poses = synthetic_poses(n, args.seed)
        embedding, t_mds = timed(landmark_mds, poses, args.dims, args.landmarks, args.seed)
        iterations = []
        _, t_km = timed(kmeans, embedding, args.k, args.seed,
                        progress=lambda it, shift: iterations.append(it))
        rows.append((n, t_mds, t_km))
        print(f"{n:>10} {t_mds:>8.2f} {t_km:>10.2f} {len(iterations):>6} {peak_mb():>15.0f}", flush=True)
        del poses, embedding
    for (n0, m0, k0), (n1, m1, k1) in zip(rows, rows[1:]):
        print(f"growth {n0} → {n1} (×{n1 / n0:.2f} points): MDS ×{m1 / m0:.2f}, k-means ×{k1 / k0:.2f}")


if __name__ == "__main__":
    main()
