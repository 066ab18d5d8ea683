"""The benchmark (``make bench``: ``python -m gsp_bench``) and the paper's reproduction
(``make paper``: ``python -m gsp_bench.paper_cli``): experiments on the installed packages, kept
out of them (no node package imports this folder).

One module a ``bench.json`` section (its key, e.g. :mod:`~gsp_bench.verdict`,
:mod:`~gsp_bench.physics`); :mod:`~gsp_bench.core` runs them and adds the core's own sections;
:mod:`~gsp_bench.paper` with :mod:`~gsp_bench.tables` (the paper's tables, ``data/tables.yaml``)
and :mod:`~gsp_bench.nominal_sets` reproduce the paper.
"""
