"""Checksums that prove a zarr store holds what was computed: per stored chunk.

A zarr store is a folder of files: each variable's ``zarr.json`` (its dimensions, type,
codecs and attributes) and one file per stored chunk (per shard, where a variable is
sharded: `rbstudy.archive.zarr_store.SHARD_BYTES`). The checksum of each is the SHA-256 of
its bytes as stored (encoded and compressed): what the disk holds is hashed, nothing decoded,
so sealing reads the compressed store once (~a third of its values' bytes) and damage
anywhere in a file, the index of a shard included, is found. The group `GROUP` holds them in
its attributes: ``checksums`` (the store path of each file -> ``sha256:<hex>``, and under
`rbstudy.archive.checksums.MEANING` the global attributes that give the values their
meaning) and ``part_checksums`` (the digest of every part the store was built from).
`verify_store` recomputes them: a file changed, missing or added is named by its variable
and its chunk's index in the chunk grid (`ArchiveCheck`, as `verify_archive` reports the
netCDF archive). The root's other global attributes (title, history, config text) are left
out, as in the netCDF archive: a changed title is redescribed in place.
"""

import hashlib
import json
import os
import pathlib

from rbstudy.archive.checksums import ALGORITHM, MEANING, MEANING_ATTRIBUTES, ArchiveCheck
from rbstudy.archive.files import fsync_path
from rbstudy.archive.ids import ids_digest
from rbstudy.errors import one_line

__all__ = ["GROUP", "seal_store", "store_checksums", "verify_store"]


GROUP = "integrity"


_METADATA = "zarr.json"


# Bytes read at once while hashing a stored file.
_READ_BYTES = 1 << 22


def _file_checksum(path, sync=False):
    """``sha256:<hex>`` of the bytes of the file at ``path``; with ``sync``, the file is
    synced to disk too (the store is renamed into place after it is sealed)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while block := handle.read(_READ_BYTES):
            digest.update(block)
        if sync:
            os.fsync(handle.fileno())
    return f"{ALGORITHM}:{digest.hexdigest()}"


def _meaning(root):
    """The checksum of the global attributes (`MEANING_ATTRIBUTES`) in the store's root
    ``zarr.json`` at ``root``, and of the copy of every array's metadata kept there
    (consolidated: what xarray reads in their place)."""
    metadata = json.loads((root / _METADATA).read_text())
    attributes = metadata["attributes"]
    meaning = {key: attributes[key] for key in MEANING_ATTRIBUTES if key in attributes}
    meaning["consolidated_metadata"] = metadata.get("consolidated_metadata")
    return f"{ALGORITHM}:" + hashlib.sha256(json.dumps(meaning, sort_keys=True).encode()).hexdigest()


def store_checksums(path: str | os.PathLike[str], sync: bool = False) -> dict[str, str]:
    """Store path -> ``sha256:<hex>`` of every file of the store at ``path`` but its root's
    ``zarr.json`` (whose meaning attributes go under `MEANING`) and the `GROUP`'s."""
    root = pathlib.Path(path)
    found = {MEANING: _meaning(root)}
    for folder, dirs, files in os.walk(root):
        dirs.sort()
        here = pathlib.Path(folder).relative_to(root)
        if here.parts[:1] == (GROUP,):
            continue
        for name in sorted(files):
            key = (here / name).as_posix()
            if key != _METADATA:
                found[key] = _file_checksum(pathlib.Path(folder) / name, sync)
        if sync:
            fsync_path(folder)
    return found


def seal_store(path: str | os.PathLike[str], part_digests: list[list[str]]) -> None:
    """Seal the store at ``path``: the checksum of every file written (each synced to disk)
    and the parts' digests ``part_digests`` ([batch id, digest] each), in the group `GROUP`."""
    import zarr

    checksums = store_checksums(path, sync=True)
    zarr.create_group(
        store=str(path),
        path=GROUP,
        zarr_format=3,
        attributes={"checksums": checksums, "part_checksums": part_digests},
    )
    fsync_path(pathlib.Path(path) / GROUP)


def _named(key):
    """What the file of store path ``key`` holds, as a problem names it."""
    if key == MEANING:
        return f"the global attributes {', '.join(MEANING_ATTRIBUTES)}"
    variable, _, rest = key.partition("/")
    if rest == _METADATA:
        return f"the metadata of variable {variable}"
    if rest.startswith("c/"):
        return f"variable {variable} chunk ({', '.join(rest.split('/')[1:])})"
    if rest == "c":  # a variable without dimensions keeps its one chunk as "c"
        return f"variable {variable} chunk ()"
    return f"the file {key}"


def verify_store(path: str | os.PathLike[str]) -> ArchiveCheck:
    """The `ArchiveCheck` of the zarr store at ``path``: every file against its checksum,
    and its parts against the study's batches."""
    root = pathlib.Path(path)
    try:
        sealed = json.loads((root / GROUP / _METADATA).read_text())["attributes"]
        stored, parts = sealed["checksums"], sealed["part_checksums"]
        batches = json.loads((root / _METADATA).read_text())["attributes"]["batches"]
    except FileNotFoundError:
        return ArchiveCheck(
            ("it carries no checksums (its sweep stopped before sealing it)",), provable=False
        )
    except (OSError, ValueError, KeyError, TypeError) as error:
        return ArchiveCheck((f"it cannot be read as a zarr store ({one_line(error)})",))
    try:
        found = store_checksums(root)
    except (OSError, ValueError, KeyError) as error:
        return ArchiveCheck((f"it cannot be read as a zarr store ({one_line(error)})",))
    try:
        problems = [
            f"{_named(key)} differs from its checksum"
            for key in sorted(set(stored) & set(found))
            if stored[key] != found[key]
        ]
        problems += [f"{_named(key)} is missing" for key in sorted(set(stored) - set(found))]
        problems += [f"{_named(key)} was added" for key in sorted(set(found) - set(stored))]
        if ids_digest([batch_id for batch_id, _ in parts]) != batches:
            problems.append("its part_checksums do not name the batches of its `batches` attribute")
    except (TypeError, ValueError, AttributeError):
        return ArchiveCheck(("its checksums attributes are not what rbstudy writes (edited?)",))
    variables = sum(key.endswith("/" + _METADATA) for key in stored)
    return ArchiveCheck(tuple(problems), variables=variables, parts=len(parts))
