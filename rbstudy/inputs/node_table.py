"""Node tables: the secondary nodes of an assembled body, read from a file.

A body of thousands of nodes is given as a table rather than inline (docs/config.md): one node
per line, columns ``id x y z mass`` and optionally the nodal inertia
``Ixx Iyy Izz Ixy Iyz Izx``, as `rbstudy.inputs.text_table` splits them (CSV or white
space, ``#`` comments); a first line starting with ``id`` names the columns and must name
these, in this order (any case). Units are those of the inline form: m, kg, kg m^2.

Every bad line fails as a `SceneError` placed in the table file at its line, naming the node,
so that the config that refers to the table need not be searched.
"""

import os
from collections import Counter
from dataclasses import dataclass

import numpy as np

from rbstudy.errors import SceneError
from rbstudy.inputs.reader import Reader
from rbstudy.inputs.text_table import finite, table_lines

__all__ = ["NodeTable", "read_node_table", "COLUMNS", "INERTIA_COLUMNS", "RESERVED"]

COLUMNS = ("id", "x", "y", "z", "mass")
INERTIA_COLUMNS = ("Ixx", "Iyy", "Izz", "Ixy", "Iyz", "Izx")
# The master node's name where loads are placed by node (`rbstudy.inputs.loads`).
RESERVED = "master"
_FORMAT = "id x y z mass [Ixx Iyy Izz Ixy Iyz Izx]"


@dataclass(frozen=True)
class NodeTable:
    """K nodes: ``names`` (K,), ``positions`` (K, 3) m, ``masses`` (K,) kg, ``inertias``
    (K, 6) kg m^2 as ``Ixx Iyy Izz Ixy Iyz Izx`` (zero where the table has no inertia
    columns), and the sha256 ``digest`` of the file's bytes (batch ids change when the table
    does)."""

    names: tuple
    positions: np.ndarray
    masses: np.ndarray
    inertias: np.ndarray
    digest: str


def read_node_table(path: str | os.PathLike[str]) -> NodeTable:
    """The `NodeTable` of the file ``path``; a `SceneError` at the first bad line."""
    reader = Reader(str(path), SceneError)
    digest, records = table_lines(
        path, reader, "the node table", "give the path of a text file, relative to the config"
    )
    names, lines, values, width = [], [], [], None
    for number, fields in records:
        where = f"line {number}"
        if width is None and fields[0].lower() == COLUMNS[0]:
            expected = [c.lower() for c in COLUMNS + INERTIA_COLUMNS][: len(fields)]
            if [f.lower() for f in fields] != expected or len(fields) not in (5, 11):
                reader.fail(
                    where,
                    f"the column names {' '.join(fields)!r:.80} are not {_FORMAT}",
                    "name the columns in that order, or leave the names out",
                )
            width = len(fields)
            continue
        if len(fields) not in (5, 11) or (width is not None and len(fields) != width):
            reader.fail(
                where,
                f"expected {width or '5 or 11'} columns ({_FORMAT}), got {len(fields)}",
                "give every node the same columns",
            )
        width = len(fields)
        name = fields[0]
        where = f"line {number} (node {name})"
        if name == RESERVED:
            reader.fail(where, f"{RESERVED!r} names the master node", "rename this node")
        row = []
        # 4 or 10 fields: the inertia columns are optional
        for column, field in zip(COLUMNS[1:] + INERTIA_COLUMNS, fields[1:], strict=False):
            value = finite(field)
            if value is None:
                reader.fail(
                    where,
                    f"{column} = {field!r:.40} is not a finite number",
                    "give finite numbers in m, kg, kg m^2",
                )
            row.append(value)
        if row[3] < 0.0:
            reader.fail(where, f"mass = {row[3]!r} must be >= 0", "give a mass >= 0 kg")
        names.append(name)
        lines.append(number)
        values.append(row)
    if not names:
        reader.fail("table", "the node table has no nodes", f"give one line per node: {_FORMAT}")
    duplicate = next((name for name, count in Counter(names).items() if count > 1), None)
    if duplicate is not None:
        twice = [line for line, name in zip(lines, names, strict=True) if name == duplicate]
        reader.fail(
            f"line {twice[1]} (node {duplicate})",
            f"node {duplicate} is given again (first on line {twice[0]})",
            "give each node one line",
        )
    table = np.array(values)
    inertias = table[:, 4:] if width == 11 else np.zeros((len(names), 6))
    return NodeTable(tuple(names), table[:, :3], table[:, 3], inertias, digest)
