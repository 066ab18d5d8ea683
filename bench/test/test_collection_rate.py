"""The collection_rate section of the bench (:mod:`gsp_bench.collection_rate`)."""

import gsp_bench.collection_rate


def test_the_collection_rate_bench_collects_each_posture_from_cdr_bytes():
    """gsp_bench's collection_rate section feeds the collection as the node does; every posture
    it plans gives its row (its figure is a rate, not a test)."""
    assert gsp_bench.collection_rate.INTAKE == 'cdr'
    rows = []
    handled, _, count = gsp_bench.collection_rate.collect(10, 3, rows_out=rows)
    assert count == 3 and [row.posture for row in rows] == [1, 2, 3]
    assert handled > 3 * 4 * 10
