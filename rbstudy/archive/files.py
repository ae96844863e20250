"""Files and folders of a study, written so that no reader ever sees half of one.

Every file is written under a temporary name beside its target (`temporary_beside`), synced
to disk, renamed, and its folder synced (`write_text_atomic`, `write_dataset_atomic`), with
Ctrl-C held off for the rename (`ctrl_c_held`). A folder that cannot be written, or a full
disk, is one line (`UnwritableFolder`, `unwritable`), checked before a sweep starts
(`check_output_folder`). `make_folders` and `remove_folders` make and remove only the folders
a sweep made; `inside` is the last guard of every file written or deleted under a folder.
"""

from __future__ import annotations

import errno
import os
import pathlib
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from rbstudy.archive.hdf5 import HDF5_LOCK, nearly_full
from rbstudy.errors import InputError, RbstudyError, one_line

if TYPE_CHECKING:
    import xarray as xr

__all__ = [
    "UnwritableFolder",
    "WRITE_REFUSALS",
    "check_output_folder",
    "ctrl_c_held",
    "inside",
    "make_folders",
    "remove_folders",
    "fsync_path",
    "replace_folder",
    "temporary_beside",
    "temporary_folder_beside",
    "unwritable",
    "write_dataset_atomic",
    "write_text_atomic",
]


# mkstemp and mkdtemp create files and folders their owner alone may read; results are meant
# to be shared.
_FILE_MODE = 0o644
_FOLDER_MODE = 0o755


# Attempts of `check_output_folder` and `make_folders` to write in a folder that a failed
# sweep, at the same instant, removes under them (each removes only the folders it made).
_CHECK_ATTEMPTS = 10


@contextmanager
def temporary_beside(path: str | os.PathLike[str]) -> Iterator[str]:
    """A temporary path in ``path``'s folder, renamed to ``path`` on success, removed on failure."""
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        os.close(handle)
    except OSError as error:
        raise unwritable(path.parent, error) from None
    try:
        yield temporary
        os.chmod(temporary, _FILE_MODE)
        fsync_path(temporary)  # the data on disk before the name points at it
        os.replace(temporary, path)
        fsync_path(path.parent)  # and the rename itself, so that a crash keeps one or the other
    except (OSError, RuntimeError) as error:
        _raise_if_full(path.parent, error)
        raise
    finally:
        if os.path.exists(temporary):
            os.remove(temporary)


@contextmanager
def temporary_folder_beside(path: str | os.PathLike[str]) -> Iterator[str]:
    """A temporary folder in ``path``'s folder, to fill (its files synced by the caller),
    then put in ``path``'s place on success (`replace_folder`), removed on failure."""
    path = pathlib.Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary = tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as error:
        raise unwritable(path.parent, error) from None
    try:
        yield temporary
        replace_folder(temporary, path)
    except (OSError, RuntimeError) as error:
        _raise_if_full(path.parent, error)
        raise
    finally:
        if os.path.exists(temporary):
            shutil.rmtree(temporary)


def replace_folder(source: str | os.PathLike[str], path: str | os.PathLike[str]) -> None:
    """Put the folder ``source`` (its files synced) in ``path``'s place, in the same file
    system. A folder cannot be renamed over one that holds files: the old one is first renamed
    aside and removed after, so a reader finds the old folder, the new one or, for an instant,
    none; never half of one."""
    path = pathlib.Path(path)
    os.chmod(source, _FOLDER_MODE)
    old = None
    try:
        with ctrl_c_held():
            if path.exists():
                old = tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".old.tmp")
                os.replace(path, old)
            os.replace(source, path)
            fsync_path(path.parent)
    finally:
        if old is not None and os.path.exists(old):
            shutil.rmtree(old)


# What a file system answers a write it refuses: read-only, immutable, not ours, full.
WRITE_REFUSALS = frozenset({errno.EROFS, errno.EPERM, errno.EACCES, errno.ENOSPC, errno.EDQUOT})


# What a file system answers a write that found no room: no blocks, or the user's quota spent.
_NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})


class UnwritableFolder(RbstudyError):
    """A folder whose file system refuses rbstudy's files (read-only, immutable, a path
    under a file, a system file system such as /proc)."""


def unwritable(folder: str | os.PathLike[str], error: OSError, label: str = "") -> UnwritableFolder:
    """The one-line error of ``folder`` refusing a write with the `OSError` ``error``:
    "no space left" (raised here) when its file system is (nearly) full, else an
    `UnwritableFolder` with the system's reason, to raise. ``label`` goes before the
    folder (``"--out "``)."""
    if error.errno != errno.EROFS:  # read-only media (an ISO image) report no free space
        _raise_if_full(folder, error)
    # a system file system (/proc) answers a new name with "No such file or directory"
    reason = (
        "its file system takes no new files"
        if error.errno == errno.ENOENT
        else error.strerror or one_line(error)
    )
    return UnwritableFolder(
        f"{label}{folder}: cannot write results there ({reason}); choose another folder with --out"
    )


def check_output_folder(folder: str | os.PathLike[str], label: str = "--out ") -> None:
    """Refuse ``folder``, in one line, when rbstudy could not write there: a path that is, or
    lies under, a file, or a folder whose file system refuses a new file (read-only,
    immutable, /proc) or one of its missing names (too long). Called before a command prints
    or computes anything. It touches no folder another command may share: the missing
    folders are made, with a file in the last, inside a private folder of the nearest one
    that exists, which it removes whole (`_probe_under`). A failed sweep that removes that
    nearest folder under the check at the same instant makes it look again."""
    folder = pathlib.Path(folder)
    for attempt in range(1, _CHECK_ATTEMPTS + 1):
        place, under = folder.absolute(), False
        while not place.exists():
            place, under = place.parent, True
        if not place.is_dir():
            what = "is a file" if not under else f"lies under the file {place}"
            raise UnwritableFolder(f"{label}{folder}: {what}, not a folder; choose another folder with --out")
        try:
            _probe_under(place, folder.absolute().relative_to(place))
            return
        except OSError as error:
            # the nearest folder gone under this check (or /proc, which takes no new name:
            # it fails each time)
            if error.errno != errno.ENOENT or attempt == _CHECK_ATTEMPTS:
                raise unwritable(folder, error, label) from None


def _probe_under(place, missing):
    """Make the relative path ``missing`` (``.``: none) and a file in it inside a new private
    folder of the existing folder ``place``, then remove that folder whole: raises the
    `OSError` a write of those names in ``place`` meets."""
    private = pathlib.Path(tempfile.mkdtemp(dir=place, prefix=".rbstudy-probe-"))
    try:
        deepest = private / missing
        deepest.mkdir(parents=True, exist_ok=True)
        handle, _ = tempfile.mkstemp(dir=deepest)
        os.close(handle)
    finally:
        shutil.rmtree(private, ignore_errors=True)


def make_folders(folder: str | os.PathLike[str]) -> list[pathlib.Path]:
    """Make ``folder`` and its missing parents; the folders this process made, outermost
    first (one that another process makes at the same instant is found, not made; one that a failed
    sweep that made it removes under it is made again). On a
    failure the folders it made are removed again."""
    made: list[pathlib.Path] = []
    attempt = 0
    while True:
        attempt += 1
        missing, place = [], pathlib.Path(folder)
        while not place.exists():
            missing.append(place)
            place = place.parent
        try:
            for path in reversed(missing):
                try:
                    path.mkdir()
                    made.append(path)
                except FileExistsError:
                    pass  # made by another: a file there fails the next mkdir, or the caller
            return made
        except OSError as error:
            if not isinstance(error, FileNotFoundError) or attempt == _CHECK_ATTEMPTS:
                remove_folders(made)
                raise


def remove_folders(made: list[pathlib.Path]) -> None:
    """Remove the folders `make_folders` made, innermost first, as long as they are empty:
    another command may be writing in them."""
    for path in reversed(made):
        try:
            path.rmdir()
        except OSError:
            return


def _raise_if_full(folder, error=None):
    """The one-line error of a full disk, when the write that failed with ``error`` said so
    (ENOSPC: `rbstudy.archive.hdf5` turns HDF5's errors on a nearly full disk into
    one, measured before the temporary was truncated) or the file system of ``folder`` (or
    of its nearest existing ancestor) is (nearly) full (`rbstudy.archive.hdf5.nearly_full`)."""
    if getattr(error, "errno", None) not in _NO_SPACE and not nearly_full(folder):
        return
    mount = pathlib.Path(folder).absolute()
    while not os.path.ismount(mount):
        mount = mount.parent
    raise RbstudyError(
        f"{folder}: no space left on the file system at {mount}; free space and "
        "rerun the same command (a sweep keeps its finished parts and resumes)"
    ) from None


def fsync_path(path: str | os.PathLike[str]) -> None:
    """fsync a file or a folder: a machine crash after a rename must not leave the new name
    on an empty or partial file (the rename can reach the disk before the data)."""
    handle = os.open(path, os.O_RDONLY)
    try:
        os.fsync(handle)
    finally:
        os.close(handle)


def inside(folder: str | os.PathLike[str], name: str) -> pathlib.Path:
    """``folder / name``, refused unless it resolves inside ``folder``: the last guard of
    every file a command names after what it read (a figure is named after the archive's
    study), whatever let such a name through."""
    folder = pathlib.Path(folder)
    path = folder / name
    if not path.resolve().is_relative_to(folder.resolve()):
        raise InputError(
            f"{name!r} would be written outside it, at {path.resolve()}",
            "a study name holds letters, digits, '-' and '_' only",
            str(folder),
        )
    return path


def write_text_atomic(text: str, path: str | os.PathLike[str]) -> None:
    """Write ``text`` to ``path`` through a temporary beside it (`temporary_beside`)."""
    with temporary_beside(path) as temporary:
        pathlib.Path(temporary).write_text(text)


def write_dataset_atomic(dataset: xr.Dataset, path: str | os.PathLike[str]) -> None:
    """Write an xarray ``dataset`` to the netCDF file ``path`` through a temporary beside it:
    a reader never sees half a file (the conformance scorecard, the step search's probes)."""
    with ctrl_c_held(), temporary_beside(path) as temporary, HDF5_LOCK:
        dataset.to_netcdf(temporary)


@contextmanager
def ctrl_c_held() -> Iterator[None]:
    """Hold a Ctrl-C until the block ends, then raise it: xarray's ``to_netcdf``,
    interrupted between taking its netCDF lock and releasing it, waits for that lock
    forever as it closes the file (a sweep --find-step, interrupted, hung so). Only the
    main thread receives Python's signals; elsewhere the block runs as it is."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught = []
    previous = signal.signal(signal.SIGINT, lambda number, frame: caught.append(number))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught and callable(previous):  # Python's own raises KeyboardInterrupt
        previous(signal.SIGINT, None)
