"""How the clustered search scales with the database: clusters K for N projections, clusters searched i for K.

The method (Yiannakides et al.): K = 500 k-means clusters over ~630,000 projections; a query scores every
cluster representative, then the members of the i = 5 nearest clusters (10 taken from each). A query costs
K + i × (members of a searched cluster) Eq. 1 distances, and the clusters a query lands in are the big ones
(about 4 × the mean N / K). Measured with ``tools/bench_search.py`` (docs/benchmarks.md, "Search at scale"; subject 7
held out, databases at 12°, 3.6° and 1.25° yaw steps, 0.58 M to 5.5 M projections):

* recall@1 against exact search depends on K and i, hardly on N (K 500, i 5: 0.988 clean / 0.954 noisy at
  0.58 M, 0.998 / 0.963 at 5.5 M), so with K fixed the members searched grow like N (5.5 M: 193,000
  distances per query, 9.5 × the 0.58 M database's);
* at one N, more and smaller clusters reach a recall with fewer distances, but need more of them searched:
  i ∝ K^0.45 keeps the recall (5.5 M, noisy recall@1 ~0.98: K 500 needs i 7 and 252,000 distances,
  K 4,401 i 20 and 85,000; clean and noisy at the rule's K 4,401 and i 13, with the runtime's grid descents:
  1.000 / 0.975 from 61,000 distances, against 0.995 / 0.973 from 20,000 at the paper's size).

Hence :func:`clusters_for`: the paper's cluster size, 1,260 projections per cluster (K 500 up to 630,000),
and :func:`clusters_searched_for`: 5 at K 500, growing as K^0.45. A core leaf: the runtime's default
``--clusters-searched`` is :func:`clusters_searched_for` of the database's K.

More clusters cost the build O(N·K) in k-means and the Eq. 1 assignment (``--clusters 4401`` took 1,900 s
at 5.5 M, K 500 212 s), so the builder keeps the method's K 500 and bounds the search one level down
instead: the search index cuts each cluster into :func:`subclusters_for` sub-clusters of the same 1,260
projections (O(Σ n_c² / 1,260) to build), and a query searches the few nearest of each searched cluster
(``runtime/search.py``, docs/benchmarks.md "Search at scale").
"""
from __future__ import annotations

PAPER_CLUSTERS = 500                   # K of the method
PAPER_CLUSTERS_SEARCHED = 5            # i of the method
PROJECTIONS_PER_CLUSTER = 1_260        # the method's ~630,000 projections / 500 clusters
SEARCHED_EXPONENT = 0.45               # i ∝ K^0.45 keeps recall@1 (fit on 5.5 M over K 500, 1,550, 4,600)


def clusters_for(n_projections: int) -> int:
    """Default K for a database of ``n_projections``: 500 up to 630,000 projections, then one cluster per
    1,260 (2 M: 1,587; 6 M: 4,762; 25 M: 19,841); never more than the projections."""
    return max(1, min(n_projections, max(PAPER_CLUSTERS, round(n_projections / PROJECTIONS_PER_CLUSTER))))


def subclusters_for(n_members: int) -> int:
    """Sub-clusters of a cluster of ``n_members`` projections in the search index: one per
    :data:`PROJECTIONS_PER_CLUSTER` (rounded up), so a cluster of the method's size stays whole."""
    return max(1, -(-n_members // PROJECTIONS_PER_CLUSTER))


def subclusters_searched_for(n_projections: int) -> int:
    """Default sub-clusters searched per cluster searched, for a database of ``n_projections``: 5 up to the
    method's 630,000, then ``5 · (N / 630,000)^0.25`` rounded (5.5 M: 9; 28 M: 13). Measured with
    ``tools/bench_search.py`` (docs/benchmarks.md "Search at scale"): noisy recall@1 0.973 at 0.58 M and
    0.98 at 28 M."""
    return max(PAPER_CLUSTERS_SEARCHED,
               round(PAPER_CLUSTERS_SEARCHED * (n_projections / (PAPER_CLUSTERS * PROJECTIONS_PER_CLUSTER)) ** 0.25))


def clusters_searched_for(n_clusters: int) -> int:
    """Default i for a database of ``n_clusters`` clusters: 5 at the method's 500 (and below), then
    ``5 · (K / 500)^0.45`` rounded (K 1,587: 8; 4,762: 14; 19,841: 26)."""
    ratio = max(n_clusters, PAPER_CLUSTERS) / PAPER_CLUSTERS
    return round(PAPER_CLUSTERS_SEARCHED * ratio ** SEARCHED_EXPONENT)
