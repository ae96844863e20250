"""Checksums that prove the archive holds what was computed.

The archive (``<study>.nc``) travels alone, so it carries its own proof, in the netCDF group
`GROUP` (out of the global attributes a user reads: ``xr.open_dataset`` of the file does not
show it): its attribute ``checksums`` holds one SHA-256 per variable, of its type, shape,
attributes and stored values (fill values included, nothing decoded), and ``part_checksums``
the digest of every part it was built from. `verify_archive` recomputes the first and checks
that the second names exactly the study's batches (its ``batches`` attribute). Archives of
rbstudy 0.3 hold the two as global attributes, and are proven the same way. A group added to
a sealed archive (the step search's ``search``) is sealed with it: ``<group>/<variable>`` per
variable and ``<group>/`` + `MEANING` for its attributes, in the same ``checksums``
(`reseal_group`). The global attributes (title, history, config text) are not in the
per-variable checksums: a changed title is redescribed in place without touching the data
(`rbstudy.archive.rewrite.refresh_description`).
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import netCDF4
import numpy as np

from rbstudy.archive.hdf5 import HDF5_LOCK, netcdf_writer
from rbstudy.archive.ids import ids_digest
from rbstudy.archive.layout import is_part
from rbstudy.errors import one_line

__all__ = [
    "ALGORITHM",
    "ArchiveCheck",
    "GROUP",
    "MEANING",
    "MEANING_ATTRIBUTES",
    "SEALS",
    "StreamedChecksum",
    "archive_checksums",
    "group_checksums",
    "reseal_group",
    "seal_archive",
    "verify_archive",
]


ALGORITHM = "sha256"


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
    that sealing need not read the archive back (1e6 cases: 1.5 GB decompressed).

    It holds only when every value was written once, in C order of the variable's first
    ``grid_rank`` dimensions (a study's parts copied in order usually are), and its header
    has not changed since; `archive_checksums` reads back any other variable."""

    def __init__(self, variable: Any, grid_rank: int) -> None:
        self.header = _header(variable)
        self.grid_shape = variable.shape[:grid_rank]
        self.dtype = variable.dtype
        self.digest = hashlib.sha256(self.header.encode())
        self.fed = 0  # how many positions of the grid were fed, from its first
        self.in_order = grid_rank > 0 and variable.dtype is not str

    def wrote(self, index: tuple, values: np.ndarray) -> None:
        """Feed ``values``, just written at ``index`` (a slice or a list per grid dimension),
        when they continue the variable in C order; else give up (read back when sealed)."""
        if self.in_order:
            run = _run_of(index, self.grid_shape)
            self.in_order = run is not None and run[0] == self.fed
            if self.in_order:
                self.digest.update(np.ascontiguousarray(values, dtype=self.dtype).data)
                self.fed += run[1]

    def checksum(self, variable: Any) -> str | None:
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


def archive_checksums(nc: Any, streamed: Mapping[str, StreamedChecksum] | None = None) -> dict[str, str]:
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


def group_checksums(nc: Any, group: str) -> dict[str, str]:
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


def reseal_group(nc: Any, group: str) -> None:
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


def seal_archive(
    path: str | os.PathLike[str],
    part_digests: list[list[str]],
    streamed: Mapping[str, StreamedChecksum] | None = None,
) -> None:
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

    problems: tuple[str, ...]
    provable: bool = True
    variables: int = 0
    parts: int = 0


def verify_archive(path: str | os.PathLike[str]) -> ArchiveCheck:
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
