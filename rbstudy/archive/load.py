"""Loading an archive as an xarray dataset.

`open_results` reads without decoding times (simulated time is plain seconds) and, for the
time series a reader only reduces (the findings' maxima), reduces them along time slab by
slab, so a million cases' findings never hold their whole series. `read_group` reads a
group stored beside the archive's dataset (the step search's).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Collection, Mapping
from typing import TYPE_CHECKING, Any

import netCDF4
import numpy as np

from rbstudy.archive.hdf5 import HDF5_LOCK
from rbstudy.archive.variables import VARIABLES
from rbstudy.archive.zarr_store import is_store

if TYPE_CHECKING:
    import xarray as xr

__all__ = ["open_results", "read_group"]


def open_results(
    path: str | os.PathLike[str],
    variables: Collection[str] | None = None,
    reduced: Mapping[str, str] | None = None,
) -> xr.Dataset:
    """Load an archive (a netCDF file of results, or a zarr store), ``time`` in seconds from the start of
    the run.

    ``variables`` (optional) loads only those data variables (and the coordinates): the
    summary of a large study needs its per-case scalars, not its trajectories. ``reduced``
    (optional, name -> ``"max"`` or ``"last"``) loads those time series of them reduced
    along ``time``, slab by slab: the largest sample (NaN where any is), or the last one
    (``time`` its scalar coordinate). A million cases' two series of 11 samples took 176 MB
    whole and twice that while read.
    """
    import xarray as xr  # here: a sweep's workers and its forecast never read a dataset

    skip = None if variables is None else [name for name in VARIABLES if name not in variables]
    # a zarr store (`rbstudy.archive.zarr_store`) needs no HDF5 lock, and has no consolidated
    # metadata to look for
    store = is_store(path)
    how: dict[str, Any] = {"engine": "zarr", "consolidated": False} if store else {}
    with (
        contextlib.nullcontext() if store else HDF5_LOCK,
        xr.open_dataset(path, decode_times=False, drop_variables=skip, **how) as dataset,
    ):
        series = {
            name: _reduced_along_time(dataset[name], how)
            for name, how in (reduced or {}).items()
            if name in dataset and "time" in dataset[name].dims
        }
        rest = dataset.drop_vars(list(series))
        if series and not any("time" in variable.dims for variable in rest.data_vars.values()):
            rest = rest.drop_vars("time")  # the last sample's time would collide with it
        return rest.load().assign(series)


# Bytes of a slab read at a time by `_reduced_along_time`.
_REDUCTION_SLAB_BYTES = 2**23


def _reduced_along_time(variable, how):
    """``variable`` (lazy) reduced along ``time``: ``"max"`` (NaN propagated) or ``"last"``."""
    if how == "last":
        return variable.isel(time=-1).load()
    if how != "max":
        raise ValueError(f"reduce along time by 'max' or 'last', not {how!r}")
    if not variable.ndim or variable.dims[0] == "time":
        return variable.max("time", skipna=False).load()
    per_position = variable.size // variable.shape[0] * variable.dtype.itemsize
    step = max(1, _REDUCTION_SLAB_BYTES // max(1, per_position))
    first = variable.dims[0]
    largest = np.concatenate(
        [
            variable.isel({first: slice(start, start + step)}).max("time", skipna=False).values
            for start in range(0, variable.shape[0], step)
        ]
    )
    return variable.isel(time=0, drop=True).copy(data=largest)


def read_group(path: str | os.PathLike[str], group: str) -> xr.Dataset | None:
    """The netCDF group ``group`` of the file at ``path`` as a loaded xarray dataset; None
    where the file has no such group (an archive without a step search) or is a zarr store."""
    import xarray as xr  # here, as in `open_results`

    if is_store(path):  # a zarr store holds no step search (`sweep --find-step` keeps netCDF)
        return None
    with HDF5_LOCK:  # the library is not thread-safe: one file at a time in a process
        with netCDF4.Dataset(path) as nc:
            if group not in nc.groups:
                return None
        return xr.load_dataset(path, group=group)
