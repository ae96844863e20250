"""Checksums that prove a stored result is the one that was computed.

Two kinds of file, two kinds of proof:

* **A part file** (``parts/<batch>.nc``) is an intermediate that only rbstudy reads. Its
  whole byte content is hashed (SHA-256) when it is written, and the digest is kept beside it
  in ``<batch>.nc.sha256``. A part is reused only when its bytes still hash to that digest:
  a truncated, zeroed, overwritten, edited or swapped file never is, wherever the damage lies
  (data, attributes, the HDF5 structure, or garbage after its end).
* **The archive** (``<study>.nc``) travels alone, so it carries its own proof: the attribute
  ``checksums`` holds one SHA-256 per variable, of its type, shape, attributes and stored
  values (fill values included, nothing decoded). ``part_checksums`` names the digest of every
  part it was built from. `verify_archive` recomputes the first and checks that the second
  names exactly the study's batches (its ``batches`` attribute).

The global attributes (title, history, config text) are not in the per-variable checksums:
a changed title is redescribed in place without touching the data (`store.refresh_description`).
"""

import hashlib
import json
import pathlib

import netCDF4
import numpy as np

from rbstudy.errors import InputError
from rbstudy.pipeline.batches import ids_digest

__all__ = ["file_digest", "seal_part", "part_digest", "archive_checksums", "seal_archive",
           "verify_archive", "verify_file", "SIDECAR_SUFFIX", "ALGORITHM"]

ALGORITHM = "sha256"
SIDECAR_SUFFIX = ".sha256"
# Bytes read at once while hashing a file, and values per slab while hashing a variable:
# bounded memory whatever the size of the study.
_READ_BYTES = 1 << 20
_SLAB_BYTES = 1 << 26
# The global attributes in the archive's checksums (under the name `MEANING`): those that give
# its values their meaning. The title, history and config text are left out: a changed title
# is redescribed in place.
MEANING_ATTRIBUTES = ("study", "batches", "accuracy_bound")
MEANING = "(global attributes)"
# Words of `verify_archive`'s problems that say the content changed (the others say that it
# cannot be checked).
_DAMAGE = ("differs", "is missing", "was added", "do not name", "not what rbstudy writes",
           "cannot be read")


def file_digest(path):
    """``sha256:<hex>`` of the bytes of the file at ``path``."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(_READ_BYTES):
            digest.update(block)
    return f"{ALGORITHM}:{digest.hexdigest()}"


def _sidecar(path):
    path = pathlib.Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def seal_part(temporary, path, write_text):
    """The digest of the finished part ``temporary`` (about to be renamed to ``path``), and a
    function that stores it beside ``path`` once the rename is done (a part without its
    digest, after a kill between the two, is simply recomputed)."""
    digest = file_digest(temporary)
    return digest, lambda: write_text(f"{digest}  {pathlib.Path(path).name}\n", _sidecar(path))


def sealed(path):
    """True when the part at ``path`` exists with its digest beside it (so that a part which
    fails `part_digest` then is damaged, not unfinished)."""
    return pathlib.Path(path).exists() and _sidecar(path).exists()


def part_digest(path):
    """The digest of the part at ``path`` when its bytes match the one stored beside it at
    writing, else None (no part, no digest, or any byte changed since)."""
    path = pathlib.Path(path)
    try:
        stored = _sidecar(path).read_text().split()[0]
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
    row_bytes = max(1, int(np.prod(shape[1:], dtype=np.int64)) * variable.dtype.itemsize)
    step = max(1, _SLAB_BYTES // row_bytes)
    for start in range(0, shape[0], step):
        digest.update(np.ascontiguousarray(variable[start:start + step]).tobytes())


def archive_checksums(nc):
    """Name -> ``sha256:<hex>`` for every variable of the open netCDF4 dataset ``nc``: of its
    dimensions, type, attributes and raw stored values; and under `MEANING` the global
    attributes that say what the values mean (the study, its batches, the accuracy bound that
    defines the stored verdict)."""
    nc.set_auto_maskandscale(False)
    meaning = {key: np.asarray(nc.getncattr(key)).tolist() for key in MEANING_ATTRIBUTES
               if key in nc.ncattrs()}
    found = {MEANING: f"{ALGORITHM}:" + hashlib.sha256(
        json.dumps(meaning, sort_keys=True).encode()).hexdigest()}
    for name, variable in nc.variables.items():
        digest = hashlib.sha256()
        attributes = {key: np.asarray(variable.getncattr(key)).tolist()
                      for key in variable.ncattrs()}
        header = {"dimensions": variable.dimensions, "shape": variable.shape,
                  "dtype": str(variable.dtype), "attributes": attributes}
        digest.update(json.dumps(header, sort_keys=True, default=str).encode())
        _update_values(digest, variable)
        found[name] = f"{ALGORITHM}:{digest.hexdigest()}"
    return found


def seal_archive(path, part_digests):
    """Store the checksums of the written archive at ``path`` (still under its temporary
    name) and the digests of the parts it was built from (``[batch id, digest]`` pairs, in
    the study's batch order)."""
    with netCDF4.Dataset(path, "a") as nc:
        checksums = archive_checksums(nc)
        nc.setncatts({"checksums": json.dumps(checksums, sort_keys=True),
                      "part_checksums": json.dumps(part_digests)})


def _named(name):
    return (f"the global attributes {', '.join(MEANING_ATTRIBUTES)}" if name == MEANING
            else f"variable {name}")


def verify_archive(path):
    """Problems of the archive at ``path`` (empty when intact), each a short phrase: a
    variable that differs from its checksum, or parts that are not the study's batches."""
    try:
        with netCDF4.Dataset(path) as nc:
            attributes = set(nc.ncattrs())
            if "batch" in attributes and "case" in nc.dimensions:
                return ["it is a part file without its digest beside it (its sweep stopped "
                        "before sealing it)"]
            if not {"checksums", "part_checksums", "batches"} <= attributes:
                return ["it carries no checksums (written by an rbstudy before 0.3, or not by "
                        "rbstudy)"]
            stored, parts = (json.loads(nc.getncattr(name))
                             for name in ("checksums", "part_checksums"))
            batches = nc.getncattr("batches")
            found = archive_checksums(nc)
    except (OSError, RuntimeError, AttributeError, KeyError, ValueError) as error:
        return [f"it cannot be read as netCDF ({str(error).strip().splitlines()[0]})"]
    try:
        problems = [f"{_named(name)} differs from its checksum"
                    for name in sorted(set(stored) & set(found)) if stored[name] != found[name]]
        problems += [f"{_named(name)} is missing" for name in sorted(set(stored) - set(found))]
        problems += [f"{_named(name)} was added" for name in sorted(set(found) - set(stored))]
        if ids_digest([batch_id for batch_id, _ in parts]) != batches:
            problems.append("its part_checksums do not name the batches of its `batches` "
                            "attribute")
    except (TypeError, ValueError, AttributeError):
        return ["its checksums attributes are not what rbstudy writes (edited?)"]
    return problems


def verify_file(path):
    """What ``rbstudy verify`` says of ``path`` when it is intact (an archive, or a part with
    its digest beside it); an `InputError` naming the first problems when it is not."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise InputError("no such file", "give the <study>.nc written by rbstudy sweep", path)
    if _sidecar(path).exists():
        if part_digest(path) is None:
            raise InputError("damaged: its bytes do not match the digest stored beside it",
                             "rerun its sweep: the part is recomputed", path)
        return "intact (a part; its bytes match its digest)"
    problems = verify_archive(path)
    if problems:
        shown = "; ".join(problems[:3]) + (f"; and {len(problems) - 3} more"
                                           if len(problems) > 3 else "")
        if any(word in problems[0] for word in _DAMAGE):
            raise InputError(f"damaged: {shown}", "rerun its sweep: a damaged archive is rebuilt",
                             path)
        raise InputError(f"cannot be proven intact: {shown}",
                         "rerun its sweep with this rbstudy", path)
    with netCDF4.Dataset(path) as nc:
        variables = len(json.loads(nc.getncattr("checksums")))
        parts = len(json.loads(nc.getncattr("part_checksums")))
    return f"intact ({variables} variables match their SHA-256 checksums; built from {parts} parts)"
