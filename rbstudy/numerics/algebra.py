"""Formulas written once for two kinds of operands: scalars inside kernels, arrays elsewhere.

Each function takes sequences of components, ``a = (ax, ay, az, aw)`` or ``w = (w1, w2, w3)``,
and uses only ``+ - * /``. Numba compiles them into the scheme kernels (`rotation`,
`dynamics`, `driver` wrap them with ``jit``), where the components are floats held in
registers; numpy evaluates the very same expressions on component-first arrays (each component
an array over bodies and times: ``np.moveaxis(q, -1, 0)``) in the error measures and the
adaptive reference. One formula, so the kernels' invariant checks, the archive's error
measures and the reference scheme cannot disagree by the way they are written.

The last two, the relabelling of a free body's axes (docs/theory.md s3), branch and take
three floats: the exact flow compiles them (`free_flow`) and the numba-free flip interval
(`rbstudy.physics.analytic`) calls them as Python.

This module imports nothing outside the standard library: importing it compiles
nothing. A component (`Component`) is a float in a kernel, an array over bodies and times
elsewhere.
"""

from collections.abc import Iterator
from typing import Any, Protocol

# A float inside a kernel, a numpy array of any shape in the numpy code.
Component = Any


class Components(Protocol):
    """Components read by index: a tuple in a kernel, a component-first array elsewhere."""

    def __getitem__(self, index: int, /) -> Any: ...

    def __iter__(self) -> Iterator[Any]: ...


__all__ = [
    "hamilton_product",
    "rotation_columns",
    "rotational_energy",
    "momentum_squared",
    "relative_drift",
    "momentum_excess",
    "circulation_axes",
]


def hamilton_product(a: Components, b: Components) -> tuple[Component, Component, Component, Component]:
    """Hamilton product ``a * b`` of scalar-last quaternions.

    Parameters
    ----------
    a, b : sequence of 4 floats, or of 4 arrays of one shape
        Components ``(x, y, z, w)``: floats in a kernel, component-first arrays in numpy.

    Returns
    -------
    tuple of 4
        The components of ``a * b``, of the operands' kind.
    """
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotation_columns(q: Components) -> tuple[tuple[Component, ...], ...]:
    """The columns ``R e_1, R e_2, R e_3`` of the rotation of a unit quaternion.

    Parameters
    ----------
    q : sequence of 4 floats, or of 4 arrays of one shape
        ``(x, y, z, w)``, scalar last, body to space.

    Returns
    -------
    tuple of 3 tuples of 3
        The three columns, each as its components.
    """
    x, y, z, w = q
    return (
        (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        (2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    )


def rotational_energy(w: Components, inertia: Components) -> Component:
    """Kinetic energy of rotation ``1/2 w . (I w)`` for principal inertias.

    Parameters
    ----------
    w : sequence of 3 floats, or of 3 arrays of one shape
        Body angular velocity (rad/s).
    inertia : sequence of 3 floats, or of 3 arrays broadcasting against ``w``'s
        Principal inertias (kg m^2).

    Returns
    -------
    float or array of the operands' shape
        J.
    """
    return 0.5 * (inertia[0] * w[0] * w[0] + inertia[1] * w[1] * w[1] + inertia[2] * w[2] * w[2])


def momentum_squared(w: Components, inertia: Components) -> Component:
    """``|I w|^2``, equal to ``|L|^2`` in space (a rotation keeps lengths).

    Parameters
    ----------
    w : sequence of 3 floats, or of 3 arrays of one shape
        Body angular velocity (rad/s).
    inertia : sequence of 3 floats, or of 3 arrays broadcasting against ``w``'s
        Principal inertias (kg m^2).

    Returns
    -------
    float or array of the operands' shape
        (kg m^2/s)^2.
    """
    m0, m1, m2 = inertia[0] * w[0], inertia[1] * w[1], inertia[2] * w[2]
    return m0 * m0 + m1 * m1 + m2 * m2


def relative_drift(value: Component, initial: Component) -> Component:
    """``|value - initial| / initial``, or the absolute change when ``initial`` is zero: a body
    at rest has nothing to be relative to.

    Parameters
    ----------
    value : float or array
        The quantity now.
    initial : float
        The quantity at the start, >= 0 (a scalar: it picks the formula).

    Returns
    -------
    float or array of ``value``'s shape
    """
    if initial > 0.0:
        return abs(value - initial) / initial
    return abs(value - initial)


def momentum_excess(inertia: Components, m: Components, j: int) -> float:
    """``G^2 - 2 E I_j`` of a body, summed term by term (``sum_{n != j} m_n^2 (I_n - I_j) /
    I_n``): free of the cancellation of ``|m|^2 - I_j m . w`` when two moments nearly agree.

    Parameters
    ----------
    inertia : sequence of 3 floats
        Principal inertias (kg m^2).
    m : sequence of 3 floats
        Body angular momentum ``I w`` (kg m^2/s).
    j : int
        The axis (0, 1, 2).

    Returns
    -------
    float
        (kg m^2/s)^2.
    """
    total = 0.0
    for k in range(3):
        if k != j:
            total += m[k] * m[k] * (inertia[k] - inertia[j]) / inertia[k]
    return total


def circulation_axes(inertia: Components, excess: Components) -> tuple[int, int, int, float]:
    """The relabelling of a free body's principal axes (docs/theory.md s3).

    Parameters
    ----------
    inertia : sequence of 3 floats
        Principal inertias (kg m^2), any order.
    excess : sequence of 3 floats
        ``G^2 - 2 E I_j`` for j = 0, 1, 2 (`momentum_excess`).

    Returns
    -------
    first, mid, third : int
        Axis indices: ``third`` the axis the body circulates about (its largest when the
        excess of the intermediate axis ``mid`` is positive, else its smallest).
    sign : float
        1.0 or -1.0, the sign ``first`` takes to keep the frame right-handed.
    """
    lo, mid, hi = 0, 1, 2
    if inertia[lo] > inertia[mid]:
        lo, mid = mid, lo
    if inertia[mid] > inertia[hi]:
        mid, hi = hi, mid
    if inertia[lo] > inertia[mid]:
        lo, mid = mid, lo
    if excess[mid] > 0.0:
        first, third = lo, hi
    else:
        first, third = hi, lo
    return first, mid, third, (1.0 if mid == (first + 1) % 3 else -1.0)
