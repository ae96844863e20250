"""Formulas written once for two kinds of operands: scalars inside kernels, arrays elsewhere.

Each function takes sequences of components, ``a = (ax, ay, az, aw)`` or ``w = (w1, w2, w3)``,
and uses only ``+ - * /``. Numba compiles them into the scheme kernels (`rotation`,
`dynamics`, `driver` wrap them with ``jit``), where the components are floats held in
registers; numpy evaluates the very same expressions on component-first arrays (each component
an array over bodies and times: ``np.moveaxis(q, -1, 0)``) in the error measures and the
adaptive reference. One formula, so the kernels' invariant checks, the archive's error
measures and the reference scheme cannot disagree by the way they are written.

This module imports nothing: importing it compiles nothing.
"""

__all__ = ["hamilton_product", "rotation_columns", "rotational_energy", "momentum_squared",
           "relative_drift"]


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
