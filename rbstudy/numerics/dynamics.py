"""Rigid-body physics on scalars: loads, Euler's equations, invariants.

Shared by every scheme so that all of them see the same loads (docs/theory.md, section 1):
moments enter Euler's equations in the body frame, forces the translation in space.
"""

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.jit import inline_jit, jit
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
    """Space-frame moment of space-fixed forces at body-fixed points (`S.LEVER`):
    ``sum_b c_b x k_b`` with ``c_b = R e_b`` the columns of the body's rotation."""
    x, y, z, w = q
    c1 = (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y))
    c2 = (2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x))
    c3 = (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))
    return add(add(cross(c1, read3(p, S.LEVER)), cross(c2, read3(p, S.LEVER + 3))),
               cross(c3, read3(p, S.LEVER + 6)))


@jit
def has_lever(p):
    """True when space-fixed forces act at points off the centre of mass."""
    for k in range(9):
        if p[S.LEVER + k] != 0.0:
            return True
    return False


@inline_jit
def body_moment(q, p):
    """Total moment in the body frame: the body-fixed moment, and the space moment with the
    moment of space-fixed forces at body-fixed points (skipped when there is none) turned in.
    Inlined by numba (`rbstudy.numerics.jit.inline_jit` says why)."""
    space = read3(p, S.MOMENT_SPACE)
    if has_lever(p):
        space = add(space, lever_moment(q, p))
    return add(read3(p, S.MOMENT_BODY), quat_rotate_inverse(q, space))


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
