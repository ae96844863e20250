"""Part files: one finished batch each, written by whichever process computed it.

A part (``parts/<batch-id>.npz``) is an intermediate that only rbstudy reads: numpy's archive
of arrays, uncompressed, each variable's values case first beside ``case`` (each case's
position in the study, C order of the grid), and what the part is (`PART_ATTRIBUTES`: its
study, batch and config) as text. Not netCDF: a part lives until the archive is written, and
netCDF4 took far longer to write one of the default study's 54 parts (a file of 37
variables, under the process's one HDF5 lock, which the archive's writer waited on); numpy
writes one at the disk's pace, needs no lock, and reads it back without pickles
(``allow_pickle=False``). Its whole byte content is hashed (SHA-256) when it is written, and
the digest is kept beside it in ``<batch>.npz.sha256`` (`sidecar`). A part is reused only when its bytes still
hash to that digest (`part_complete`): a truncated, zeroed, overwritten, edited or swapped
file never is, wherever the damage lies. `PartTarget` is what a task, local or on a cluster
worker, is handed to write its batch.
"""

from __future__ import annotations

import functools
import hashlib
import os
import pathlib
import re
import zipfile
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np

from rbstudy.archive.checksums import ALGORITHM
from rbstudy.archive.files import temporary_beside, write_text_atomic
from rbstudy.archive.layout import Layout
from rbstudy.archive.variables import VARIABLES
from rbstudy.errors import RbstudyError
from rbstudy.inputs.reader import open_regular_file

__all__ = [
    "PART_ATTRIBUTES",
    "PART_SUFFIX",
    "PartTarget",
    "SIDECAR_SUFFIX",
    "file_digest",
    "part_attributes",
    "part_complete",
    "part_digest",
    "part_values",
    "read_part",
    "sealed",
    "sees_folder",
    "sidecar",
    "sidecar_text",
    "write_part",
]


PART_SUFFIX = ".npz"
SIDECAR_SUFFIX = ".sha256"
# What a part says of itself, as text arrays beside its values (no variable has such a name):
# its study's name, its batch's id and its config's identity (as the archive's attribute
# `rbstudy.archive.owner.IDENTITY`), which decides whose a study folder is where its record
# is missing.
PART_ATTRIBUTES = {"study": "(study)", "batch": "(batch)", "identity": "(identity)"}
# What numpy raises reading a file that is no part it wrote (truncated, zeroed, another zip:
# encrypted, of another compression, a header claiming a huge shape).
UNREADABLE_PART = (
    OSError,
    KeyError,
    ValueError,
    EOFError,
    zipfile.BadZipFile,
    RuntimeError,
    NotImplementedError,
    MemoryError,
)


# Bytes read at once while hashing a file, and values per slab while hashing a variable:
# bounded memory whatever the size of the study.
_READ_BYTES = 1 << 20


# The most of a digest file read: its one line (`sidecar_text`) is ~80 bytes and the part's
# name; more is not one rbstudy wrote (a link to /dev/zero, which never ends).
_SIDECAR_BYTES = 4096


def file_digest(path: str | os.PathLike[str]) -> str:
    """``sha256:<hex>`` of the bytes of the regular file at ``path`` (`open_regular_file`:
    a FIFO or a device in a part's place is refused, never waited on or read forever)."""
    digest = hashlib.sha256()
    with open_regular_file(path) as handle:
        while block := handle.read(_READ_BYTES):
            digest.update(block)
    return f"{ALGORITHM}:{digest.hexdigest()}"


def sidecar(path: str | os.PathLike[str]) -> pathlib.Path:
    """Where the digest of the part at ``path`` is kept."""
    path = pathlib.Path(path)
    return path.with_name(path.name + SIDECAR_SUFFIX)


def sidecar_text(digest: str, path: str | os.PathLike[str]) -> str:
    """The digest file's line, as ``sha256sum`` writes it (``sha256sum -c`` does not read the
    ``sha256:`` prefix, but a reader sees which file and algorithm)."""
    return f"{digest}  {pathlib.Path(path).name}\n"


def sealed(path: str | os.PathLike[str]) -> bool:
    """True when the part at ``path`` exists with its digest beside it (so that a part which
    fails `part_digest` then is damaged, not unfinished)."""
    return pathlib.Path(path).exists() and sidecar(path).exists()


def part_digest(path: str | os.PathLike[str]) -> str | None:
    """The digest of the part at ``path`` when its bytes match the one stored beside it at
    writing, else None (no part, no digest, no regular file for either, or any byte changed
    since)."""
    try:
        with open_regular_file(sidecar(path)) as handle:
            stored = handle.read(_SIDECAR_BYTES).decode().split()[0]
        return stored if file_digest(path) == stored else None
    except (OSError, IndexError, UnicodeDecodeError):
        return None


class PartTarget(NamedTuple):
    """Where a store task puts its batch: the study's `Layout`, the batch (a
    `rbstudy.pipeline.batches.Batch`: its ``id`` and ``cases`` are read) and the path of its
    part file."""

    layout: Layout
    batch: Any
    path: str

    @property
    def cases(self) -> int:
        return len(self.batch.cases)

    def write(self, values: Mapping[str, np.ndarray]) -> str:
        """`write_part` of this batch's ``values``; the part's digest."""
        return write_part(self.layout, self.batch, values, self.path)


def part_values(batch: Any, variables: Iterable[str], values: Mapping[str, Any]) -> dict[str, np.ndarray]:
    """What the part of ``batch`` holds, and `read_part` returns, of its computed ``values``:
    ``case`` (each case's position in the study) and each of ``variables`` in its storage
    type, name -> array."""
    return {"case": np.array(batch.cases)} | {
        name: np.asarray(values[name], dtype=VARIABLES[name].dtype) for name in variables
    }


def _write_arrays(path, arrays):
    """``arrays`` (name -> array) into the numpy archive at ``path``, uncompressed."""
    with open(path, "wb") as file:  # a file, not a name: numpy would add ".npz"
        np.savez(file, **arrays)


# The header numpy's savez writes before each array's bytes (format 1.0 or 2.0).
_NPY_HEADER = re.compile(
    r"\{'descr': '([<>|=][A-Za-z]\d*)', 'fortran_order': False, 'shape': \(([\d, ]*)\), \}"
)


class _Part:
    """The arrays of the part file at ``path``, by name (``part[name]``), read without
    ``numpy.load``: its header parser, ``ast.literal_eval``, is not thread-safe in CPython 3.11
    (a part read by the archive's thread while distributed's threads ran raised "SystemError:
    AST constructor recursion depth mismatch"). Only what `write_part` writes is read: any other
    header is a ValueError, a part that is not one."""

    def __init__(self, path):
        self._file = open_regular_file(path)
        try:
            self._zip = zipfile.ZipFile(self._file)
        except BaseException:
            self._file.close()
            raise

    def __getitem__(self, name):
        data = self._zip.read(f"{name}.npy")
        if data[:6] != b"\x93NUMPY" or data[6] not in (1, 2):
            raise ValueError(f"{name}: not an array numpy wrote")
        width = 2 if data[6] == 1 else 4
        start = 8 + width + int.from_bytes(data[8 : 8 + width], "little")
        header = _NPY_HEADER.match(data[8 + width : start].decode("latin1").strip())
        if header is None:
            raise ValueError(f"{name}: not an array rbstudy wrote")
        shape = tuple(int(size) for size in header[2].split(",") if size.strip())
        return np.frombuffer(data, dtype=np.dtype(header[1]), offset=start).reshape(shape)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._zip.close()
        self._file.close()


def read_part(path: str | os.PathLike[str], variables: Iterable[str]) -> dict[str, np.ndarray]:
    """The case numbers and ``variables`` of the part file at ``path``, name -> array."""
    with _Part(path) as part:
        return {name: part[name] for name in ("case", *variables)}


def part_attributes(path: str | os.PathLike[str]) -> dict[str, str]:
    """What the part file at ``path`` says of itself (`PART_ATTRIBUTES`), name -> text."""
    with _Part(path) as part:
        return {name: str(part[key]) for name, key in PART_ATTRIBUTES.items()}


def part_complete(path: str | os.PathLike[str], batch: Any) -> str | None:
    """The digest of ``path`` when it is an intact part of ``batch`` (its bytes match the
    digest stored when it was written, its id and its cases match), else None.

    A rename makes a part appear whole, but a crash of the machine (not of the process) can
    leave an empty or truncated file, and a disk or a hand can change one: such a part is
    recomputed, never trusted.
    """
    digest = part_digest(path)
    if digest is None:
        return None
    try:
        with _Part(path) as part:
            same = str(part[PART_ATTRIBUTES["batch"]]) == batch.id and np.array_equal(
                part["case"], np.asarray(batch.cases)
            )
    except UNREADABLE_PART:
        return None
    return digest if same else None


def write_part(layout: Layout, batch: Any, values: Mapping[str, Any], path: str | os.PathLike[str]) -> str:
    """Write the part of ``batch`` (its variables ``values``, case first) to ``path`` through
    a temporary file and a rename, then its digest beside it; returns the digest."""
    said = {"study": layout.study, "batch": batch.id, "identity": "\n".join(layout.identity)}
    arrays = part_values(batch, layout.variables, values) | {
        key: np.array(said[name]) for name, key in PART_ATTRIBUTES.items()
    }
    with temporary_beside(path) as temporary:
        _write_arrays(temporary, arrays)
        digest = file_digest(temporary)
    # after the rename: a kill between the two leaves a part without digest, recomputed
    try:
        write_text_atomic(sidecar_text(digest, path), sidecar(path))
    except RbstudyError:  # a full disk: no part is left without its digest, half finished
        os.remove(path)
        raise
    return digest


@functools.lru_cache(maxsize=16)
def sees_folder(probe: tuple[str, str] | None) -> bool:
    """Whether this process reads ``probe`` = (path, token) as the client wrote it
    (`rbstudy.archive.folder.StudyFolder.probe`): a worker that does writes its parts itself.
    None: the client's own process, which sees the folder."""
    if probe is None:
        return True
    path, token = probe
    try:
        return pathlib.Path(path).read_text() == token
    except OSError:
        return False
