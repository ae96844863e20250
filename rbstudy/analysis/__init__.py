"""The analysis layer: the per-scheme summary, figures and the HTML report, from archives only
(never the solver; numba is never imported), and `bench`, which times the kernels.

Importing this package loads nothing.
"""
