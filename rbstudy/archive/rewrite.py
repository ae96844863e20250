"""Changing a sealed archive: a copy beside it, changed, and renamed over it.

A reader of the archive never sees it half changed: `refresh_description` (new global
attributes, the data untouched) and `put_group` (a group added and sealed with the archive's
checksums) both go through `_rewritten`.
"""

from __future__ import annotations

import os
import pathlib
import shutil
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rbstudy.archive.checksums import reseal_group
from rbstudy.archive.files import WRITE_REFUSALS, ctrl_c_held, temporary_beside, unwritable
from rbstudy.archive.hdf5 import HDF5_LOCK, hdf5_writer, netcdf_writer

if TYPE_CHECKING:
    import xarray as xr

__all__ = ["put_group", "refresh_description"]


def refresh_description(path: str | os.PathLike[str], attrs: Mapping[str, Any]) -> None:
    """Replace the global attributes of the archive at ``path`` (its title, config text and
    provenance) without touching its data: a changed title or comment needs no recomputation.
    Written through a copy and a rename, like every other write (`_rewritten`)."""
    with _rewritten(path) as temporary, netcdf_writer(temporary, "a") as nc:
        nc.setncatts(attrs)


@contextmanager
def _rewritten(path: str | os.PathLike[str]) -> Iterator[str]:
    """A copy of the archive at ``path`` under a temporary name beside it, to change, then
    renamed over it (under `HDF5_LOCK`, a Ctrl-C held till then): a file system that refuses
    the copy or the rename (read-only, immutable, full) is one line naming the folder."""
    try:
        with ctrl_c_held(), temporary_beside(path) as temporary, HDF5_LOCK:
            shutil.copyfile(path, temporary)
            yield temporary
    except OSError as error:
        if error.errno in WRITE_REFUSALS:
            raise unwritable(pathlib.Path(path).parent, error) from None
        raise


def put_group(path: str | os.PathLike[str], group: str, dataset: xr.Dataset) -> None:
    """Put the xarray ``dataset`` into the sealed archive at ``path`` as its netCDF group
    ``group`` (replacing one of that name), sealed with the archive's own checksums
    (`rbstudy.archive.checksums.reseal_group`): the step search's probes travel in the
    archive, and ``verify`` proves them. Written through a copy and a rename (`_rewritten`)."""
    with _rewritten(path) as temporary:
        with hdf5_writer(temporary) as h5file:
            if group in h5file:  # netCDF4 cannot remove a group; HDF5 unlinks it
                del h5file[group]
        dataset.to_netcdf(temporary, mode="a", group=group)
        with netcdf_writer(temporary, "a") as nc:
            reseal_group(nc, group)
