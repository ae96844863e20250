"""Reading a scene's loads: ``scene.loads`` of a study (docs/config.md) -> the `Loads` columns
of a `rbstudy.physics.scenes.SceneTable`.

Loads come constant (``[x, y, z]``) or tabulated in time (``{table: ..., scale: s}``,
`rbstudy.inputs.load_table`), at the centre of mass or at nodes; every kind is one of the
catalogue (`rbstudy.numerics.loads`). Loads at nodes are aggregated to the centre of mass as
they are read: ``F = sum F_i``, ``M = sum M_i + sum d_i x F_i``; a space force at a node
adds its lever ``d F^T`` (`rbstudy.numerics.state.LEVER`), which the kernels turn with the
body. Tabulated loads are evaluated at the union of all their tables' times (the knots) and
aggregated there alike (the sum is linear, so it is exact between knots too).
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.inputs.columns import (
    FileBinding,
    file_bindings,
    in_principal,
    one_row_if_alike,
    read_files,
    refuse,
    rows,
)
from rbstudy.inputs.load_table import inline_load_table, read_load_file
from rbstudy.inputs.reader import Reader
from rbstudy.numerics import state as S
from rbstudy.numerics.loads import KIND, LOAD_KINDS
from rbstudy.physics.loads import GIVEN, TABULATED, record_slice

__all__ = ["read_loads"]

# The kinds that may act at a node (`_add_nodal_loads`), and those given in body axes (turned
# into the principal frame with the body's other vectors).
_NODAL_LOADS = tuple(kind.name for kind in LOAD_KINDS if kind.at_nodes)
_IN_BODY_AXES = tuple(kind.name for kind in LOAD_KINDS if kind.frame == "body")


def _lever(offsets, forces):
    """The `Loads.lever` of space ``forces`` (n, ..., 3) at principal ``offsets`` (n, 3): the
    rows ``d[b] F`` of ``d F^T``, (n, ..., 9) (either may have one row for all n)."""
    product = _along(offsets, forces)[..., :, None] * forces[..., None, :]
    return product.reshape(product.shape[:-2] + (9,))


def _along(offsets, vectors):
    """``offsets`` (n, 3) shaped to broadcast against ``vectors`` (n, ..., 3)."""
    return offsets.reshape(offsets.shape[:1] + (1,) * (vectors.ndim - 2) + (3,))


@dataclass(frozen=True)
class _Timed:
    """A load tabulated in time in n scenes: the distinct `LoadTable`s, which one each scene
    takes (n,), the scale (n,) of its values, and the table files read
    (`rbstudy.inputs.columns.file_bindings`; none for a table given inline)."""

    tables: list
    index: np.ndarray
    scale: np.ndarray
    files: tuple = ()

    def at(self, knots):
        """The load (n, K, 3) at ``knots`` (K,); (1, K, 3) when the scenes share it."""
        values = np.stack([table.at(knots) for table in self.tables])[one_row_if_alike(self.index)]
        return values * one_row_if_alike(self.scale)[:, None, None]


def _read_timed(reader, spec, key, size):
    """The `_Timed` load of ``{table: rows or file, scale: s}`` at ``key``."""
    spec = reader.mapping(spec, key, ("table", "scale"))
    if "table" not in spec:
        reader.fail(
            f"{key}.table",
            "missing",
            "give rows [t, x, y, z] or a table file, or a constant [x, y, z] for the load",
        )
    scale = np.broadcast_to(reader.number(spec.get("scale", 1.0), f"{key}.scale"), (size,))
    table = spec["table"]
    if isinstance(table, list):
        return _Timed([inline_load_table(reader, table, f"{key}.table")], np.zeros(size, int), scale)
    names, tables, index = read_files(
        reader, table, f"{key}.table", size, read_load_file, "rows [t, x, y, z] or a load table file"
    )
    return _Timed(tables, index, scale, file_bindings(f"{key}.table", names, tables))


def _loaded_nodes(reader, spec, path, points):
    """The loads at nodes ``spec`` (node name -> {force_space, ...}, at ``path``), checked:
    ``(key, node name, its loads)`` for each node, which must be one of ``points``."""
    if not isinstance(spec, dict):
        reader.fail(path, f"expected a mapping of node name -> loads, got {spec!r:.80}")
    if len({str(name) for name in spec}) < len(spec):  # 56 and "56" in the YAML
        reader.fail(path, "a node is loaded twice (as a number and as text)", "load it once")
    checked = []
    for name, node_spec in spec.items():
        key = f"{path}.{name}"
        if str(name) not in points:
            reader.fail(
                key,
                "no such node in this body",
                "load a node of the scene's nodes (or master, for an assembled body)",
            )
        checked.append((key, str(name), reader.mapping(node_spec, key, _NODAL_LOADS)))
    return checked


def _timed_loads(reader, spec, path, nodal, size):
    """The loads tabulated in time under ``scene.loads`` (``spec``, at ``path``), at the
    centre and at the ``nodal`` loads (`_loaded_nodes`): key -> `_Timed`."""
    found = {f"{path}.{name}": spec[name] for name in TABULATED if isinstance(spec.get(name), dict)}
    found.update(
        {
            f"{key}.{name}": value
            for key, _, node_loads in nodal
            for name, value in node_loads.items()
            if isinstance(value, dict)
        }
    )
    return {key: _read_timed(reader, value, key, size) for key, value in found.items()}


class _LoadSets:
    """The loads of n scenes while they are read: the constant ones (name -> (n, 3), (n, 9)
    for the lever) and those tabulated in time at the ``knots`` (K,) (name -> (n, K, 3),
    (n, K, 9), or one row (1, K, ...) while every scene has the same), each added to as it
    is read."""

    def __init__(self, reader, timed, size):
        self.reader, self.timed, self.size = reader, timed, size
        self.knots = np.unique(
            np.concatenate([np.zeros(0)] + [table.times for load in timed.values() for table in load.tables])
        )
        self.constant = {kind.name: np.zeros((size, kind.width)) for kind in LOAD_KINDS}
        self.tabulated = {name: np.zeros((1, len(self.knots), KIND[name].width)) for name in TABULATED}

    def read(self, value, key):
        """The load at ``key``, constant (n, 3) or tabulated at the knots (n or 1, K, 3)."""
        if key in self.timed:
            return self.timed[key].at(self.knots)
        return rows(self.reader.vector(value, key), self.size)

    def add(self, name, value):
        """Add ``value`` ((n, w) or (n or 1, K, w), as `read` gives it) to the load ``name``."""
        loads = self.constant if value.ndim == 2 else self.tabulated
        loads[name] = loads[name] + value

    def hold(self):
        """Take out every force's push on the centre (the kinds that move it): a body held at
        a fixed point, whose reaction cancels it there; their moments stay."""
        for kind in LOAD_KINDS:
            if kind.moves_centre:
                self.constant[kind.name] = np.zeros_like(self.constant[kind.name])
                if kind.tabulated:
                    self.tabulated[kind.name] = np.zeros_like(self.tabulated[kind.name])

    def columns(self):
        """The `SceneTable.loads` columns: the constant loads, the knots and the records
        (read-only views, of one row when every scene has the same)."""
        shape = (self.size, len(self.knots))
        record = np.zeros((max(len(value) for value in self.tabulated.values()), shape[1], S.LOAD_RECORD))
        for name, values in self.tabulated.items():
            record[..., record_slice(name)] = values
        record.setflags(write=False)  # each scene's `Loads` holds a view of it
        return {
            **self.constant,
            "knots": np.broadcast_to(self.knots, shape),
            "tabulated": np.broadcast_to(record, shape + (S.LOAD_RECORD,)),
        }


def _add_nodal_loads(nodal, loads, points, axes):
    """Add the loads at nodes ``nodal`` (`_loaded_nodes`) to ``loads`` (a `_LoadSets`),
    aggregated to the centre of mass: ``F = sum F_i`` and ``M = sum M_i + sum d_i x F_i``
    with ``d_i`` the node's offset (``points``: name -> (n, 3), principal axes). A body-axis
    force gives a body moment; a space-axis force a moment that turns with the body (the
    lever, evaluated every step by the kernels). Constant and tabulated loads aggregate
    alike (each is linear in the nodal loads)."""
    for key, name, node_spec in nodal:
        offset = one_row_if_alike(points[name])
        for load, value in node_spec.items():
            given = loads.read(value, f"{key}.{load}")
            if load in _IN_BODY_AXES:
                given = in_principal(axes, given)
            loads.add(load, given)
            _add_moment(loads, load, given, offset)


def _add_moment(loads, load, given, offset):
    """Add to ``loads`` the moment of a force ``given`` of kind ``load`` (another kind: none)
    at principal ``offset`` (n, 3) from the point the body turns about: a body-axis force a
    body moment, a space-axis force one that turns with the body (the lever, evaluated every
    step by the kernels)."""
    if load == "force_space":
        loads.add("lever", _lever(offset, given))
    elif load == "force_body":
        loads.add("moment_body", np.cross(_along(offset, given), given))


def _below_zero(given: np.ndarray) -> Callable[[int], str]:
    """The message of a row of ``given`` (n, ...) that holds a value below 0."""
    return lambda row: f"got {given[row].tolist()}, below 0"


def read_loads(
    reader: Reader,
    spec: Any,
    path: str,
    points: Mapping[str, np.ndarray],
    axes: np.ndarray | None,
    first_moment: np.ndarray | None,
    size: int,
    held: np.ndarray | None = None,
) -> tuple[dict[str, np.ndarray], tuple[FileBinding, ...]]:
    """The `rbstudy.physics.scenes.SceneTable.loads` columns of the ``scene.loads`` block
    ``spec`` (at ``path``) of ``size`` scenes, and the load table files read
    (`rbstudy.inputs.columns.file_bindings`).

    ``points``: node name -> offsets (n, 3) in principal axes, the nodes a load may act at;
    ``axes`` (n, 3, 3): the principal axes in the input body frame as columns, None for the
    identity; ``first_moment`` (n, 3) kg m in principal axes: an assembled body's
    ``sum m_j d_j`` about its centre of mass, the lever of gravity (None: zero); ``held``
    (n, 3) m in principal axes: for a body turning about a fixed point (``scene.pivot``),
    its centre of mass from that point, where the forces of ``scene.loads`` act (their
    moments about the point are added, and no force moves the body: the point's reaction
    cancels it); None for a free body.
    """
    spec = reader.mapping(spec, path, GIVEN + ("nodes",))
    nodal = _loaded_nodes(reader, spec["nodes"], f"{path}.nodes", points) if "nodes" in spec else []
    loads = _LoadSets(reader, _timed_loads(reader, spec, path, nodal, size), size)
    for name in GIVEN:
        if name in spec:
            key = f"{path}.{name}"
            given = loads.read(spec[name], key)
            if KIND[name].dissipates:  # a negative value would feed energy in
                refuse(
                    reader,
                    np.any(given.reshape(len(given), -1) < 0.0, axis=-1),
                    key,
                    _below_zero(given),
                    f"give values >= 0 ({KIND[name].units}): it only takes energy out",
                )
            given = in_principal(one_row_if_alike(axes), given) if name in _IN_BODY_AXES else given
            loads.add(name, given)
            if held is not None:
                _add_moment(loads, name, given, one_row_if_alike(held))
    if first_moment is not None:
        # gravity pulls every mass point: about a centre that is not the centre of mass, its
        # moment is (sum m_j d_j) x g
        first_moment = one_row_if_alike(first_moment)
        for gravity in (loads.constant["gravity"], loads.tabulated["gravity"]):
            loads.add("lever", _lever(first_moment, gravity))
    _add_nodal_loads(nodal, loads, points, one_row_if_alike(axes))
    if held is not None:
        loads.hold()
    return loads.columns(), tuple(binding for load in loads.timed.values() for binding in load.files)
