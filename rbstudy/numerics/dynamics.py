"""Rigid-body physics on scalars: loads, Euler's equations, invariants.

Shared by every scheme so that all of them see the same loads (docs/theory.md, section 1):
moments enter Euler's equations in the body frame, forces the translation in space.
"""

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import add, axpy, cross, quat_rotate, quat_rotate_inverse, read3

__all__ = [
    "inertia", "to_momentum", "to_omega", "lever_moment", "has_lever", "body_moment",
    "space_force", "euler_rates", "momentum_rates", "rotational_energy", "momentum_squared", "is_moment_free",
]


@jit
def inertia(p):
    """Principal inertias ``(I1, I2, I3)`` of a parameter row ``p`` (N_PARAM,)."""
    return read3(p, S.INERTIA)


@jit
def to_momentum(w, inertia_):
    """Body angular momentum ``m = I w``."""
    return (inertia_[0] * w[0], inertia_[1] * w[1], inertia_[2] * w[2])


@jit
def to_omega(m, inertia_):
    """Body angular velocity ``w = I^-1 m``."""
    return (m[0] / inertia_[0], m[1] / inertia_[1], m[2] / inertia_[2])


@jit
def lever_moment(q, p):
    """Body-frame moment of space-fixed forces at body-fixed points (`S.LEVER`):
    ``sum_b e_b x R^T k_b`` with ``e_b x v`` written out."""
    a = quat_rotate_inverse(q, read3(p, S.LEVER))
    b = quat_rotate_inverse(q, read3(p, S.LEVER + 3))
    c = quat_rotate_inverse(q, read3(p, S.LEVER + 6))
    return (b[2] - c[1], c[0] - a[2], a[1] - b[0])


@jit
def has_lever(p):
    """True when space-fixed forces act at points off the centre of mass."""
    for k in range(9):
        if p[S.LEVER + k] != 0.0:
            return True
    return False


@jit
def body_moment(q, p):
    """Total moment in the body frame: body-fixed moment, the space moment turned in, and the
    moment of space-fixed forces at body-fixed points (skipped, three rotations, when none)."""
    moment = add(read3(p, S.MOMENT_BODY), quat_rotate_inverse(q, read3(p, S.MOMENT_SPACE)))
    if has_lever(p):
        moment = add(moment, lever_moment(q, p))
    return moment


@jit
def space_force(q, p):
    """Total force in space: space force, body-fixed force turned out, and weight."""
    mass = p[S.MASS]
    f = add(read3(p, S.FORCE_SPACE), quat_rotate(q, read3(p, S.FORCE_BODY)))
    return axpy(mass, read3(p, S.GRAVITY), f)


@jit
def euler_rates(w, inertia_, moment):
    """``dw/dt`` from Euler's equations ``I dw/dt = M - w x (I w)`` in the body frame."""
    i1, i2, i3 = inertia_
    return (
        (moment[0] - (i3 - i2) * w[1] * w[2]) / i1,
        (moment[1] - (i1 - i3) * w[2] * w[0]) / i2,
        (moment[2] - (i2 - i1) * w[0] * w[1]) / i3,
    )


@jit
def momentum_rates(m, w, moment):
    """``dm/dt = m x w + M`` for the body angular momentum ``m = I w``."""
    return add(cross(m, w), moment)


# The invariants, as `rbstudy.numerics.algebra` writes them for numpy code too.
rotational_energy = jit(algebra.rotational_energy)
momentum_squared = jit(algebra.momentum_squared)


@jit
def is_moment_free(p):
    """True when no moment acts, so that energy and angular momentum must be conserved."""
    for k in range(3):
        if p[S.MOMENT_BODY + k] != 0.0 or p[S.MOMENT_SPACE + k] != 0.0:
            return False
    return not has_lever(p)
