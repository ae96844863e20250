"""Checksums that prove a stored result is the one that was computed.

Two kinds of file, two kinds of proof:

* **A part file** (``parts/<batch>.nc``) is an intermediate that only rbstudy reads. Its
  whole byte content is hashed (SHA-256) when it is written, and the digest is kept beside it
  in ``<batch>.nc.sha256``. A part is reused only when its bytes still hash to that digest:
  a truncated, zeroed, overwritten, edited or swapped file never is, wherever the damage lies
  (data, attributes, the HDF5 structure, or garbage after its end).
* **The archive** (``<study>.nc``) travels alone, so it carries its own proof, in the netCDF
  group `GROUP` (out of the global attributes a user reads: ``xr.open_dataset`` of the file
  does not show it): its attribute ``checksums`` holds one SHA-256 per variable, of its type,
  shape, attributes and stored values (fill values included, nothing decoded), and
  ``part_checksums`` the digest of every part it was built from. `verify_archive`
  recomputes the first and checks that the second names exactly the study's batches (its
  ``batches`` attribute). Archives of rbstudy 0.3 hold the two as global attributes, and
  are proven the same way. A group added to a sealed archive (the step search's ``search``)
  is sealed with it: ``<group>/<variable>`` per variable and ``<group>/`` + `MEANING` for
  its attributes, in the same ``checksums`` (`reseal_group`).

The global attributes (title, history, config text) are not in the per-variable checksums:
a changed title is redescribed in place without touching the data (`store.refresh_description`).
"""

import contextlib
import errno
import hashlib
import json
import os
import pathlib
import shutil
import threading
from dataclasses import dataclass

import h5py
import netCDF4
import numpy as np

from rbstudy.errors import one_line
from rbstudy.inputs.reader import open_regular_file
from rbstudy.pipeline.batches import ids_digest

__all__ = [
    "file_digest",
    "is_part",
    "sidecar",
    "sidecar_text",
    "sealed",
    "part_digest",
    "archive_checksums",
    "group_checksums",
    "reseal_group",
    "seal_archive",
    "ArchiveCheck",
    "verify_archive",
    "SIDECAR_SUFFIX",
    "ALGORITHM",
    "hdf5_writer",
    "netcdf_writer",
    "GROUP",
    "SEALS",
    "HDF5_LOCK",
    "StreamedChecksum",
    "nearly_full",
]

# The HDF5 library under netCDF4 is not thread-safe: two threads writing files at once crash
# the process. Every netCDF access of this process goes through this lock (parts are written
# by the tasks of the threaded scheduler, the archive by a thread of its own meanwhile).
HDF5_LOCK = threading.RLock()
ALGORITHM = "sha256"
SIDECAR_SUFFIX = ".sha256"
# Bytes read at once while hashing a file, and values per slab while hashing a variable:
# bounded memory whatever the size of the study.
_READ_BYTES = 1 << 20
# The most of a digest file read: its one line (`sidecar_text`) is ~80 bytes and the part's
# name; more is not one rbstudy wrote (a link to /dev/zero, which never ends).
_SIDECAR_BYTES = 4096
_SLAB_BYTES = 1 << 23
# Slots of a variable's chunk cache while it is hashed (a prime, as HDF5 advises).
_CACHE_SLOTS = 521
# The global attributes in the archive's checksums (under the name `MEANING`): those that give
# its values their meaning. The title, history and config text are left out: a changed title
# is redescribed in place.
MEANING_ATTRIBUTES = ("study", "batches", "accuracy_bound")
MEANING = "(global attributes)"
# The archive's group of checksums, and its two attributes.
GROUP = "integrity"
SEALS = ("checksums", "part_checksums")
# Closes of an HDF5 file whose flush met a full disk, once its temporary is truncated
# (`_close_or_truncate`): measured on a full tmpfs, the first fails and the second succeeds.
_CLOSE_ATTEMPTS = 3
# The files a full disk kept open even then (`_close_or_truncate`), closed at the next write.
_UNCLOSED = []
# Free bytes below which a failed write is put down to a full disk: HDF5 reports one as "HDF
# error" (a RuntimeError), "Disable slist on flush dest failure failed" or even "Permission
# denied", so the free space, not the error, tells.
_FULL_BYTES = 2**20


def file_digest(path):
    """``sha256:<hex>`` of the bytes of the regular file at ``path`` (`open_regular_file`:
    a FIFO or a device in a part's place is refused, never waited on or read forever)."""
    digest = hashlib.sha256()
    with open_regular_file(path) as handle:
        while block := handle.read(_READ_BYTES):
            digest.update(block)
    return f"{ALGORITHM}:{digest.hexdigest()}"


def sidecar(path):
    """Where the digest of the part at ``path`` is kept."""
    path = pathlib.Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def sidecar_text(digest, path):
    """The digest file's line, as ``sha256sum`` writes it (``sha256sum -c`` does not read the
    ``sha256:`` prefix, but a reader sees which file and algorithm)."""
    return f"{digest}  {pathlib.Path(path).name}\n"


def is_part(attributes, dimensions):
    """Whether a netCDF file with these global ``attributes`` and ``dimensions`` (names) is
    one batch's part file rather than a study's archive."""
    return "batch" in attributes and "case" in dimensions


def sealed(path):
    """True when the part at ``path`` exists with its digest beside it (so that a part which
    fails `part_digest` then is damaged, not unfinished)."""
    return pathlib.Path(path).exists() and sidecar(path).exists()


def part_digest(path):
    """The digest of the part at ``path`` when its bytes match the one stored beside it at
    writing, else None (no part, no digest, no regular file for either, or any byte changed
    since)."""
    try:
        with open_regular_file(sidecar(path)) as handle:
            stored = handle.read(_SIDECAR_BYTES).decode().split()[0]
        return stored if file_digest(path) == stored else None
    except (OSError, IndexError, UnicodeDecodeError):
        return None


def _update_values(digest, variable):
    """Feed the stored values of ``variable`` to ``digest``, slab by slab along its first
    dimension."""
    if variable.dtype is str:  # a string coordinate: its values joined by NUL
        digest.update("\0".join(str(v) for v in np.ravel(variable[...])).encode())
        return
    shape = variable.shape
    if not shape:
        digest.update(np.ascontiguousarray(variable[...]).tobytes())
        return
    if variable.chunking() != "contiguous":
        # each chunk is read once: netCDF's default cache (64 MiB a variable, kept while the
        # file is open) held 320 MiB of a 1e5-case archive when it was sealed
        variable.set_var_chunk_cache(size=_SLAB_BYTES, nelems=_CACHE_SLOTS, preemption=1.0)
    row_bytes = max(1, int(np.prod(shape[1:], dtype=np.int64)) * variable.dtype.itemsize)
    step = max(1, _SLAB_BYTES // row_bytes)
    for start in range(0, shape[0], step):
        digest.update(np.ascontiguousarray(variable[start : start + step]).data)


def _header(variable):
    """What a variable's checksum covers besides its values: its dimensions, shape, type and
    attributes, as the JSON text hashed before them."""
    attributes = {key: np.asarray(variable.getncattr(key)).tolist() for key in variable.ncattrs()}
    header = {
        "dimensions": variable.dimensions,
        "shape": variable.shape,
        "dtype": str(variable.dtype),
        "attributes": attributes,
    }
    return json.dumps(header, sort_keys=True, default=str)


class StreamedChecksum:
    """The checksum of an archive variable computed from its values as they are written, so
    that sealing need not read the archive back (1e6 cases: 1.5 GB decompressed, ~9 s).

    It holds only when every value was written once, in C order of the variable's first
    ``grid_rank`` dimensions (a study's parts copied in order usually are), and its header
    has not changed since; `archive_checksums` reads back any other variable."""

    def __init__(self, variable, grid_rank):
        self.header = _header(variable)
        self.grid_shape = variable.shape[:grid_rank]
        self.dtype = variable.dtype
        self.digest = hashlib.sha256(self.header.encode())
        self.fed = 0  # how many positions of the grid were fed, from its first
        self.in_order = grid_rank > 0 and variable.dtype is not str

    def wrote(self, index, values):
        """Feed ``values``, just written at ``index`` (a slice or a list per grid dimension),
        when they continue the variable in C order; else give up (read back when sealed)."""
        if self.in_order:
            run = _run_of(index, self.grid_shape)
            self.in_order = run is not None and run[0] == self.fed
            if self.in_order:
                self.digest.update(np.ascontiguousarray(values, dtype=self.dtype).data)
                self.fed += run[1]

    def checksum(self, variable):
        """``sha256:<hex>`` of ``variable`` when every value was fed in order and its header is
        the one hashed; else None."""
        whole = self.in_order and self.fed == int(np.prod(self.grid_shape, dtype=np.int64))
        if not whole or _header(variable) != self.header:
            return None
        return f"{ALGORITHM}:{self.digest.hexdigest()}"


def _run_of(index, shape):
    """(first flat position in C order, count) of the slab ``index`` (a slice or a list per
    dimension of ``shape``) when its positions are consecutive; else None."""
    if len(index) != len(shape) or not all(isinstance(piece, slice) for piece in index):
        return None
    pieces = [range(*piece.indices(size)) for piece, size in zip(index, shape, strict=True)]
    if any(piece.step != 1 or not len(piece) for piece in pieces):
        return None
    # consecutive: whole along every dimension after the first partial one, one position along
    # every dimension before it
    partial = next((k for k in range(len(shape) - 1, -1, -1) if len(pieces[k]) != shape[k]), -1)
    if any(len(piece) != 1 for piece in pieces[:partial]):
        return None
    first = int(np.ravel_multi_index([piece.start for piece in pieces], shape))
    return first, int(np.prod([len(piece) for piece in pieces], dtype=np.int64))


def archive_checksums(nc, streamed=None):
    """Name -> ``sha256:<hex>`` for every variable of the open netCDF4 dataset ``nc``: of its
    dimensions, type, attributes and raw stored values; and under `MEANING` the global
    attributes that say what the values mean (the study, its batches, the accuracy bound that
    defines the stored verdict). A variable of ``streamed`` (name -> `StreamedChecksum`)
    whose values were hashed as they were written is not read."""
    nc.set_auto_maskandscale(False)
    streamed = streamed or {}
    meaning = {
        key: np.asarray(nc.getncattr(key)).tolist() for key in MEANING_ATTRIBUTES if key in nc.ncattrs()
    }
    found = {
        MEANING: f"{ALGORITHM}:" + hashlib.sha256(json.dumps(meaning, sort_keys=True).encode()).hexdigest()
    }
    for name, variable in nc.variables.items():
        found[name] = (streamed[name].checksum(variable) if name in streamed else None) or _read_checksum(
            variable
        )
    for name in nc.groups:
        if name != GROUP:
            found.update(group_checksums(nc, name))
    return found


def group_checksums(nc, group):
    """Name -> ``sha256:<hex>`` for the group ``group`` of the open netCDF4 dataset ``nc``
    (one added to a sealed archive, as the step search's): ``<group>/<variable>`` for each of
    its variables, and ``<group>/`` + `MEANING` for all its attributes."""
    held = nc.groups[group]
    held.set_auto_maskandscale(False)
    attributes = {key: np.asarray(held.getncattr(key)).tolist() for key in held.ncattrs()}
    found = {
        f"{group}/{MEANING}": f"{ALGORITHM}:"
        + hashlib.sha256(json.dumps(attributes, sort_keys=True, default=str).encode()).hexdigest()
    }
    found.update({f"{group}/{name}": _read_checksum(variable) for name, variable in held.variables.items()})
    return found


def reseal_group(nc, group):
    """Replace the checksums of the group ``group`` of the sealed archive open for writing as
    ``nc`` by those of its present content (none when it is gone): the checksums of the
    archive's own variables are kept as they were sealed, not recomputed."""
    sealed_in = nc.groups[GROUP]
    checksums = json.loads(sealed_in.getncattr(SEALS[0]))
    checksums = {name: value for name, value in checksums.items() if not name.startswith(f"{group}/")}
    if group in nc.groups:
        checksums.update(group_checksums(nc, group))
    sealed_in.setncattr(SEALS[0], json.dumps(checksums, sort_keys=True))


def _read_checksum(variable):
    """``sha256:<hex>`` of ``variable``'s header and stored values, read from the file."""
    digest = hashlib.sha256(_header(variable).encode())
    _update_values(digest, variable)
    return f"{ALGORITHM}:{digest.hexdigest()}"


@contextlib.contextmanager
def netcdf_writer(temporary, mode="w"):
    """``netCDF4.Dataset(temporary, mode)`` (NETCDF4) of a temporary file, closed on the way
    out even when a full disk fails its close (`_closed_on_exit`). Opening and closing take
    `HDF5_LOCK`; what the caller does in between takes it as it needs."""
    with HDF5_LOCK:
        _close_unclosed()
        nc = netCDF4.Dataset(temporary, mode, format="NETCDF4")
    with _closed_on_exit(nc, temporary, HDF5_LOCK):
        yield nc


@contextlib.contextmanager
def hdf5_writer(temporary):
    """``h5py.File(temporary, "r+")``, closed on the way out as `netcdf_writer` closes. h5py
    carries its own HDF5 library and lock: `HDF5_LOCK`, netCDF4's, is not taken."""
    _close_unclosed()
    handle = h5py.File(temporary, "r+")
    with _closed_on_exit(handle, temporary, contextlib.nullcontext()):
        yield handle


def nearly_full(path):
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


def seal_archive(path, part_digests, streamed=None):
    """Store the checksums of the written archive at ``path`` (still under its temporary
    name; those of ``streamed`` as they were hashed while written, `archive_checksums`) and
    the digests of the parts it was built from (``[batch id, digest]`` pairs, in the study's
    batch order)."""
    with netcdf_writer(path, "a") as nc, HDF5_LOCK:
        checksums = archive_checksums(nc, streamed)
        nc.createGroup(GROUP).setncatts(
            dict(zip(SEALS, (json.dumps(checksums, sort_keys=True), json.dumps(part_digests)), strict=True))
        )


def _named(name):
    if name == MEANING:
        return f"the global attributes {', '.join(MEANING_ATTRIBUTES)}"
    group, _, rest = name.rpartition("/")
    return f"the attributes of group {group}" if rest == MEANING else f"variable {name}"


@dataclass(frozen=True)
class ArchiveCheck:
    """What `verify_archive` found: ``problems`` (short phrases, none when intact);
    ``provable`` False when the file cannot be checked at all (no checksums, not an archive)
    rather than found changed; the ``variables`` and ``parts`` its checksums name."""

    problems: tuple
    provable: bool = True
    variables: int = 0
    parts: int = 0


def verify_archive(path):
    """An `ArchiveCheck` of the archive at ``path``: every variable against its checksum, and
    its parts against the study's batches."""
    try:
        with netCDF4.Dataset(path) as nc:
            attributes = set(nc.ncattrs())
            if is_part(attributes, nc.dimensions):
                return ArchiveCheck(
                    ("it is a part file without its digest beside it (its sweep stopped before sealing it)",),
                    provable=False,
                )
            # rbstudy 0.3 sealed its archives in the global attributes
            sealed_in = nc.groups[GROUP] if GROUP in nc.groups else nc
            if not set(SEALS) <= set(sealed_in.ncattrs()) or "batches" not in attributes:
                return ArchiveCheck(
                    ("it carries no checksums (written by an rbstudy before 0.3, or not by rbstudy)",),
                    provable=False,
                )
            stored, parts = (json.loads(sealed_in.getncattr(name)) for name in SEALS)
            batches = nc.getncattr("batches")
            found = archive_checksums(nc)
    except (OSError, RuntimeError, AttributeError, KeyError, ValueError) as error:
        return ArchiveCheck((f"it cannot be read as netCDF ({one_line(error)})",))
    try:
        problems = [
            f"{_named(name)} differs from its checksum"
            for name in sorted(set(stored) & set(found))
            if stored[name] != found[name]
        ]
        problems += [f"{_named(name)} is missing" for name in sorted(set(stored) - set(found))]
        problems += [f"{_named(name)} was added" for name in sorted(set(found) - set(stored))]
        if ids_digest([batch_id for batch_id, _ in parts]) != batches:
            problems.append("its part_checksums do not name the batches of its `batches` attribute")
    except (TypeError, ValueError, AttributeError):
        return ArchiveCheck(("its checksums attributes are not what rbstudy writes (edited?)",))
    variables = sum(not name.endswith(MEANING) for name in stored)
    return ArchiveCheck(tuple(problems), variables=variables, parts=len(parts))
