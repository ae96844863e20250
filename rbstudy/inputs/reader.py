"""The one reader of user input: typed values from nested YAML mappings, by key path.

Scenes, study configs and sweeps read their input through a `Reader`, so that every bad value
fails the same way: an `rbstudy.errors.InputError` (of the reader's kind) naming the file, the
key path, the value received and what is expected.

A swept value arrives as a column: a numpy array with one entry per scene of a table
(`rbstudy.physics.scenes.SceneTable`). Numbers are checked for the whole column at once; the
first bad entry fails exactly as a single value would, with its row on the error.

The files themselves (a study config, a cluster file, a node or load table) are read by
`read_input_file`: regular files only, of bounded size, so that a path to a FIFO, a device or
a huge file fails in one line instead of hanging or exhausting the memory.
"""

from __future__ import annotations

import errno
import math
import os
import stat
from collections.abc import Callable, Iterable, Sequence
from typing import IO, Any, NoReturn

import numpy as np

from rbstudy.errors import InputError, did_you_mean

__all__ = [
    "Reader",
    "read_input_file",
    "open_regular_file",
    "NotARegularFile",
    "MAX_INPUT_BYTES",
    "is_folder_name",
    "FOLDER_NAME_RULE",
    "MAX_NAME_BYTES",
    "MAX_TITLE_CHARACTERS",
]

# The largest input file read: a config is kilobytes, a node table of a million nodes with
# their inertias ~130 MiB. A larger file is not one written for rbstudy (a log, a mesh, a
# disk image), and parsing it would take gigabytes.
MAX_INPUT_BYTES = 256 * 2**20
_MIB = 2**20
# What a path that is no regular file names, by its `stat` kind.
_KINDS = {
    stat.S_IFDIR: "a folder",
    stat.S_IFIFO: "a FIFO (named pipe)",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFSOCK: "a socket",
}


class NotARegularFile(OSError):
    """A path that names no regular file: ``kind`` says what it is ("a folder", "a FIFO
    (named pipe)"); its ``strerror`` says so as a reason ("it is a folder, not a regular
    file")."""

    def __init__(self, kind: str, path: str | os.PathLike[str]) -> None:
        super().__init__(None, f"it is {kind}, not a regular file", str(path))
        self.kind = kind


def _check_kind(info, path):
    if not stat.S_ISREG(info.st_mode):
        raise NotARegularFile(_KINDS.get(stat.S_IFMT(info.st_mode), "not a file"), path)


def open_regular_file(path: str | os.PathLike[str]) -> IO[bytes]:
    """The regular file ``path`` (a link is followed) opened for reading bytes; anything else
    (a folder, a FIFO, a device) is a `NotARegularFile`, and a path that cannot be opened the
    system's `OSError`. Every command that reads a file a user names opens it here.

    A FIFO blocks whoever opens it and a device such as /dev/zero never ends, so the kind is
    checked before the file is opened, and again on the opened file (opened non-blocking, so
    that a path swapped for a FIFO in between cannot hang it).
    """
    try:
        _check_kind(os.stat(path), path)
    except ValueError:  # a NUL in the path, which no file's name holds
        raise OSError(errno.EINVAL, "no file's name holds a NUL character", str(path)) from None
    file = os.fdopen(os.open(path, os.O_RDONLY | os.O_NONBLOCK), "rb")
    try:
        _check_kind(os.fstat(file.fileno()), path)
    except OSError:
        file.close()
        raise
    return file


def _too_large(size, path, what):
    raise InputError(
        f"{what} is {size / _MIB:,.0f} MiB, larger than the {MAX_INPUT_BYTES // _MIB} "
        "MiB an input file may be",
        "give the right file, or a smaller one",
        str(path),
    )


def read_input_file(path: str | os.PathLike[str], what: str, fix: str | None) -> bytes:
    """The bytes of the regular file ``path`` (`open_regular_file`), at most
    `MAX_INPUT_BYTES`; anything else is an `InputError` at ``path`` (no key: the caller
    places it) saying "cannot read ``what``" ("the node table") and why, with ``fix``. The
    size is checked before reading, and at most one byte past the bound is read, so that a
    file growing meanwhile is refused too."""
    try:
        with open_regular_file(path) as file:
            size = os.fstat(file.fileno()).st_size
            if size > MAX_INPUT_BYTES:
                _too_large(size, path, what)
            data = file.read(MAX_INPUT_BYTES + 1)
    except OSError as error:
        raise InputError(f"cannot read {what}: {error.strerror}", fix, str(path)) from None
    if len(data) > MAX_INPUT_BYTES:
        _too_large(len(data), path, what)
    return data


# A file name holds at most 255 bytes on the common file systems (ext4, XFS, Btrfs, APFS;
# NTFS 255 UTF-16 units), and a study's name goes into file names: the longest, its figures'
# (`<name>_convergence_momentum_magnitude.svg`, `rbstudy.analysis.plots.figure_name`, 35
# bytes more), ahead of the temporary of the archive's checksum (`.<name>.nc.sha256.<8
# random>.tmp`, `rbstudy.archive.files`, 24 more). Five bytes more leave room for a longer
# figure name. The --out folder is not known when a config is validated, so its own limit
# (`os.pathconf`) cannot be asked.
_FILE_NAME_BYTES = 255
MAX_NAME_BYTES = _FILE_NAME_BYTES - 40
# What a name that becomes a folder or file name may hold (a study's, from a config or read
# back from an archive): no path separator and no "..", so it can never point elsewhere.
FOLDER_NAME_RULE = f"letters, digits, '-' and '_' only, at most {MAX_NAME_BYTES} bytes"
# A title is one line atop every figure, where two lines hold about 200 characters; a longer
# one is no title (the figures would show only it). The report's page cuts an archive's to it.
MAX_TITLE_CHARACTERS = 200


def is_folder_name(value: Any) -> bool:
    """Whether ``value`` is a string that keeps `FOLDER_NAME_RULE`."""
    return (
        isinstance(value, str)
        and value.replace("_", "").replace("-", "").isalnum()
        and len(value.encode()) <= MAX_NAME_BYTES
    )


class Reader:
    """Reads values from the file ``source``; every failure is a ``kind`` error there."""

    def __init__(self, source: str, kind: type[InputError] = InputError) -> None:
        self.source, self.kind = source, kind

    def fail(self, key: str | None, message: str, fix: str | None = None, row: int | None = None) -> NoReturn:
        """Raise the error ``<source>: <key>: <message>; <fix>`` (of the table row ``row``)."""
        raise self.kind(message, fix, self.source, key or "(top level)", row)

    def locate(self, error: InputError, key: str | None = None) -> InputError:
        """``error`` (an `InputError` raised where the file and key were unknown) placed
        here, under ``key``, as this reader's kind."""
        return error.located(self.source, key, self.kind)

    def _first_failure(self, column: np.ndarray, rows: Iterable[int], check: Callable[[Any], object]) -> None:
        """Run ``check`` on the entries ``rows`` of ``column``, one at a time: the first that
        fails raises its error, marked with its row."""
        entries = column.tolist()
        for row in rows:
            try:
                check(entries[row])
            except self.kind as error:
                error.row = int(row)
                raise

    def mapping(self, value: Any, key: str, allowed: Sequence[str]) -> dict[Any, Any]:
        """``value`` as a mapping whose keys are all in ``allowed`` (None reads as empty)."""
        if isinstance(value, np.ndarray):  # a swept number where a mapping belongs
            self._first_failure(value, range(len(value)), lambda entry: self.mapping(entry, key, allowed))
        if value is None:
            return {}
        if not isinstance(value, dict):
            self.fail(key, f"expected a mapping with keys {', '.join(allowed)}, got {value!r}")
        for name in value:
            if name not in allowed:
                self.fail(
                    f"{key}.{name}" if key else str(name),  # `1e400: 1`: YAML made the key a number
                    f"unknown key{did_you_mean(name, allowed)}; valid keys here: {', '.join(allowed)}",
                )
        return value

    def number(self, value: Any, key: str, positive: bool = False) -> float | np.ndarray:
        """``value`` as a finite float (and > 0 when ``positive``); a column as a float array."""
        if isinstance(value, np.ndarray):
            return self._numbers(value, key, positive)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(key, f"expected a number, got {value!r:.80}")
        try:
            number = float(value)
        except OverflowError:  # an integer beyond any float
            number = math.inf
        if not math.isfinite(number):
            self.fail(key, f"must be finite, got {value!r}")
        if positive and number <= 0.0:
            self.fail(key, f"must be > 0, got {value!r}")
        return number

    def _numbers(self, column, key, positive):
        """The column ``column`` (n,) as floats, each checked as `number` checks one."""
        if column.dtype.kind in "iuf":
            numbers = column.astype(float)
            with np.errstate(invalid="ignore"):
                bad = ~np.isfinite(numbers) | (positive & (numbers <= 0.0))
            if not bad.any():
                return numbers
            rows = np.flatnonzero(bad)
        else:  # names or flags among the values
            rows = range(len(column))
        self._first_failure(column, rows, lambda entry: self.number(entry, key, positive))
        return column.astype(float)  # numbers only, held as objects

    def count(self, value: Any, key: str, maximum: int | None = None, minimum: int = 1) -> int:
        """``value`` as a whole number >= ``minimum`` (and at most ``maximum``), as an int;
        a whole float is one (``count: 1e3``: YAML reads an exponent as a float)."""
        whole = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
        if isinstance(value, bool) or not whole or value < minimum:
            self.fail(key, f"expected a whole number >= {minimum}, got {value!r}")
        if maximum is not None and value > maximum:
            self.fail(
                key,
                f"{value:,} is too many" if isinstance(value, int) else f"{value:g} is too many",
                f"at most {maximum:,}",
            )
        return int(value)

    def vector(self, value: Any, key: str, length: int = 3) -> tuple[Any, ...]:
        """``value`` as a tuple of ``length`` finite floats (a swept entry: a float array)."""
        if isinstance(value, np.ndarray):  # a swept number where a list belongs
            self._first_failure(value, range(len(value)), lambda entry: self.vector(entry, key, length))
        if not isinstance(value, (list, tuple)) or len(value) != length:
            self.fail(key, f"expected a list of {length} numbers, got {value!r}")
        return tuple(self.number(v, f"{key}[{i}]") for i, v in enumerate(value))

    def flag(self, value: Any, key: str) -> bool | np.ndarray:
        """``value`` as true or false (a column: a bool array)."""
        if isinstance(value, np.ndarray):  # a swept flag: a column of true and false
            if value.dtype != bool:
                self._first_failure(value, range(len(value)), lambda entry: self.flag(entry, key))
            return value
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {value!r}")
        return value

    def folder_name(self, value: Any, key: str) -> str:
        """``value`` as a name that keeps `FOLDER_NAME_RULE`."""
        if isinstance(value, str) and len(value.encode()) > MAX_NAME_BYTES:
            self.fail(
                key,
                f"{len(value.encode()):,} bytes long (UTF-8), at most {MAX_NAME_BYTES}: it goes into "
                f"file names such as {value[:20]}..._convergence_momentum_magnitude.svg, which a "
                f"file system keeps to {_FILE_NAME_BYTES} bytes",
                f"shorten it to {MAX_NAME_BYTES} bytes or fewer",
            )
        if not is_folder_name(value):
            self.fail(key, f"use {FOLDER_NAME_RULE} (it names a folder), got {value!r}")
        return value

    def line(self, value: Any, key: str) -> str:
        """``value`` as one line of text."""
        if not isinstance(value, str) or "\n" in value.strip():
            self.fail(key, f"expected one line of text, got {value!r}")
        return value.strip()
