"""The pipeline layer: study configs, the sweep grid, batches, execution under dask, the step
search, and the output variables bound to the functions that compute them (`formulas`).

`outputs`, `batch_data` and `batches` are numba-free; `config`, `grid` and `execute` know the schemes. The
study folder on disk is the archive layer's (`rbstudy.archive`). Importing this package loads
nothing.
"""
