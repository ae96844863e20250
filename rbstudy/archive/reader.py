"""Opening an archive for reading: the one door of every command that reads one (``plot``,
``report``, ``verify``, ``conformance`` and the summary a sweep prints).

An archive is input like a config. It may be damaged (a bit flipped on a disk, a value edited
by hand, a block zeroed), not rbstudy's (a YAML file, another tool's netCDF, one with the
right names but other shapes), or crafted (a ``study`` attribute of ``../../escaped``, which
names the figure files). `open_archive` checks, in this order, that the file is netCDF, that
it has the layout the summary, the figures and the report read (`check_layout`), and unless
told not to that every variable matches its checksum (`rbstudy.archive.checksums`). A zarr
store (``<study>.zarr``, `rbstudy.archive.zarr_store`) is read through the same checks, its
root group seen as a netCDF dataset (`open_header`) and its chunks proven by their checksums
(`rbstudy.archive.zarr_integrity`). Each
failure is one `InputError` naming the file, the attribute or variable, and the fix; a
netCDF or HDF5 error while reading becomes "damaged", never a traceback.
"""

from __future__ import annotations

import contextlib
import errno
import os
import pathlib
from collections.abc import Collection, Mapping
from typing import TYPE_CHECKING, Any

import netCDF4
import numpy as np

from rbstudy.archive.checksums import verify_archive
from rbstudy.archive.hdf5 import HDF5_LOCK
from rbstudy.archive.layout import is_part
from rbstudy.archive.load import open_results
from rbstudy.archive.parts import PART_SUFFIX, part_digest, sidecar
from rbstudy.archive.variables import BOOKKEEPING, VARIABLES
from rbstudy.archive.zarr_integrity import verify_store
from rbstudy.archive.zarr_store import is_store, open_header
from rbstudy.errors import InputError, one_line
from rbstudy.inputs.reader import FOLDER_NAME_RULE, NotARegularFile, is_folder_name, open_regular_file

if TYPE_CHECKING:
    import xarray as xr

__all__ = ["open_archive", "check_layout", "verify_file", "NOT_AN_ARCHIVE", "GIVE_AN_ARCHIVE"]

NOT_AN_ARCHIVE = "not an rbstudy archive"
GIVE_AN_ARCHIVE = "give the <study>.nc (or <study>.zarr) written by rbstudy sweep"
_REBUILD = "rerun its sweep (rbstudy sweep <config>): a damaged archive is rebuilt"
# The first bytes of a netCDF file: classic, 64-bit offset, 64-bit data, netCDF-4 (HDF5).
_SIGNATURES = (b"CDF\x01", b"CDF\x02", b"CDF\x05", b"\x89HDF\r\n\x1a\n")
# A part file's first bytes (a zip archive, numpy's .npz), and what is said of one.
_PART_SIGNATURE = b"PK\x03\x04"
_IS_A_PART = "is one batch's part file, not a study's archive"
_GIVE_THE_ARCHIVE = "give the <study>.nc written beside parts/"
# How much of a file is read to tell netCDF, text and other bytes apart.
_HEAD_BYTES = 512
# The coordinates every archive has, as a swept dimension or a single value, and the type of
# their values (numpy's dtype kinds, "O" for netCDF strings): the summary picks rows by them.
_CASE_COORDINATES = {"scheme": "O", "dt": "f"}
_KIND_NAMES = {"O": "text", "f": "numbers"}
# Variables named in an error that lists what a foreign file holds.
_SHOWN = 6


def _kind(variable):
    return "O" if variable.dtype is str else np.dtype(variable.dtype).kind


def _type_name(variable):
    return "text" if variable.dtype is str else np.dtype(variable.dtype).name


def _foreign(path, key, what):
    return InputError(f"{NOT_AN_ARCHIVE}: {what}", GIVE_AN_ARCHIVE, str(path), key)


def _head(path):
    """The first bytes of the file at ``path``, after refusing a missing or unreadable path
    and one that is no regular file (a folder, a FIFO, a device: never opened to wait or to
    read forever), saying which it is."""
    if not str(path):  # an unset shell variable: the line must still show what was given
        raise InputError("an empty path names no file", GIVE_AN_ARCHIVE, "''")
    try:
        with open_regular_file(path) as handle:
            return handle.read(_HEAD_BYTES)
    except NotARegularFile as error:
        raise _foreign(path, None, f"{error.kind}, not a file") from None
    except OSError as error:
        said = "no such file" if error.errno == errno.ENOENT else f"cannot read it: {error.strerror}"
        raise InputError(said, GIVE_AN_ARCHIVE, str(path)) from None


def _check_netcdf(path):
    """Refuse what `_head` refuses, and a file that is not netCDF at all (text, YAML, an
    image), saying which it is: a non-archive, never a damaged archive."""
    head = _head(path)
    if head.startswith(_PART_SIGNATURE) and pathlib.PurePath(path).suffix == PART_SUFFIX:
        raise InputError(_IS_A_PART, _GIVE_THE_ARCHIVE, str(path))
    if not head.startswith(_SIGNATURES):
        raise _foreign(path, None, f"not a netCDF file{_kind_of_file(head)}")


def _kind_of_file(head):
    """`` (an empty file)`` or `` (a text file)`` from a file's first bytes ``head``; ''
    for other bytes."""
    if not head:
        return " (an empty file)"
    # a character cut at the end of the head is no sign of bytes that are not text
    text = b"\0" not in head and not head.decode("utf-8", "replace")[:-1].count("\ufffd")
    return " (a text file)" if text else ""


def _layout_problem(path, nc):
    """The first way the open netCDF4 dataset ``nc`` differs from an archive's layout, as
    an `InputError`; None when it has it."""
    attributes = nc.ncattrs()
    if is_part(attributes, nc.dimensions):  # as earlier versions wrote parts
        return InputError(_IS_A_PART, _GIVE_THE_ARCHIVE, str(path))
    if "study" not in attributes:
        held = ", ".join(list(nc.variables)[:_SHOWN]) or "no variables"
        return _foreign(path, None, f"no study attribute; it holds {held}")
    study = nc.getncattr("study")
    if not is_folder_name(study):  # it names the figure files: the config's rule
        return _foreign(
            path, "study", f"the study attribute {study!r:.80} is not a study name ({FOLDER_NAME_RULE})"
        )
    missing = [name for name in (*BOOKKEEPING, *_CASE_COORDINATES) if name not in nc.variables]
    if missing:
        written_by = nc.getncattr("source") if "source" in attributes else "an unknown writer"
        return InputError(
            f"{NOT_AN_ARCHIVE}: it lacks {', '.join(missing)} (written by {written_by})",
            "rerun its sweep with this rbstudy (--force) to rebuild it",
            str(path),
        )
    grid = nc["status"].dimensions
    for name, kind in _CASE_COORDINATES.items():
        variable = nc[name]
        swept = name in grid
        if variable.dimensions != ((name,) if swept else ()):
            wanted = f"({name})" if swept else f"a single value (swept: {', '.join(grid) or 'none'})"
            return _foreign(path, name, f"{name} lies along ({', '.join(variable.dimensions)}), not {wanted}")
        if _kind(variable) != kind:
            return _foreign(path, name, f"{name} holds {_type_name(variable)}, not {_KIND_NAMES[kind]}")
    for name, variable in nc.variables.items():
        if name not in VARIABLES:
            continue
        own = VARIABLES[name].dims
        expected = (*grid, *own)
        leading = variable.dimensions[: len(variable.dimensions) - len(own)]
        # a variable of the scene alone lies along the dimensions its scene changes along
        # (along all of them in archives of rbstudy 0.3)
        scene_grid = (
            VARIABLES[name].per_scene
            and variable.dimensions[len(leading) :] == own
            and _in_order(leading, grid)
        )
        if variable.dimensions != expected and not scene_grid:
            wanted = ", ".join(expected) + (" or some of the first" if VARIABLES[name].per_scene else "")
            return _foreign(
                path, name, f"{name} lies along ({', '.join(variable.dimensions)}), not ({wanted})"
            )
        if _kind(variable) != np.dtype(VARIABLES[name].dtype).kind:
            return _foreign(
                path, name, f"{name} holds {_type_name(variable)}, not {np.dtype(VARIABLES[name].dtype).name}"
            )
    return None


def _content_problem(path, nc):
    """The first value of the open archive ``nc`` (of an archive's layout) that rbstudy never
    writes, as an `InputError`; None when there is none. Its checksums may match (a file
    sealed anew after an edit): the summary would otherwise print wrong words (a status of
    -1 read as the last, "not_converged") or fail on them. Reads the flags, a byte a case."""
    for dim in (*nc["status"].dimensions, "time"):
        if dim in nc.dimensions and not len(nc.dimensions[dim]):
            held = "no output times" if dim == "time" else "no cases"
            return _foreign(path, dim, f"it holds {held} ({dim} has length 0)")
    if "accuracy_bound" in nc.ncattrs():
        bound = np.asarray(nc.getncattr("accuracy_bound"))
        if bound.dtype.kind not in "iuf" or bound.size != 1 or not np.isfinite(bound).all() or bound <= 0:
            return _foreign(
                path,
                "accuracy_bound",
                f"the accuracy_bound attribute holds {bound.tolist()!r:.80}, not a number above 0",
            )
    nc.set_auto_maskandscale(False)
    for name, variable in nc.variables.items():
        flags = VARIABLES[name].flags if name in VARIABLES else ()
        if not flags:
            continue
        values = np.asarray(variable[...])
        odd = values[(values < 0) | (values >= len(flags))]
        if odd.size:
            codes = ", ".join(f"{code} ({flag})" for code, flag in enumerate(flags))
            return _foreign(path, name, f"{name} holds {odd.flat[0]}; its values are {codes}")
    return None


def _in_order(names, grid):
    """Whether ``names`` are some of ``grid``'s, in its order."""
    rest = iter(grid)
    return all(name in rest for name in names)


def check_layout(path: str | os.PathLike[str]) -> int:
    """Refuse the file at ``path`` unless it is netCDF with an archive's layout: the study
    attribute (a study name), the bookkeeping variables and the ``scheme`` and ``dt``
    coordinates, and every output variable along the swept dimensions (a variable of the
    scene alone: some of them) then its own, of its type; then that it holds cases and
    output times, an accuracy bound that is a number above 0, and only the codes of each
    flag (`_content_problem`). Reads the file's header and its flags; returns the number of
    cases it holds. A zarr store is checked alike."""
    failures: tuple[type[Exception], ...]
    if is_store(path):  # zarr raises what a damaged store's JSON or chunks make it raise
        opened, kind, failures = (
            open_header(path),
            "a zarr store",
            (OSError, RuntimeError, ValueError, KeyError, TypeError),
        )
    else:
        _check_netcdf(path)
        opened, kind, failures = _netcdf_header(path), "netCDF", (OSError, RuntimeError)
    try:
        with opened as header:
            problem = _layout_problem(path, header) or _content_problem(path, header)
            cases = 0 if problem else int(header["status"].size)
    except failures as error:
        raise InputError(
            f"damaged: it cannot be read as {kind} ({one_line(error)})", _REBUILD, str(path)
        ) from None
    if problem is not None:
        raise problem
    return cases


@contextlib.contextmanager
def _netcdf_header(path):
    """The netCDF file at ``path`` open for reading, under the HDF5 lock."""
    with HDF5_LOCK, netCDF4.Dataset(path) as nc:
        yield nc


def _verified(path, bypass=None):
    """The `ArchiveCheck` of an intact archive at ``path``; an `InputError` naming the first
    problems (and ``bypass``, how a caller reads it anyway) when it is not."""
    if is_store(path):
        check = verify_store(path)
    else:
        with HDF5_LOCK:
            check = verify_archive(path)
    if not check.problems:
        return check
    problems = check.problems
    shown = "; ".join(problems[:3]) + (f"; and {len(problems) - 3} more" if len(problems) > 3 else "")
    fix = "rerun its sweep with this rbstudy" if not check.provable else _REBUILD
    fix += f", or {bypass}" if bypass else ""
    if not check.provable:
        raise InputError(f"cannot be proven intact: {shown}", fix, str(path))
    raise InputError(f"damaged: {shown}", fix, str(path))


def open_archive(
    path: str | os.PathLike[str],
    variables: Collection[str] | None = None,
    verify: bool = True,
    reduced: Mapping[str, str] | None = None,
    progress: Any = None,
) -> xr.Dataset:
    """The archive at ``path`` as a loaded xarray dataset (`rbstudy.archive.load.open_results`:
    ``variables`` only, when given, and the time series of ``reduced`` reduced along time),
    after `check_layout` and, when ``verify``, after proving every variable intact by its
    checksum; each step a phase of ``progress`` (a `rbstudy.pipeline.progress.Progress`, or
    None: nothing shown) once the layout is known to be an archive's."""
    cases = check_layout(path)
    name = pathlib.PurePath(path).name
    if verify:
        if progress is not None:
            progress.phase(f"{name}: checking its checksums")
        _verified(path, bypass="give --no-verify to read it as it is")
    if progress is not None:
        progress.phase(f"{name}: reading its {cases} case{'s' * (cases != 1)}")
    try:
        return open_results(path, variables, reduced)
    except (OSError, RuntimeError, ValueError) as error:  # HDF5 reading a zeroed block
        raise InputError(f"damaged: it cannot be read ({one_line(error)})", _REBUILD, str(path)) from None


def verify_file(path: str | os.PathLike[str]) -> str:
    """What ``rbstudy verify`` says of ``path`` when it is intact (an archive, or a part with
    its digest beside it, or a zarr store); an `InputError` naming the first problems when it
    is not."""
    if is_store(path):
        check_layout(path)
        check = _verified(path)
        return (
            f"intact ({check.variables} variables match their chunks' SHA-256 checksums; "
            f"built from {check.parts} parts)"
        )
    _head(path)  # a file, before its digest's name is made from its name ("." has none)
    digest = sidecar(path)
    if digest.exists():
        try:  # a folder, a FIFO or /dev/zero there is not a digest that does not match
            open_regular_file(digest).close()
        except OSError as error:
            raise InputError(
                f"cannot read its digest {digest.name}: {error.strerror}",
                "remove it and rerun its sweep: the part is recomputed",
                str(path),
            ) from None
        if part_digest(path) is None:
            raise InputError(
                "damaged: its bytes do not match the digest stored beside it",
                "rerun its sweep: the part is recomputed",
                str(path),
            )
        return "intact (a part; its bytes match its digest)"
    check_layout(path)
    check = _verified(path)
    return (
        f"intact ({check.variables} variables match their SHA-256 checksums; built from {check.parts} parts)"
    )
