"""``gsp_bench``'s sections of this package (``main``: the console script), one module a
section; the core's sections are in :mod:`gsp_experiments`."""
