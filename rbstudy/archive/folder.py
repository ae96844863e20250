"""The state of a study folder's archive and the step search's working file."""

import pathlib

import netCDF4

from rbstudy.archive.checksums import verify_archive
from rbstudy.archive.hdf5 import HDF5_LOCK
from rbstudy.archive.ids import batches_digest

__all__ = ["SEARCH_FILE", "archive_state", "search_path"]


SEARCH_FILE = pathlib.Path("search") / "steps.nc"


def search_path(archive):
    """The step search's working file beside the archive at ``archive`` (`SEARCH_FILE`)."""
    return pathlib.Path(archive).parent / SEARCH_FILE


def archive_state(path, study):
    """What the archive at ``path`` is to ``study``: ``("absent", [])``, ``("outdated", [])``
    (another config or code: its ``batches`` differ), ``("damaged", problems)`` (a variable
    no longer matches its checksum, `rbstudy.archive.checksums`) or ``("current", [])``:
    then a rerun has nothing to do."""
    if not pathlib.Path(path).exists():
        return "absent", []
    try:
        with HDF5_LOCK, netCDF4.Dataset(path) as nc:
            batches = nc.getncattr("batches")
    except (OSError, AttributeError, RuntimeError):
        return "damaged", ["it cannot be read as netCDF"]
    if batches != batches_digest(study.batches):
        return "outdated", []
    with HDF5_LOCK:
        problems = verify_archive(path).problems
    return ("damaged", list(problems)) if problems else ("current", [])
