"""Search that scales with the database: recall@1 against exact search and µs per query, per method.

    python tools/bench_search.py /tmp/db06 /tmp/db2 /tmp/db6 [--heldout ../shared/data/cmu_bvh/007_*.bvh] [--graph]
                                 [--subclusters 1 2 3 5 8] [--descents 0 3] [--every 2]

Build the databases without the held-out subject (``mocapdb build ../shared/data/cmu_bvh --out /tmp/db06
--exclude '007_*'``, ``--yaw-step 3.6`` and ``1.25`` for ~2 M and ~6 M projections). Queries: the held-out
clips sampled as ``mocapdb eval --leave-one-subject-out`` does (8 clips × 240 frames, 2 yaws off the 12° grid,
varied bodies), rendered clean and with σ 5 px + 10 % dropout + 5 % left/right swaps (missing joints: Eq. 1
over the visible joints, each database pose renormalised over them), every ``--every``-th frame.

Methods: ``exact`` (brute force, the reference); ``clustered`` i × 10 on the database's own clusters searched
whole (the method: 5 × 10; i also the rule's for the database's K, ``mocapdb.core.search_rules``), and 5 × 10
searched in the j sub-clusters of each cluster nearest the query (the search index's second level, where its
clusters have several; ``--subclusters``), without and with the engine's default 3 grid descents
(``runtime/search.py``; ``--descents``; their few extra distances are not counted); with ``--graph``, hnswlib
(``pip install hnswlib``: L2 over the 28 normalised coordinates, M 16, ef_construction 100; missing joints
filled from the nearest representative) re-ranked with Eq. 1 at several ef.
recall@1: the share of queries whose best candidate is at the exact search's Eq. 1 distance (relative 1e-5:
equal-distance ties count as found). Candidates: Eq. 1 distances per query (representatives plus the members
of the clusters searched; for hnswlib the ef re-ranked, its L2 visits not counted).
µs: one query at a time, one thread, from Python (as the engine calls it); compare within one run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mocapdb.core.formats.database import MotionDatabase  # noqa: E402
from mocapdb.core.formats.database_reader import load_database  # noqa: E402
from mocapdb.core.geometry import normalize_pose_2d  # noqa: E402
from mocapdb.core.search_rules import PAPER_CLUSTERS_SEARCHED, clusters_searched_for  # noqa: E402
from mocapdb.evaluation.heldout import Scenario, camera_distance, camera_view, render, scenario_positions  # noqa: E402
from mocapdb.evaluation.loso import LOSO_SCENARIOS, LosoConfig, sample_truths  # noqa: E402
from mocapdb.evaluation.reconstruction import EvalConfig  # noqa: E402
from mocapdb.runtime.search import SearchIndex, search_clustered, search_exact, visible_distances  # noqa: E402

DEFAULT_HELDOUT = sorted((ROOT.parent / "shared" / "data" / "cmu_bvh").glob("007_*.bvh"))
SCENARIOS = (LOSO_SCENARIOS[0], LOSO_SCENARIOS[2])  # varied bodies: clean; σ 5 px + 10 % dropout + 5 % swaps
CLUSTERS_SEARCHED = (5, 7, 10, 20)
SUBCLUSTERS = (1, 2, 3, 5, 8)  # sub-clusters searched per cluster (databases whose clusters have several)
ALL_SUBS = 10**9               # every sub-cluster: the flat clusters of the method
DESCENTS = (0, 3)  # without grid descents, and the engine's default
GRAPH_EF = (32, 64, 128, 256)
CONFIDENCE = 0.3  # the engine's threshold for a visible joint


def heldout_queries(files: list[Path], scenario: Scenario, every: int) -> tuple[np.ndarray, np.ndarray]:
    """Normalised queries ``[Q, 14, 2]`` float32 and their visible joints ``[Q, 14]`` (≥ 6 each)."""
    config, rng = EvalConfig(), np.random.default_rng(0)
    queries, visible = [], []
    for i, truth in enumerate(sample_truths(files, LosoConfig())):
        for j, yaw in enumerate(truth.yaws_deg):
            positions, _ = scenario_positions(truth, scenario, i, j, config.seed)
            cam = camera_view(positions, yaw, scenario.camera_height_m, camera_distance(positions, yaw, config),
                              scenario.pitch_deg)
            for frame in render(cam, scenario, config.focal_px, config.image_size, rng)[::every]:
                person = frame.people[0]
                vis = person.confidence >= CONFIDENCE
                query, _, scale = normalize_pose_2d(person.points_px, vis)
                if vis.sum() >= 6 and scale > 0:
                    queries.append(query)
                    visible.append(vis)
    return np.array(queries, dtype=np.float32), np.array(visible)


def timed(search, queries: np.ndarray, visible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best Eq. 1 distance found ``[Q]`` and µs ``[Q]`` of ``search(query, visible) → (rows, distances)``."""
    search(queries[0], visible[0])  # compile
    best, us = np.empty(len(queries)), np.empty(len(queries))
    for n, (query, vis) in enumerate(zip(queries, visible)):
        start = time.perf_counter()
        _, dist = search(query, vis)
        us[n] = 1e6 * (time.perf_counter() - start)
        best[n] = dist.min() if len(dist) else np.inf
    return best, us


def clustered_candidates(index: SearchIndex, query: np.ndarray, vis: np.ndarray, n_clusters: int,
                         subclusters: int) -> int:
    """Eq. 1 distances the clustered search computes: every representative, then, of the ``n_clusters``
    nearest clusters, their sub-clusters' representatives (where they have more than ``n_clusters ×
    subclusters`` in all) and the members of the ``n_clusters × subclusters`` nearest sub-clusters."""
    rep = visible_distances(index.rep_x, index.rep_y, query, vis)
    clusters = index.rep_cluster[np.argsort(rep, kind="stable")[:n_clusters]]
    subs = np.concatenate([np.arange(index.cluster_subs[c], index.cluster_subs[c + 1]) for c in clusters])
    count = len(rep)
    if len(subs) > n_clusters * subclusters:
        sub = visible_distances(index.sub_x[:, subs], index.sub_y[:, subs], query, vis)
        subs, count = subs[np.argsort(sub, kind="stable")[:n_clusters * subclusters]], count + len(subs)
    return count + int(np.sum(index.sub_start[subs + 1] - index.sub_start[subs]))


class GraphSearch:
    """hnswlib over the normalised projections (L2), its candidates re-ranked with Eq. 1."""

    def __init__(self, db: MotionDatabase, index: SearchIndex):
        import hnswlib

        self.poses, self.index = db.keypoints_2d, index
        self.graph = hnswlib.Index(space="l2", dim=self.poses[0].size)
        self.graph.init_index(max_elements=len(self.poses), M=16, ef_construction=100, random_seed=0)
        start = time.perf_counter()
        self.graph.add_items(self.poses.reshape(len(self.poses), -1), np.arange(len(self.poses)), num_threads=2)
        self.build_s = time.perf_counter() - start

    def filled(self, query: np.ndarray, vis: np.ndarray) -> np.ndarray:
        """``query`` with its missing joints taken from the nearest representative (renormalised over the
        visible joints like the query), the whole then renormalised over all joints as the database is."""
        if vis.all():
            return query
        rep = visible_distances(self.index.rep_x, self.index.rep_y, query, vis)
        c = int(np.argmin(rep))
        nearest = np.stack([self.index.rep_x[:, c], self.index.rep_y[:, c]], axis=-1)
        nearest, _, _ = normalize_pose_2d(nearest, vis)
        return normalize_pose_2d(np.where(vis[:, None], query, nearest))[0].astype(np.float32)

    def search(self, query: np.ndarray, vis: np.ndarray, ef: int) -> tuple[np.ndarray, np.ndarray]:
        self.graph.set_ef(ef)
        labels, _ = self.graph.knn_query(self.filled(query, vis).reshape(1, -1), k=ef)
        rows = labels[0].astype(np.int64)
        cand = self.poses[rows]
        dist = visible_distances(np.ascontiguousarray(cand[..., 0].T), np.ascontiguousarray(cand[..., 1].T),
                                 query, vis)
        return rows, dist


def database_rows(db: MotionDatabase, queries: dict, graph: bool, subclusters: tuple = SUBCLUSTERS,
                  descents_tried: tuple = DESCENTS) -> list[tuple]:
    """Table rows ``(N, K, scenario, method, params, candidates, recall@1, µs p50, µs p99)`` of one database."""
    index = SearchIndex.from_database(db)
    n, k = db.n_projections, db.n_clusters
    searcher = GraphSearch(db, index) if graph else None
    if searcher is not None:
        print(f"hnswlib index of {n:,} projections built in {searcher.build_s:.0f} s", file=sys.stderr)
    rows = []
    for name, (q, v) in queries.items():
        exact, us = timed(lambda a, b: search_exact(index, a, b, 1), q, v)
        rows.append((n, k, name, "exact", "", n, 1.0, *np.percentile(us, [50, 99])))
        for i, j in [(i, ALL_SUBS) for i in sorted({*CLUSTERS_SEARCHED, clusters_searched_for(k)})] + [
                (PAPER_CLUSTERS_SEARCHED, j) for j in subclusters if np.diff(index.cluster_subs).max() > 1]:
            cand = np.mean([clustered_candidates(index, a, b, i, j) for a, b in zip(q, v)])
            for descents in descents_tried:
                best, us = timed(lambda a, b: search_clustered(index, a, b, i, 10, descents, j), q, v)
                params = f"{i}×10" + ("" if j == ALL_SUBS else f" in {j} sub-clusters") + (
                    f", {descents} descents" if descents else "")
                rows.append((n, k, name, "clustered", params, cand, _recall(best, exact), *np.percentile(us, [50, 99])))
        for ef in GRAPH_EF if searcher is not None else ():
            best, us = timed(lambda a, b: searcher.search(a, b, ef), q, v)
            rows.append((n, k, name, "hnswlib + Eq. 1", f"ef {ef}", ef, _recall(best, exact),
                         *np.percentile(us, [50, 99])))
    return rows


def _recall(best: np.ndarray, exact: np.ndarray) -> float:
    return float(np.mean(best <= exact * (1 + 1e-5) + 1e-7))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("databases", type=Path, nargs="+", help="databases built without the held-out clips")
    ap.add_argument("--heldout", type=Path, nargs="+", default=DEFAULT_HELDOUT, help="held-out BVH files")
    ap.add_argument("--every", type=int, default=2, help="query every n-th rendered frame (default 2)")
    ap.add_argument("--graph", action="store_true", help="also hnswlib re-ranked with Eq. 1 (pip install hnswlib)")
    ap.add_argument("--subclusters", type=int, nargs="+", default=SUBCLUSTERS,
                    help="sub-clusters searched per cluster, one row each (default 1 2 3 5 8)")
    ap.add_argument("--descents", type=int, nargs="+", default=DESCENTS,
                    help="grid descents, one row each (default 0 3)")
    args = ap.parse_args()
    queries = {s.name.removeprefix("varied bodies, "): heldout_queries(args.heldout, s, args.every) for s in SCENARIOS}
    print("| N | K | queries | method | params | candidates | recall@1 | µs p50 | µs p99 |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in args.databases:
        db = load_database(path, projections=args.graph)  # the poses from the search index, memory-mapped
        for n, k, name, method, params, cand, recall, p50, p99 in database_rows(db, queries, args.graph,
                                                                                args.subclusters, args.descents):
            print(f"| {n:,} | {k:,} | {name} ({len(queries[name][0])}) | {method} | {params} | {cand:,.0f} | "
                  f"{recall:.3f} | {p50:,.0f} | {p99:,.0f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
