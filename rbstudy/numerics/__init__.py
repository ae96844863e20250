"""The numerics layer: state layout, formulas, rotation kernels, dynamics, the batch driver,
numba set-up.

Plain float64 arrays with a leading batch axis ``B``; imports numpy and numba only (no files,
configs, xarray, dask, yaml or matplotlib). Importing this package loads nothing: `state` and
`algebra` are numba-free, so that the layers above may read the layout and the formulas
without compiling anything.
"""
