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
largest, raised to it. The scene reader (`rbstudy.inputs.scenes`) diagonalises ``I_G`` as it does
any inertia tensor: the principal axes at t = 0 are the body's initial orientation, and the
node offsets ``d_i`` turned into them are its nodes.

Every function takes any leading scene axes (a sweep builds all its bodies at once).
"""

from dataclasses import dataclass

import numpy as np

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
    the other two (Radioss warns; the body is integrated as given). master_offset : (..., 3) m,
    the master's ``x_M - x_G``. first_moment : (..., 3) kg m, ``m_M d_M + sum m_i d_i``: zero
    about the centre of mass, the lever of gravity about a centre taken elsewhere.
    """

    mass: np.ndarray
    centre: np.ndarray
    tensor: np.ndarray
    offsets: np.ndarray
    master_offset: np.ndarray
    first_moment: np.ndarray
    principal: np.ndarray
    regularised: np.ndarray
    lopsided: np.ndarray


def _point_inertia(mass, offset):
    """``m (|d|^2 1 - d d^T)`` of point masses: mass (...,), offset (..., 3) -> (..., 3, 3)."""
    square = np.einsum("...i,...i->...", offset, offset)
    return mass[..., None, None] * (
        square[..., None, None] * np.eye(3) - offset[..., :, None] * offset[..., None, :]
    )


def assemble(
    master_position: np.ndarray,
    master_mass: np.ndarray,
    master_inertia: np.ndarray,
    positions: np.ndarray,
    masses: np.ndarray,
    inertias: np.ndarray,
    centre: str | np.ndarray = "all",
    spherical: bool | np.ndarray = False,
) -> Assembly:
    """The `Assembly` of a master node and K secondary nodes.

    Parameters
    ----------
    master_position : (..., 3) m. master_mass : (...,) kg, >= 0.
    master_inertia : (..., 3, 3) kg m^2, the master's added inertia tensor (symmetric).
    positions : (..., K, 3) m. masses : (..., K) kg, >= 0. inertias : (..., K, 3, 3) kg m^2.
    centre : one of `CENTRES`, or (...,) of them. spherical : every principal inertia
    trace / 3; a flag, or (...,) flags.

    The caller checks the input (finite, masses >= 0, a positive total): this is the formula.
    """
    total = master_mass + masses.sum(axis=-1)
    centre = np.broadcast_to(np.asarray(centre, dtype=object), total.shape)
    spherical = np.broadcast_to(np.asarray(spherical, dtype=bool), total.shape)
    weighted = np.einsum("...k,...ki->...i", masses, positions)
    with np.errstate(invalid="ignore", divide="ignore"):  # the options a row does not take
        by_secondaries = weighted / masses.sum(axis=-1)[..., None]
        by_all = (master_mass[..., None] * master_position + weighted) / total[..., None]
    centre_of_mass = np.where(
        (centre == "master")[..., None],
        master_position,
        np.where((centre == "secondaries")[..., None], by_secondaries, by_all),
    )
    offsets = positions - centre_of_mass[..., None, :]
    master_offset = master_position - centre_of_mass
    # written so that what vanishes vanishes exactly, not to round-off, and gravity alone
    # leaves such a body moment-free (its energy a conserved quantity): the whole first
    # moment about the centre of mass, the secondaries' about their own centre
    first_moment = np.where(
        (centre == "all")[..., None],
        0.0,
        np.where(
            (centre == "secondaries")[..., None],
            master_mass[..., None] * master_offset,
            np.einsum("...k,...ki->...i", masses, offsets),
        ),
    )
    tensor = (
        master_inertia
        + _point_inertia(master_mass, master_offset)
        + inertias.sum(axis=-3)
        + _point_inertia(masses, offsets).sum(axis=-3)
    )
    tensor = 0.5 * (tensor + np.swapaxes(tensor, -1, -2))  # exactly symmetric
    principal, axes = np.linalg.eigh(tensor)
    largest = principal[..., 2:]
    lopsided = principal[..., 2] > principal[..., 0] + principal[..., 1]
    floor = REGULARISATION * largest
    regularised = ~spherical & (principal < floor).any(axis=-1)
    raised = np.einsum("...ij,...j,...kj->...ik", axes, np.maximum(principal, floor), axes)
    trace = np.trace(tensor, axis1=-2, axis2=-1)
    tensor = np.where(
        spherical[..., None, None],
        (trace / 3.0)[..., None, None] * np.eye(3),
        np.where(regularised[..., None, None], raised, tensor),
    )
    return Assembly(
        total, centre_of_mass, tensor, offsets, master_offset, first_moment, principal, regularised, lopsided
    )
