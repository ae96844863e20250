"""Reading an assembled body: the ``scene.assembly`` block of a study (docs/config.md) -> its
`rbstudy.physics.assembly.Assembly` and its secondary nodes.

A master node and secondary nodes, given inline (node name -> position, mass, inertia) or as
node table files (`rbstudy.inputs.node_table`), with the Radioss options; every bad value fails
through the scene's reader, naming the node. Every function takes columns of n scenes.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.inputs.columns import file_bindings, read_files, refuse, rows, symmetric_tensor
from rbstudy.inputs.node_table import RESERVED, read_node_table
from rbstudy.inputs.reader import Reader
from rbstudy.physics.assembly import CENTRES, DEGENERATE, Assembly, assemble

__all__ = ["Secondaries", "read_assembly"]

_KEYS = ("master", "nodes", "centre_of_mass", "spherical", "scale")
_NODE_KEYS = ("position", "mass", "inertia")
_MASTER_KEYS = ("position", "mass", "inertia")


@dataclass(frozen=True)
class Secondaries:
    """The secondary nodes of n scenes: ``names`` (K,), ``positions`` (n, K, 3) m, ``masses``
    (n, K) kg, ``inertias`` (n, K, 3, 3) kg m^2, and the node table files read
    (`rbstudy.inputs.columns.file_bindings`)."""

    names: tuple
    positions: np.ndarray
    masses: np.ndarray
    inertias: np.ndarray
    tables: tuple = ()


def _tensor_of_six(six):
    """Nodal inertias ``[Ixx, Iyy, Izz, Ixy, Iyz, Izx]`` (..., 6) -> (..., 3, 3)."""
    xx, yy, zz, xy, yz, zx = np.moveaxis(six, -1, 0)
    return np.stack([np.stack([xx, xy, zx], -1), np.stack([xy, yy, yz], -1), np.stack([zx, yz, zz], -1)], -2)


def _master_tensor(reader, value, key, size):
    """The master's added inertia: a number J (J on every axis) or a 3x3 tensor -> (size, 3, 3)."""
    if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) for r in value):
        return symmetric_tensor(reader, value, key, size)
    spherical = np.broadcast_to(reader.number(value, key), (size,))
    return spherical[:, None, None] * np.eye(3)


def _not_negative(reader, values, key, what):
    refuse(
        reader,
        values < 0.0,
        key,
        lambda row: f"{what} must be >= 0, got {float(values[row])!r}",
        "give a mass >= 0 kg",
    )


def _inline_nodes(reader, nodes, path, size):
    """`Secondaries` of a mapping node name -> {position, mass, inertia}."""
    names = tuple(str(name) for name in nodes)
    if len(set(names)) < len(names):  # 56 and "56" in the YAML
        reader.fail(path, "a node is given twice (as a number and as text)", "give it once")
    if RESERVED in names:
        reader.fail(f"{path}.{RESERVED}", f"{RESERVED!r} names the master node", "rename this node")
    positions, masses, inertias = [], [], []
    for name, node in nodes.items():
        key = f"{path}.{name}"
        node = reader.mapping(node, key, _NODE_KEYS)
        for needed in ("position", "mass"):
            if needed not in node:
                reader.fail(f"{key}.{needed}", "missing", "give every node a position (m) and a mass (kg)")
        positions.append(rows(reader.vector(node["position"], f"{key}.position"), size))
        mass = np.broadcast_to(reader.number(node["mass"], f"{key}.mass"), (size,))
        _not_negative(reader, mass, f"{key}.mass", "a node's mass")
        masses.append(mass)
        inertias.append(
            _tensor_of_six(rows(reader.vector(node["inertia"], f"{key}.inertia", length=6), size))
            if "inertia" in node
            else np.zeros((size, 3, 3))
        )
    return Secondaries(names, np.stack(positions, 1), np.stack(masses, 1), np.stack(inertias, 1))


def _tabled_nodes(reader, files, path, size):
    """`Secondaries` of node table files (`rbstudy.inputs.node_table`): one name, or a
    column of n (a sweep), each relative to the config; every table must name the same nodes
    in the same order, so that the scenes share their node axis."""
    distinct, tables, inverse = read_files(
        reader, files, path, size, read_node_table, "a node table file or a mapping of nodes"
    )
    for k in range(1, len(tables)):
        if tables[k].names != tables[0].names:
            reader.fail(
                path,
                f"the node tables {distinct[0]} and {distinct[k]} name different nodes",
                "a sweep over node tables needs the same node ids, in the same order, in every table",
                row=int(np.argmax(inverse == k)),
            )
    positions, masses, inertias = (
        np.stack([getattr(t, field) for t in tables])[inverse]
        for field in ("positions", "masses", "inertias")
    )
    return Secondaries(
        tables[0].names, positions, masses, _tensor_of_six(inertias), file_bindings(path, distinct, tables)
    )


def _read_secondaries(reader, nodes, path, size):
    if isinstance(nodes, dict) and nodes:
        return _inline_nodes(reader, nodes, path, size)
    if isinstance(nodes, (str, np.ndarray)):
        return _tabled_nodes(reader, nodes, path, size)
    reader.fail(
        path,
        f"expected a node table file or a mapping of node name -> {{position, mass}}, got {nodes!r:.80}",
        "give the secondary nodes",
    )


def _read_centre(reader, value, key):
    """`CENTRES` name, or a column of them (a sweep)."""
    names = np.asarray(value, dtype=object).reshape(-1)
    refuse(
        reader,
        ~np.isin(names, CENTRES),
        key,
        lambda row: f"expected one of {', '.join(CENTRES)}, got {names[row]!r:.80}",
    )
    return value


def read_assembly(reader: Reader, spec: Any, path: str, size: int) -> tuple[Assembly, Secondaries]:
    """The `Assembly` of the ``scene.assembly`` block ``spec`` (columns of ``size``) and its
    `Secondaries`; every bad value fails through ``reader``, naming the node."""
    spec = reader.mapping(spec, path, _KEYS)
    master = reader.mapping(spec.get("master"), f"{path}.master", _MASTER_KEYS)
    master_key = f"{path}.master"
    master_position = rows(
        reader.vector(master.get("position", [0.0, 0.0, 0.0]), f"{master_key}.position"), size
    )
    master_mass = np.broadcast_to(reader.number(master.get("mass", 0.0), f"{master_key}.mass"), (size,))
    _not_negative(reader, master_mass, f"{master_key}.mass", "the master's added mass")
    master_inertia = (
        _master_tensor(reader, master["inertia"], f"{master_key}.inertia", size)
        if "inertia" in master
        else np.zeros((size, 3, 3))
    )
    nodes = _read_secondaries(reader, spec.get("nodes"), f"{path}.nodes", size)
    scale = np.broadcast_to(reader.number(spec.get("scale", 1.0), f"{path}.scale", positive=True), (size,))
    positions = master_position[:, None, :] + scale[:, None, None] * (
        nodes.positions - master_position[:, None, :]
    )
    centre = _read_centre(reader, spec.get("centre_of_mass", "all"), f"{path}.centre_of_mass")
    spherical = reader.flag(spec.get("spherical", False), f"{path}.spherical")
    by_secondaries = np.broadcast_to(centre == "secondaries", (size,))
    weighed = nodes.masses.sum(axis=1) + np.where(by_secondaries, 0.0, master_mass)
    refuse(
        reader,
        weighed <= 0.0,
        f"{path}.nodes",
        lambda row: "the secondary nodes have no mass" if by_secondaries[row] else "the body has no mass",
        "give a node (or the master) a mass > 0 kg",
    )
    body = assemble(
        master_position,
        master_mass,
        master_inertia,
        positions,
        nodes.masses,
        nodes.inertias,
        centre,
        spherical,
    )
    refuse(
        reader,
        ~np.broadcast_to(spherical, (size,)) & (body.principal[:, 0] <= DEGENERATE * body.principal[:, 2]),
        f"{path}.nodes",
        lambda row: (
            f"principal inertias {body.principal[row].tolist()}: "
            "the nodes lie on one line (or at one point) and give no inertia about it"
        ),
        "add a node off that line, a nodal inertia, or the master's inertia, or set spherical: true",
    )
    return body, nodes
