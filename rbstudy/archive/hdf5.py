"""The HDF5 library as rbstudy writes through it: one lock, and writers that survive a full disk.

HDF5 is not thread-safe: every netCDF4 or h5py call of the process holds `HDF5_LOCK`.
`netcdf_writer` and `hdf5_writer` open a file for writing and always close it, even when
HDF5 fails to flush it on a full disk (it then reports "HDF error", not ENOSPC): a file
left open would hold its handle and its blocks. `nearly_full` tells a full disk from the
free space, measured before the failed file is truncated.
"""

import contextlib
import errno
import os
import pathlib
import shutil
import threading
from collections.abc import Iterator
from typing import Any, Literal

import h5py
import netCDF4

__all__ = ["HDF5_LOCK", "hdf5_writer", "nearly_full", "netcdf_writer"]


# The HDF5 library under netCDF4 is not thread-safe: two threads writing files at once crash
# the process. Every netCDF access of this process goes through this lock (the archive is
# written by a thread of its own while the batches run; an archive or the step search's file
# may be read or written meanwhile).
HDF5_LOCK = threading.RLock()


# Closes of an HDF5 file whose flush met a full disk, once its temporary is truncated
# (`_close_or_truncate`): measured on a full tmpfs, the first fails and the second succeeds.
_CLOSE_ATTEMPTS = 3


# The files a full disk kept open even then (`_close_or_truncate`), closed at the next write.
_UNCLOSED: list[Any] = []


# Free bytes below which a failed write is put down to a full disk: HDF5 reports one as "HDF
# error" (a RuntimeError), "Disable slist on flush dest failure failed" or even "Permission
# denied", so the free space, not the error, tells.
_FULL_BYTES = 2**20


@contextlib.contextmanager
def netcdf_writer(
    temporary: str | os.PathLike[str], mode: Literal["w", "a"] = "w"
) -> Iterator[netCDF4.Dataset]:
    """``netCDF4.Dataset(temporary, mode)`` (NETCDF4) of a temporary file, closed on the way
    out even when a full disk fails its close (`_closed_on_exit`). Opening and closing take
    `HDF5_LOCK`; what the caller does in between takes it as it needs."""
    with HDF5_LOCK:
        _close_unclosed()
        nc = netCDF4.Dataset(temporary, mode, format="NETCDF4")
    with _closed_on_exit(nc, temporary, HDF5_LOCK):
        yield nc


@contextlib.contextmanager
def hdf5_writer(temporary: str | os.PathLike[str]) -> Iterator[h5py.File]:
    """``h5py.File(temporary, "r+")``, closed on the way out as `netcdf_writer` closes. h5py
    carries its own HDF5 library and lock: `HDF5_LOCK`, netCDF4's, is not taken."""
    _close_unclosed()
    handle = h5py.File(temporary, "r+")
    with _closed_on_exit(handle, temporary, contextlib.nullcontext()):
        yield handle


def nearly_full(path: str | os.PathLike[str]) -> bool:
    """Whether the file system of ``path`` (or of its nearest existing ancestor) has less
    than `_FULL_BYTES` free; one of no blocks at all (/proc, /sys) never is, nor one that
    cannot tell (it is asked while a write's error is handled: that error stays the one
    raised)."""
    place = pathlib.Path(path).absolute()
    while not place.is_dir():
        place = place.parent
    try:
        usage = shutil.disk_usage(place)
    except OSError:
        return False
    return usage.free < _FULL_BYTES and usage.total > 0


def _no_space(temporary):
    """The `OSError` (ENOSPC) of a write to ``temporary`` that failed on a nearly full disk:
    what the callers tell as the full disk, whatever HDF5 called the failure."""
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(temporary))


@contextlib.contextmanager
def _closed_on_exit(handle, temporary, lock):
    """Close ``handle`` of ``temporary`` on the way out (`_close_or_truncate`). When what was
    written failed, its error is the one raised, not the close's that follows it (HDF5 then
    fails to flush too), and an HDF5 error on a nearly full disk becomes ENOSPC: measured
    before the close truncates the temporary, which frees the space that told."""
    try:
        yield handle
    except (OSError, RuntimeError) as error:
        full = nearly_full(temporary)
        with contextlib.suppress(OSError, RuntimeError):
            _close_or_truncate(handle, temporary, lock)
        if full:
            raise _no_space(temporary) from error
        raise
    except BaseException:
        with contextlib.suppress(OSError, RuntimeError):
            _close_or_truncate(handle, temporary, lock)
        raise
    _close_or_truncate(handle, temporary, lock)


def _is_open(handle):
    """Whether a netCDF4 dataset or an h5py file is still open."""
    return handle.isopen() if isinstance(handle, netCDF4.Dataset) else bool(handle)


def _close_or_truncate(handle, temporary, lock):
    """Close ``handle`` (netCDF4 or h5py) of the file ``temporary``. HDF5 keeps a file it could
    not flush open, and every further close fails flushing it too: a long-lived process (a
    cluster's worker, a test) would hold the removed temporary's space after the user freed
    the disk. So the temporary, worthless by then, is truncated: its space lets HDF5 finish
    the close. An archive abandoned early (written beside its batches) may hold more cached
    chunks than truncating it frees: it is closed at the next write, once the user has freed
    the disk. A close that failed on a nearly full disk raises ENOSPC (`_no_space`)."""
    try:
        with lock:
            handle.close()
    except (OSError, RuntimeError) as error:
        full = nearly_full(temporary)  # before the truncation frees the space that tells
        os.truncate(temporary, 0)
        for _ in range(_CLOSE_ATTEMPTS):
            with contextlib.suppress(OSError, RuntimeError), lock:
                handle.close()
            if not _is_open(handle):
                break
        else:
            _UNCLOSED.append(handle)
        if full:
            raise _no_space(temporary) from error
        raise


def _close_unclosed():
    """Close what a full disk kept open (`_close_or_truncate`) where the disk now has room."""
    for handle in list(_UNCLOSED):
        with contextlib.suppress(OSError, RuntimeError), HDF5_LOCK:  # h5py's need it not: harmless
            handle.close()
        if not _is_open(handle):
            _UNCLOSED.remove(handle)
