"""Load tables: a force, moment or gravity given at times, linear in between.

A load that varies in time is written ``{table: ..., scale: s}`` where a constant one is
``[x, y, z]`` (docs/config.md; the optional ``scale``, read by `rbstudy.inputs.loads`,
multiplies the values and may be swept). The table is rows ``t x y z`` (s, then the load's
unit): inline, a list of rows; or a file named relative to the config, split as
`rbstudy.inputs.text_table` splits a node table, whose first line may name the columns
``t x y z`` or ``time x y z`` (any case). Times increase strictly; there are two rows or
more. Between two rows the load is linear; before
the first row and after the last it is held at that row's value, as an amplitude table of
an FE code is.

Every bad row fails as a `SceneError` where it is: at its line of the file, or at its index
under the config key.
"""

from __future__ import annotations

import os
from array import array
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.errors import SceneError
from rbstudy.inputs.reader import Reader
from rbstudy.inputs.text_table import finite, table_lines

__all__ = ["LoadTable", "read_load_file", "inline_load_table", "COLUMNS"]

COLUMNS = ("t", "x", "y", "z")
_HEADERS = (COLUMNS, ("time",) + COLUMNS[1:])
_FIX = "give rows [t, x, y, z] with t in s, increasing"


@dataclass(frozen=True)
class LoadTable:
    """K rows: ``times`` (K,) s, increasing, and ``values`` (K, 3); the sha256 ``digest`` of
    its file (None inline: the config's own digest covers it)."""

    times: np.ndarray
    values: np.ndarray
    digest: str | None = None

    def at(self, times: np.ndarray) -> np.ndarray:
        """The load (T, 3) at ``times`` (T,): linear between rows, held outside them."""
        return np.stack([np.interp(times, self.times, column) for column in self.values.T], axis=-1)


def _checked(reader, rows, where, whole, digest=None):
    """The `LoadTable` of ``rows`` (K, 4); ``where(k)`` names row k, ``whole`` the table, for
    an error."""
    table = np.array(rows, dtype=float).reshape(-1, 4)
    if len(table) < 2:
        reader.fail(
            whole,
            f"a load table needs two rows or more, got {len(table)}",
            "a constant load is written [x, y, z]",
        )
    late = np.flatnonzero(np.diff(table[:, 0]) <= 0.0)
    if late.size:
        k = int(late[0]) + 1
        reader.fail(
            where(k),
            f"time {float(table[k, 0])!r} does not come after {float(table[k - 1, 0])!r}",
            "give the rows in increasing time, each time once",
        )
    return LoadTable(table[:, 0].copy(), table[:, 1:].copy(), digest)


def read_load_file(path: str | os.PathLike[str]) -> LoadTable:
    """The `LoadTable` of the file ``path``; a `SceneError` at the first bad line."""
    reader = Reader(str(path), SceneError)
    digest, records = table_lines(
        path, reader, "the load table", "give the path of a text file, relative to the config"
    )
    # flat arrays of doubles and of line numbers: a list of lists of floats takes ~200 bytes
    # a row
    rows, lines = array("d"), array("q")
    for number, fields in records:
        where = f"line {number}"
        if not rows and tuple(f.lower() for f in fields) in _HEADERS:
            continue
        if len(fields) != 4:
            reader.fail(where, f"expected 4 columns (t x y z), got {len(fields)}", _FIX)
        for column, field in zip(COLUMNS, fields, strict=True):
            value = finite(field)
            if value is None:
                reader.fail(
                    where,
                    f"{column} = {field!r:.40} is not a finite number",
                    f"{_FIX}; a first line may name the columns t x y z or time x y z",
                )
            rows.append(value)
        lines.append(number)
    return _checked(reader, rows, lambda k: f"line {lines[k]}", "table", digest)


def inline_load_table(reader: Reader, value: Any, key: str) -> LoadTable:
    """The `LoadTable` of rows given in the config at ``key`` (a list of [t, x, y, z])."""
    if not isinstance(value, list):
        reader.fail(key, f"expected rows [t, x, y, z] or a table file, got {value!r:.80}", _FIX)
    rows = [reader.vector(row, f"{key}[{k}]", length=4) for k, row in enumerate(value)]
    if any(isinstance(entry, np.ndarray) for row in rows for entry in row):
        reader.fail(
            key,
            "a number inside an inline load table cannot be swept",
            "write each table to a file and sweep the file name",
        )
    return _checked(reader, rows, lambda k: f"{key}[{k}]", key)
