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

This module imports nothing: importing it compiles nothing.
"""

__all__ = ["hamilton_product", "rotation_columns", "rotational_energy", "momentum_squared",
           "relative_drift", "momentum_excess", "circulation_axes"]


def hamilton_product(a, b):
    """Hamilton product ``a * b`` of scalar-last quaternions, as a 4-tuple of components."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return (
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    )


def rotation_columns(q):
    """The columns ``R e_1, R e_2, R e_3`` of the rotation of a unit quaternion ``q``
    (scalar last), three 3-tuples of components."""
    x, y, z, w = q
    return ((1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
            (2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
            (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)))


def rotational_energy(w, inertia):
    """Kinetic energy of rotation ``1/2 w . (I w)`` for principal inertias ``inertia``."""
    return 0.5 * (inertia[0] * w[0] * w[0] + inertia[1] * w[1] * w[1]
                  + inertia[2] * w[2] * w[2])


def momentum_squared(w, inertia):
    """``|I w|^2``, equal to ``|L|^2`` in space (a rotation keeps lengths)."""
    m0, m1, m2 = inertia[0] * w[0], inertia[1] * w[1], inertia[2] * w[2]
    return m0 * m0 + m1 * m1 + m2 * m2


def relative_drift(value, initial):
    """``|value - initial| / initial``, or the absolute change when ``initial`` (a scalar) is
    zero: a body at rest has nothing to be relative to."""
    if initial > 0.0:
        return abs(value - initial) / initial
    return abs(value - initial)


def momentum_excess(inertia, m, j):
    """``G^2 - 2 E I_j`` of a body with principal inertias ``inertia`` and body angular
    momentum ``m``, summed term by term (``sum_{n != j} m_n^2 (I_n - I_j) / I_n``): free of the
    cancellation of ``|m|^2 - I_j m . w`` when two moments nearly agree."""
    total = 0.0
    for k in range(3):
        if k != j:
            total += m[k] * m[k] * (inertia[k] - inertia[j]) / inertia[k]
    return total


def circulation_axes(inertia, excess):
    """The relabelling of a free body's principal axes (docs/theory.md s3), given the
    body's ``excess = (G^2 - 2 E I_j for j = 0, 1, 2)`` (`momentum_excess`): the indices
    ``(first, mid, third)``, ``third`` the axis the body circulates about (its largest when
    the excess of the intermediate axis ``mid`` is positive, else its smallest), and the sign
    (1.0 or -1.0) that ``first`` takes to keep the frame right-handed."""
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
