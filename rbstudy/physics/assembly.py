"""Rigid bodies assembled from nodes, as explicit crash codes build them (the Radioss rigid body).

A master node (position ``x_M``, optional added mass ``m_M`` and inertia tensor ``J_M``) and
secondary nodes (position ``x_i``, mass ``m_i``, optional nodal inertia tensor ``I_i``) make
one body, all in space axes at t = 0:

    m   = m_M + sum m_i
    x_G = (m_M x_M + sum m_i x_i) / m                       (``centre_of_mass: all``)
    I_G = J_M + m_M (|d_M|^2 1 - d_M d_M^T) + sum_i [I_i + m_i (|d_i|^2 1 - d_i d_i^T)]

with ``d = x - x_G`` (the parallel-axis rule in tensor form). The Radioss options: the centre
of mass from the secondaries only (``secondaries``) or pinned at the master (``master``), the
inertia still taken about it; ``spherical`` inertia (trace / 3 on every axis, so there is no
gyroscopic term); and the regularisation of a principal inertia below `REGULARISATION` of the
largest, raised to it. The scene (`rbstudy.physics.scenes`) diagonalises ``I_G`` as it does
any inertia tensor: the principal axes at t = 0 are the body's initial orientation, and the
node offsets ``d_i`` turned into them are its nodes.

Every function takes any leading scene axes (a sweep builds all its bodies at once).
"""

from dataclasses import dataclass

import numpy as np

from rbstudy.physics.columns import refuse, rows, symmetric_tensor

__all__ = ["Assembly", "assemble", "CENTRES", "REGULARISATION", "DEGENERATE"]

# Where the centre of mass is taken, Radioss's options.
CENTRES = ("all", "secondaries", "master")
# A principal inertia below this share of the largest is raised to it (with a warning).
REGULARISATION = 1e-3
# A principal inertia below this share of the largest is no inertia at all (round-off of a
# body whose nodes lie on one line): that body is refused unless spherical.
DEGENERATE = 1e-12


@dataclass(frozen=True)
class Assembly:
    """A body assembled from nodes, for n scenes (leading axes ``...``).

    mass : (...,) kg. centre : (..., 3) m, the centre of mass in space axes. tensor : (..., 3, 3)
    kg m^2, the inertia about it in space axes, after the options. offsets : (..., K, 3) m,
    each secondary node's ``x_i - x_G`` in space axes. principal : (..., 3) the principal
    inertias before any regularisation, ascending. regularised : (...,) True where a principal
    inertia was raised. lopsided : (...,) True where one principal inertia exceeds the sum of
    the other two (Radioss warns; the body is integrated as given).
    """

    mass: np.ndarray
    centre: np.ndarray
    tensor: np.ndarray
    offsets: np.ndarray
    principal: np.ndarray
    regularised: np.ndarray
    lopsided: np.ndarray


def _point_inertia(mass, offset):
    """``m (|d|^2 1 - d d^T)`` of point masses: mass (...,), offset (..., 3) -> (..., 3, 3)."""
    square = np.einsum("...i,...i->...", offset, offset)
    return mass[..., None, None] * (square[..., None, None] * np.eye(3)
                                    - offset[..., :, None] * offset[..., None, :])


def assemble(master_position, master_mass, master_inertia, positions, masses, inertias,
             centre="all", spherical=False):
    """The `Assembly` of a master node and K secondary nodes.

    Parameters
    ----------
    master_position : (..., 3) m. master_mass : (...,) kg, >= 0.
    master_inertia : (..., 3, 3) kg m^2, the master's added inertia tensor (symmetric).
    positions : (..., K, 3) m. masses : (..., K) kg, >= 0. inertias : (..., K, 3, 3) kg m^2.
    centre : one of `CENTRES`. spherical : every principal inertia trace / 3.

    The caller checks the input (finite, masses >= 0, a positive total): this is the formula.
    """
    total = master_mass + masses.sum(axis=-1)
    if centre == "master":
        centre_of_mass = master_position
    elif centre == "secondaries":
        centre_of_mass = (np.einsum("...k,...ki->...i", masses, positions)
                          / masses.sum(axis=-1)[..., None])
    else:
        centre_of_mass = (master_mass[..., None] * master_position
                          + np.einsum("...k,...ki->...i", masses, positions)) / total[..., None]
    offsets = positions - centre_of_mass[..., None, :]
    tensor = (master_inertia + _point_inertia(master_mass, master_position - centre_of_mass)
              + inertias.sum(axis=-3) + _point_inertia(masses, offsets).sum(axis=-3))
    tensor = 0.5 * (tensor + np.swapaxes(tensor, -1, -2))  # exactly symmetric
    principal, axes = np.linalg.eigh(tensor)
    largest = principal[..., 2:]
    lopsided = principal[..., 2] > principal[..., 0] + principal[..., 1]
    if spherical:
        trace = np.trace(tensor, axis1=-2, axis2=-1)
        tensor = (trace / 3.0)[..., None, None] * np.eye(3)
        regularised = np.zeros(total.shape, dtype=bool)
    else:
        floor = REGULARISATION * largest
        regularised = (principal < floor).any(axis=-1)
        raised = np.maximum(principal, floor)
        tensor = np.where(regularised[..., None, None],
                          np.einsum("...ij,...j,...kj->...ik", axes, raised, axes), tensor)
    return Assembly(total, centre_of_mass, tensor, offsets, principal, regularised, lopsided)


# --- reading the ``scene.assembly`` block ----------------------------------------------------

_KEYS = ("master", "nodes", "centre_of_mass", "spherical", "scale")
_NODE_KEYS = ("position", "mass", "inertia")
_MASTER_KEYS = ("position", "mass", "inertia")


def _nodal_tensor(reader, value, key, size):
    """A nodal inertia ``[Ixx, Iyy, Izz, Ixy, Iyz, Izx]`` -> (size, 3, 3)."""
    xx, yy, zz, xy, yz, zx = rows(reader.vector(value, key, length=6), size).T
    return np.stack([np.stack([xx, xy, zx], -1), np.stack([xy, yy, yz], -1),
                     np.stack([zx, yz, zz], -1)], -2)


def _master_tensor(reader, value, key, size):
    """The master's added inertia: a number J (J on every axis) or a 3x3 tensor -> (size, 3, 3)."""
    if isinstance(value, list) and len(value) == 3 and all(isinstance(r, list) for r in value):
        return symmetric_tensor(reader, value, key, size)
    spherical = np.broadcast_to(reader.number(value, key), (size,))
    return spherical[:, None, None] * np.eye(3)


def _not_negative(reader, values, key, what):
    refuse(reader, values < 0.0, key,
           lambda row: f"{what} must be >= 0, got {float(values[row])!r}", "give a mass >= 0 kg")


def read_assembly(reader, spec, path, size):
    """The `Assembly` of the ``scene.assembly`` block ``spec`` (columns of ``size``) and its
    secondary node names; every bad value fails through ``reader``, naming the node."""
    spec = reader.mapping(spec, path, _KEYS)
    master = reader.mapping(spec.get("master"), f"{path}.master", _MASTER_KEYS)
    master_key = f"{path}.master"
    master_position = rows(reader.vector(master.get("position", [0.0, 0.0, 0.0]),
                                             f"{master_key}.position"), size)
    master_mass = np.broadcast_to(reader.number(master.get("mass", 0.0), f"{master_key}.mass"),
                                  (size,))
    _not_negative(reader, master_mass, f"{master_key}.mass", "the master's added mass")
    master_inertia = (_master_tensor(reader, master["inertia"], f"{master_key}.inertia", size)
                      if "inertia" in master else np.zeros((size, 3, 3)))
    nodes = spec.get("nodes")
    if not isinstance(nodes, dict) or not nodes:
        reader.fail(f"{path}.nodes", f"expected a mapping of node name -> {{position, mass}}, "
                                     f"got {nodes!r:.80}", "give the secondary nodes")
    names = tuple(str(name) for name in nodes)
    positions, masses, inertias = [], [], []
    for name, node in nodes.items():
        key = f"{path}.nodes.{name}"
        node = reader.mapping(node, key, _NODE_KEYS)
        for needed in ("position", "mass"):
            if needed not in node:
                reader.fail(f"{key}.{needed}", "missing", "give every node a position (m) and "
                                                          "a mass (kg)")
        positions.append(rows(reader.vector(node["position"], f"{key}.position"), size))
        mass = np.broadcast_to(reader.number(node["mass"], f"{key}.mass"), (size,))
        _not_negative(reader, mass, f"{key}.mass", "a node's mass")
        masses.append(mass)
        inertias.append(_nodal_tensor(reader, node["inertia"], f"{key}.inertia", size)
                        if "inertia" in node else np.zeros((size, 3, 3)))
    positions, masses, inertias = (np.stack(positions, 1), np.stack(masses, 1),
                                   np.stack(inertias, 1))
    scale = np.broadcast_to(reader.number(spec.get("scale", 1.0), f"{path}.scale",
                                          positive=True), (size,))
    positions = master_position[:, None, :] + scale[:, None, None] * (
        positions - master_position[:, None, :])
    centre = spec.get("centre_of_mass", "all")
    if centre not in CENTRES:
        reader.fail(f"{path}.centre_of_mass", f"expected one of {', '.join(CENTRES)}, got "
                                              f"{centre!r:.80}")
    spherical = reader.flag(spec.get("spherical", False), f"{path}.spherical")
    weighed = masses.sum(axis=1) + (0.0 if centre == "secondaries" else master_mass)
    refuse(reader, weighed <= 0.0, f"{path}.nodes",
           lambda row: "the secondary nodes have no mass" if centre == "secondaries"
           else "the body has no mass", "give a node (or the master) a mass > 0 kg")
    body = assemble(master_position, master_mass, master_inertia, positions, masses, inertias,
                    centre, spherical)
    if not spherical:
        refuse(reader, body.principal[:, 0] <= DEGENERATE * body.principal[:, 2],
               f"{path}.nodes", lambda row: f"principal inertias {body.principal[row].tolist()}: "
               "the nodes lie on one line (or at one point) and give no inertia about it",
               "add a node off that line, a nodal inertia, or the master's inertia, or set "
               "spherical: true")
    return body, names
