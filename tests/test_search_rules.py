"""The rules that scale the clustered search with the database (mocapdb/core/search_rules.py)."""
import pytest

from mocapdb.core.domains import DomainError
from mocapdb.core.search_rules import clusters_for, clusters_searched_for, subclusters_for, subclusters_searched_for
from mocapdb.runtime.engine import Engine
from mocapdb.runtime.engine_config import EngineConfig


@pytest.mark.parametrize("projections, clusters", [(1, 1), (300, 300), (100_000, 500), (630_000, 500),
                                                   (2_000_000, 1_587), (6_000_000, 4_762), (25_000_000, 19_841)])
def test_clusters_grow_with_the_database_above_the_papers_size(projections, clusters):
    """K = 500 (the method's) up to 630,000 projections, then one cluster per 1,260, never more than the
    projections."""
    assert clusters_for(projections) == clusters


@pytest.mark.parametrize("clusters, searched", [(1, 5), (500, 5), (1_587, 8), (4_762, 14), (19_841, 26)])
def test_clusters_searched_grow_with_the_clusters(clusters, searched):
    """i = 5 (the method's) at K = 500 and below, then 5 · (K / 500)^0.45."""
    assert clusters_searched_for(clusters) == searched


@pytest.mark.parametrize("projections, searched", [(1, 5), (577_680, 5), (630_000, 5), (2_100_200, 7),
                                                   (5_545_728, 9), (27_728_640, 13)])
def test_subclusters_searched_grow_with_the_database(projections, searched):
    """5 per cluster searched up to the method's 630,000 projections, then 5 · (N / 630,000)^0.25."""
    assert subclusters_searched_for(projections) == searched


@pytest.mark.parametrize("members, subclusters", [(1, 1), (1_260, 1), (1_261, 2), (55_000, 44)])
def test_a_cluster_has_a_subcluster_per_1260_members(members, subclusters):
    assert subclusters_for(members) == subclusters


def test_rules_never_shrink():
    sizes = [10 ** e for e in range(1, 9)]
    for rule in (clusters_for, clusters_searched_for, subclusters_for, subclusters_searched_for):
        assert [rule(n) for n in sizes] == sorted(rule(n) for n in sizes)


def test_engine_searches_the_rules_clusters_unless_told(small_db):
    assert EngineConfig().n_clusters is None
    assert Engine(small_db).pipeline.n_clusters == clusters_searched_for(small_db.n_clusters)
    assert Engine(small_db, EngineConfig(n_clusters=7)).pipeline.n_clusters == 7
    assert Engine(small_db).pipeline.subclusters == subclusters_searched_for(small_db.n_projections)
    assert Engine(small_db, EngineConfig(subclusters=2)).pipeline.subclusters == 2


@pytest.mark.parametrize("field, value", [("n_clusters", 0), ("grid_descents", -1), ("grid_descents", 1001),
                                          ("grid_descents", 2.5), ("n_clusters", 10 ** 20), ("subclusters", 0)])
def test_search_options_outside_their_domains_are_refused(field, value):
    with pytest.raises(DomainError, match=field):
        EngineConfig(**{field: value})
