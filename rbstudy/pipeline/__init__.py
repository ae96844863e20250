"""The pipeline layer: study configs, the sweep grid, batches, execution under dask, storage,
and the table of output variables bound to the functions that compute them.

`variables`, `outputs` and `store` are numba-free (the analysis layer reads archives through
them); `config`, `grid`, `batches` and `execute` know the schemes. Importing this package
loads nothing.
"""
