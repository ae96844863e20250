"""Closed forms of rigid-body motion, and which reference applies to a scene: numpy and scipy
only (nothing here integrates, so the figures may draw a closed form without a compiler).

- ``symmetric_top``: force-free (moment-free) body with two equal principal inertias, any
  initial data (docs/theory.md s3): ``R(t) = Rot(L/|L|, |L| t/I1) R0 Rot(e3, -W t)``,
  ``w(t) = R(t)^T L / I1 - W e3`` with ``W = w3 (I3 - I1) / I1``, in the frame whose third
  axis is the symmetry axis.
- ``axial_moment``: a body spinning about a principal axis ``k`` under a constant body moment
  along that axis: ``w_k = w_k0 + M_k t / I_k``, ``R = R0 Rot(e_k, w_k0 t + M_k t^2 / (2 I_k))``.
- the centre of mass under constant space forces and uniform gravity follows the parabola
  ``x0 + v0 t + a t^2 / 2`` whatever the rotation does (`parabola`).
- the flip interval of a free asymmetric body and the precession frequency of a free
  symmetric one.

`reference_kinds` names the reference of each scene: one of the closed forms,
``exact_asymmetric`` for a free asymmetric body (Jacobi's elliptic functions, evaluated by
the compiled `rbstudy.numerics.free_flow`), or ``exact_split_composition`` for everything
else (moments other than an axial one, body-fixed forces, forces off the centre, loads that
vary in time): two integrations by `rbstudy.physics.references`, the exact-flow splitting
composed to order 8 at a fine step and scipy's DOP853 at rtol = atol = 1e-13, whose
difference is the reference's uncertainty (DOP853 is the reference where the composition
cannot be had).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from rbstudy.numerics import algebra
from rbstudy.numerics.loads import KIND
from rbstudy.physics.loads import TURNING, constant_acting
from rbstudy.physics.quaternions import quat_to_matrix, rotvec_quaternion

__all__ = [
    "REFERENCE_KINDS",
    "INTEGRATED",
    "SYMMETRY_RTOL",
    "symmetry_axes",
    "symmetry_axis",
    "symmetrised",
    "reference_kinds",
    "symmetric_top",
    "axial_moment",
    "parabola",
    "precession_frequencies",
    "precession_frequency_exact",
    "flip_interval",
    "flip_interval_exact",
    "separatrix_distance",
]

# Every reference an archive can name, in the order of their codes in the archive's
# `reference` flag (append only: archives store the codes). ``dop853`` and
# ``exact_split_composition`` are integrated, not closed; ``none`` marks a case whose
# integrated references both passed their step budgets (or failed): its errors against a
# reference are NaN. ``exact_asymmetric`` (appended after 0.3) is the exact free motion of any
# body, used where the body is not symmetric; ``exact_split_composition`` (appended after
# 0.3) is the tight reference of a loaded body, which until then was DOP853; ``lagrange_top``
# (appended after 0.4) is the exact motion of a symmetric body under a constant space force
# on its axis (`rbstudy.numerics.heavy_top`).
REFERENCE_KINDS = (
    "symmetric_top",
    "axial_moment",
    "dop853",
    "none",
    "exact_asymmetric",
    "exact_split_composition",
    "lagrange_top",
)
# The reference planned for a scene no closed form covers (the integrations may end with
# ``dop853`` or ``none`` instead).
INTEGRATED = "exact_split_composition"
# The kinds of load (`rbstudy.numerics.loads`) the closed forms here take (`reference_kinds`),
# and those of the Lagrange top.
_CLOSED_FORM_LOADS = ("force_space", "gravity", "moment_body")
_LAGRANGE_LOADS = ("force_space", "gravity", "lever")

# Two principal inertias closer than this, relative to the largest, are equal: the body is
# symmetric. The eigenvalues of a rotated or assembled inertia tensor carry a few ulps of
# round-off (diag(1, 1, 2) turned by a rotation comes back as 1.0, 1.0000000000000004, 2.0);
# 1e-12 leaves a thousand times that, and a body meant to be asymmetric differs by far more.
SYMMETRY_RTOL = 1e-12


def symmetry_axes(inertia: npt.ArrayLike) -> np.ndarray:
    """The symmetry axis (0, 1, 2) of bodies with principal inertias ``inertia`` (..., 3):
    the axis whose moment differs when the other two are equal within `SYMMETRY_RTOL`; -1 for
    an asymmetric body, 2 for a spherical one. The one answer every part of rbstudy uses."""
    inertia = np.asarray(inertia, dtype=float)
    i1, i2, i3 = np.moveaxis(inertia, -1, 0)
    return _symmetry_rule(i1, i2, i3, SYMMETRY_RTOL * np.max(inertia, axis=-1), np.where)


def _symmetry_rule(i1, i2, i3, tolerance, where):
    """The rule of `symmetry_axes`, written once for arrays (``where`` = `np.where`) and for
    three floats (`_pick`, far faster than numpy on three numbers: every `Body` asks it)."""
    return where(
        abs(i1 - i2) <= tolerance,
        2,
        where(abs(i2 - i3) <= tolerance, 0, where(abs(i1 - i3) <= tolerance, 1, -1)),
    )


def _pick(condition, chosen, otherwise):
    return chosen if condition else otherwise


def symmetry_axis(inertia: Sequence[float] | np.ndarray) -> int | None:
    """`symmetry_axes` of one body (3,): an index, or None for an asymmetric body."""
    i1, i2, i3 = (float(v) for v in inertia)
    axis = _symmetry_rule(i1, i2, i3, SYMMETRY_RTOL * max(i1, i2, i3), _pick)
    return None if axis < 0 else axis


def symmetrised(inertia: npt.ArrayLike) -> np.ndarray:
    """The principal inertias (..., 3) with the two transverse moments of each symmetric body
    set to their mean, so that equality is exact wherever it is used; an asymmetric body as it
    is. Returns a new float array."""
    inertia = np.array(inertia, dtype=float)
    axis = symmetry_axes(inertia)
    for k in range(3):
        first, second = (k + 1) % 3, (k + 2) % 3
        mean = 0.5 * (inertia[..., first] + inertia[..., second])
        inertia[..., first] = np.where(axis == k, mean, inertia[..., first])
        inertia[..., second] = np.where(axis == k, mean, inertia[..., second])
    return inertia


def symmetric_top(
    inertia: npt.ArrayLike, quaternion0: npt.ArrayLike, omega0: npt.ArrayLike, times: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form free motion of symmetric bodies (two equal principal inertias each).

    With ``s`` the symmetry axis, ``I_t`` the transverse and ``I_s`` the axial inertia,
    ``L = R0 I w0`` and ``W = w_s (I_s - I_t) / I_t``:
    ``R(t) = Rot(L/|L|, |L| t / I_t) R0 Rot(e_s, -W t)`` and ``w(t) = R(t)^T L / I_t - W e_s``
    (``I^-1 m = m / I_t - W e_s`` for a symmetric inertia). Vectorised over bodies.

    Parameters
    ----------
    inertia : (..., 3) principal inertias, two of them equal per body.
    quaternion0 : (..., 4) initial orientation (scalar-last, body to space).
    omega0 : (..., 3) initial body angular velocity (rad/s).
    times : (T,) s.

    Returns
    -------
    quaternion : (..., T, 4); omega_body : (..., T, 3).
    """
    inertia = np.asarray(inertia, dtype=float)
    omega0 = np.asarray(omega0, dtype=float)
    quaternion0 = np.asarray(quaternion0, dtype=float)
    axis = symmetry_axes(inertia)
    if np.any(axis < 0):
        raise ValueError(f"not a symmetric body: {inertia}")
    pick = axis[..., None]
    transverse = np.take_along_axis(inertia, (pick + 1) % 3, axis=-1)[..., 0]
    rate = (
        np.take_along_axis(omega0, pick, axis=-1)[..., 0]
        * (np.take_along_axis(inertia, pick, axis=-1)[..., 0] - transverse)
        / transverse
    )
    momentum = np.einsum("...ij,...j->...i", quat_to_matrix(quaternion0), inertia * omega0)
    spin = rate[..., None] * np.eye(3)[axis]  # (..., 3): W e_s
    # component-first, each component (..., T) (`rbstudy.numerics.algebra`'s formulas): laid
    # out (..., T, 4) the same arithmetic took far longer (a batch's references)
    t = np.asarray(times, dtype=float)
    precession = rotvec_quaternion([(momentum[..., k] / transverse)[..., None] * t for k in range(3)])
    spin_back = rotvec_quaternion([-spin[..., k, None] * t for k in range(3)])
    start = [quaternion0[..., k, None] for k in range(4)]
    quaternion = algebra.hamilton_product(algebra.hamilton_product(precession, start), spin_back)
    # w = R^T L / I_t - W e_s, R^T L summed in order as numpy's einsum sums a strided axis
    m = [momentum[..., k, None] for k in range(3)]
    omega = [
        ((c[0] * m[0] + c[1] * m[1]) + c[2] * m[2]) / transverse[..., None] - spin[..., i, None]
        for i, c in enumerate(algebra.rotation_columns(quaternion))
    ]
    return np.stack(quaternion, axis=-1), np.stack(omega, axis=-1)


def axial_moment(
    inertia: np.ndarray,
    quaternion0: np.ndarray,
    omega0: np.ndarray,
    moment_body: np.ndarray,
    times: npt.ArrayLike,
) -> tuple[np.ndarray, np.ndarray]:
    """Spin about principal axis ``k`` under a constant body moment along it (closed form).

    Requires ``omega0`` and ``moment_body`` (3,) to have non-zero entries only at the same
    axis ``k``. Returns quaternion (T, 4) and omega_body (T, 3).
    """
    k = int(_axial_indices([omega0], [moment_body])[0])
    if k < 0:
        raise ValueError("omega0 and the moment must both lie along one principal axis")
    times = np.asarray(times, dtype=float)
    rate = moment_body[k] / inertia[k]
    angle = omega0[k] * times + 0.5 * rate * times**2
    from scipy.spatial.transform import Rotation  # here: the figures import this module

    turn = np.zeros((times.size, 3))
    turn[:, k] = angle
    omega = np.zeros((times.size, 3))
    omega[:, k] = omega0[k] + rate * times
    return (Rotation.from_quat(quaternion0) * Rotation.from_rotvec(turn)).as_quat(), omega


def _axial_indices(omega0, moment_body):
    """(n,) the one principal axis that ``omega0`` and ``moment_body`` (n, 3) both lie along,
    or -1 where they do not."""
    support = (np.asarray(omega0) != 0.0) | (np.asarray(moment_body) != 0.0)
    return np.where(support.sum(axis=-1) == 1, support.argmax(axis=-1), -1)


def reference_kinds(
    inertia: npt.ArrayLike,
    omega_body: npt.ArrayLike,
    loads: Mapping[str, np.ndarray],
    timed: npt.ArrayLike = False,
) -> np.ndarray:
    """The reference of each of n scenes, names of `REFERENCE_KINDS` (n,), an object array:
    the exact solution that applies to its rotation and centre of mass, else `INTEGRATED`.
    Arguments are the
    scenes' principal inertias and initial body angular velocities, each (n, 3), their
    constant loads, a mapping of every kind of `rbstudy.numerics.loads` to columns (n, w),
    and ``timed`` (n,) (or one bool), True where a load varies in time
    (the closed forms here hold for constant loads only)."""
    # the closed forms take a force in space and gravity (a parabola, whatever the rotation
    # does) and a body moment along the spin axis; any other kind (a body-fixed force or a
    # space force off the centre, which turn with the body and couple translation and
    # rotation; a space moment; a load the catalogue gained since) needs the integration
    pushed = constant_acting(loads, [name for name in KIND if name not in _CLOSED_FORM_LOADS]) | np.asarray(
        timed, dtype=bool
    )
    moment_body = np.asarray(loads["moment_body"])
    moment_free = ~constant_acting(loads, TURNING)
    axial = _axial_indices(omega_body, moment_body) >= 0
    axis = symmetry_axes(inertia)
    symmetric = axis >= 0
    # a Lagrange top: symmetric, turned by space forces whose lever lies along the symmetry
    # axis only (rows k_b = d[b] F of `rbstudy.numerics.loads`, zero but the axis's), and by
    # nothing else
    rows = np.asarray(loads["lever"]).reshape(np.shape(loads["lever"])[:-1] + (3, 3))
    along = np.arange(3) == np.maximum(axis, 0)[..., None]  # (n, 3)
    lagrange = (
        symmetric
        & ~constant_acting(loads, [name for name in KIND if name not in _LAGRANGE_LOADS])
        & ~np.asarray(timed, dtype=bool)
        & np.all((rows == 0.0) | along[..., None], axis=(-2, -1))
        & np.any((rows != 0.0) & along[..., None], axis=(-2, -1))
    )
    # an object array of the few names, each shared by its scenes: as fixed-width text, a
    # million scenes' kinds took 88 MiB
    names = np.array(
        (INTEGRATED, "symmetric_top", "exact_asymmetric", "axial_moment", "lagrange_top"), dtype=object
    )
    chosen = np.where(pushed, 0, np.where(moment_free, np.where(symmetric, 1, 2), np.where(axial, 3, 0)))
    return names[np.where(lagrange, 4, chosen)]


def precession_frequencies(inertia: npt.ArrayLike, omega_body: npt.ArrayLike) -> np.ndarray:
    """Body-frame precession frequencies ``W = w_s (I_s - I_t) / I_t`` (rad/s) of free
    symmetric bodies about their symmetry axes ``s`` (``I_t`` the transverse inertia).

    Parameters
    ----------
    inertia : ndarray, shape (n, 3)
        Principal inertias, symmetrised (`symmetrised`), kg m^2.
    omega_body : ndarray, shape (n, 3)
        Initial body angular velocities, rad/s.

    Returns
    -------
    ndarray, shape (n,)
        rad/s; NaN for an asymmetric body.
    """
    inertia = np.asarray(inertia, dtype=float)
    axis = symmetry_axes(inertia)[:, None]
    pick = np.maximum(axis, 0)
    transverse = np.take_along_axis(inertia, (pick + 1) % 3, axis=1)[:, 0]
    axial = np.take_along_axis(inertia, pick, axis=1)[:, 0]
    spin = np.take_along_axis(np.asarray(omega_body, dtype=float), pick, axis=1)[:, 0]
    return np.where(axis[:, 0] >= 0, spin * (axial - transverse) / transverse, np.nan)


def precession_frequency_exact(scene: Any) -> float | None:
    """`precession_frequencies` of one ``scene`` (a `rbstudy.physics.scenes.Scene`, which
    imports this module): a float, or None unless the body is free and symmetric."""
    if scene.body.symmetry_axis is None or not scene.loads.moment_free:
        return None
    return float(precession_frequencies([scene.body.inertia], [scene.omega_body])[0])


def flip_interval_exact(scene: Any) -> float | None:
    """`flip_interval` of one ``scene`` (a `rbstudy.physics.scenes.Scene`): None for
    symmetric or loaded bodies."""
    if not scene.loads.moment_free or scene.body.symmetry_axis is not None:
        return None
    return flip_interval(scene.body.inertia, scene.omega_body)


def _modulus(inertia, omega_body):
    """``(lambda^2, k'^2)`` of a free asymmetric body (`flip_interval`), or None where it
    turns about a principal axis."""
    inertia = tuple(float(v) for v in inertia)
    m = tuple(i * float(w) for i, w in zip(inertia, omega_body, strict=True))
    excess = tuple(algebra.momentum_excess(inertia, m, j) for j in range(3))
    first, mid, third, _ = algebra.circulation_axes(inertia, excess)
    if excess[first] == 0.0 or excess[third] == 0.0:
        return None  # a steady spin about a principal axis: no sign change
    i1, i2, i3 = inertia[first], inertia[mid], inertia[third]
    rate2 = (i3 - i2) * excess[first] / (i1 * i2 * i3)
    return rate2, (i3 - i1) * excess[mid] / ((i3 - i2) * excess[first])


def flip_interval(inertia: Sequence[float] | np.ndarray, omega_body: Sequence[float] | np.ndarray) -> float:
    """Time between sign changes of the intermediate-axis rate of a free asymmetric body, s,
    of principal ``inertia`` (3,) and initial ``omega_body`` (3,).

    ``w_mid = a2 sn(lambda t + u0 | k^2)`` (docs/theory.md s3) changes sign every
    ``2 K(k^2) / |lambda|``: the Dzhanibekov flip interval near the intermediate axis, the
    half period of the wobble elsewhere. In the relabelled axes of docs/theory.md s3 (the
    circulation axis third, `algebra.circulation_axes`), with ``d_j = G^2 - 2E I_j`` summed
    term by term (`algebra.momentum_excess`): ``lambda^2 = (I3 - I2) d1 / (I1 I2 I3)`` and
    ``k'^2 = 1 - k^2 = (I3 - I1) d2 / ((I3 - I2) d1)``, from which ``K`` is taken
    (``ellipkm1``: accurate as ``k' -> 0``). NaN when the body turns about a principal axis
    (no sign change), inf on the separatrix.
    """
    modulus = _modulus(inertia, omega_body)
    if modulus is None:
        return float("nan")
    rate2, complement = modulus
    if complement <= 0.0:
        return float("inf")  # on the separatrix: one flip, never the next
    from scipy.special import ellipkm1  # here: the figures import this module

    return 2.0 * float(ellipkm1(complement)) / math.sqrt(rate2)


def separatrix_distance(
    inertia: Sequence[float] | np.ndarray, omega_body: Sequence[float] | np.ndarray
) -> float:
    """``k'^2 = 1 - k^2`` of a free asymmetric body (`flip_interval`): how far its motion lies
    from the separatrix, 0 on it; NaN for a spin about a principal axis. Near 0 the case is
    ill-conditioned: ``k'^2`` is a small difference of the spin's squares (``d2``), and the
    flip interval ``2 K / |lambda|`` grows as ``K ~ ln(4 / k')``."""
    modulus = _modulus(inertia, omega_body)
    return float("nan") if modulus is None else max(modulus[1], 0.0)


def parabola(
    position: npt.ArrayLike, velocity: npt.ArrayLike, acceleration: npt.ArrayLike, times: npt.ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """Centre-of-mass positions and velocities on the parabola ``x0 + v0 t + a t^2 / 2``
    (exact under constant space forces and gravity, whatever the rotation does).

    Parameters
    ----------
    position, velocity, acceleration : ndarray, shape (..., 3)
        m, m/s, m/s^2 at t = 0 (the acceleration: the space force over the mass, plus
        gravity).
    times : ndarray, shape (T,)
        s.

    Returns
    -------
    position, velocity : ndarray, shape (..., T, 3)
    """
    t = np.asarray(times, dtype=float)[:, None]
    position, velocity, acceleration = (
        np.asarray(v, dtype=float)[..., None, :] for v in (position, velocity, acceleration)
    )
    return position + velocity * t + 0.5 * acceleration * t**2, velocity + acceleration * t
