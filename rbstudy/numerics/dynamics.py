"""Rigid-body physics on scalars: loads, Euler's equations, invariants.

Shared by every scheme so that all of them see the same loads (docs/theory.md, section 1):
moments enter Euler's equations in the body frame, forces the translation in space. A moment
may depend on the orientation, on the spin (the damping moment ``-C w``: `body_moment` takes
the body's ``w``) and on the time: loads may be tabulated in time
(`rbstudy.numerics.state.KNOTS`), so every evaluation of them takes the time ``t`` at which
the scheme asks, or None in a batch without such loads or a damping moment
(`rbstudy.numerics.clock` says why).
"""

import math

from rbstudy.numerics import algebra
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import without_time
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.loads import KIND, TURNING_RECORD_SLOTS, TURNING_SLOTS
from rbstudy.numerics.rotation import (
    add,
    axpy,
    cross,
    quat_rotate,
    quat_rotate_inverse,
    read3,
    sub,
)
from rbstudy.numerics.space_loads import has_lever, lever_moment, tabulated_force, tabulated_moment

__all__ = [
    "inertia",
    "to_momentum",
    "to_omega",
    "spin_damping",
    "has_damping",
    "damping_resistance",
    "kick_shortfall",
    "timed_moment",
    "timed_force",
    "timed_damping",
    "timed_shortfall",
    "body_moment",
    "moment_from",
    "force_from",
    "kick_momentum",
    "space_force",
    "euler_rates",
    "momentum_rates",
    "rotational_energy",
    "momentum_squared",
    "is_moment_free",
]

# Where the damping moment's coefficients sit in a parameter row.
_DAMPING = KIND["damping_moment"].offset


@jit
def inertia(p):
    """Principal inertias ``(I1, I2, I3)`` of a parameter row.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    tuple of 3 floats
        kg m^2.
    """
    return read3(p, S.INERTIA)


@jit
def to_momentum(w, inertia_):
    """Body angular momentum ``m = I w``.

    Parameters
    ----------
    w : tuple of 3 floats
        Body angular velocity (rad/s).
    inertia_ : tuple of 3 floats
        Principal inertias (kg m^2).

    Returns
    -------
    tuple of 3 floats
        kg m^2/s.
    """
    return (inertia_[0] * w[0], inertia_[1] * w[1], inertia_[2] * w[2])


@jit
def to_omega(m, inertia_):
    """Body angular velocity ``w = I^-1 m``.

    Parameters
    ----------
    m : tuple of 3 floats
        Body angular momentum (kg m^2/s).
    inertia_ : tuple of 3 floats
        Principal inertias (kg m^2).

    Returns
    -------
    tuple of 3 floats
        rad/s.
    """
    return (m[0] / inertia_[0], m[1] / inertia_[1], m[2] / inertia_[2])


@jit
def spin_damping(p):
    """The coefficients ``C`` (N m s, principal axes) of the linear damping moment ``-C w``
    (`rbstudy.numerics.loads`: ``damping_moment``): minus the moment's derivative in ``w``,
    which the implicit schemes' Newton iterations take.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    tuple of 3 floats
        N m s, principal body axes.
    """
    return read3(p, _DAMPING)


@jit
def has_damping(p):
    """True when a damping moment acts.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    bool
    """
    return p[_DAMPING] != 0.0 or p[_DAMPING + 1] != 0.0 or p[_DAMPING + 2] != 0.0


@jit
def damping_resistance(w, p, t):
    """``C w``, minus the damping moment on a body turning at ``w``; zero for a row without
    (``t`` unused: a function the kernels with the time carry, `timed_damping`).

    Parameters
    ----------
    w : tuple of 3 floats
        Angular velocity, rad/s, body axes.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float
        Time (s), unused.

    Returns
    -------
    tuple of 3 floats
        N m, body axes.
    """
    if not has_damping(p):
        return (0.0, 0.0, 0.0)
    c = spin_damping(p)
    return (c[0] * w[0], c[1] * w[1], c[2] * w[2])


@jit
def kick_shortfall(d, p, t):
    """How much less than the kick's length ``d`` each axis's damped momentum takes the
    moment for: ``d - (1 - exp(-k_i d)) / k_i`` with ``k_i = C_i / I_i`` (0 where ``C_i`` is;
    zero for a row without damping; ``t`` unused, as in `damping_resistance`). expm1 keeps it
    exact to round-off at small ``k_i d``.

    Parameters
    ----------
    d : float
        The kick's length (s).
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float
        Time (s), unused.

    Returns
    -------
    tuple of 3 floats
        s, per principal axis.
    """
    if not has_damping(p):
        return (0.0, 0.0, 0.0)
    c, inertia_ = spin_damping(p), inertia(p)
    return (
        _shortfall(c[0] / inertia_[0], d),
        _shortfall(c[1] / inertia_[1], d),
        _shortfall(c[2] / inertia_[2], d),
    )


@jit
def _shortfall(rate, d):
    if rate == 0.0:
        return 0.0
    return d + math.expm1(-rate * d) / rate


# The tabulated loads, and the damping moment, where the kernels are given the time (the
# catalogue's `timed_kernels`), nothing where they are not.
timed_moment = without_time(tabulated_moment)
timed_force = without_time(tabulated_force)
timed_damping = without_time(damping_resistance)
timed_shortfall = without_time(kick_shortfall)


@inline_jit
def body_moment(q, w, p, t):
    """Total moment in the body frame on a body at orientation ``q`` turning at ``w`` at time
    ``t``: the body-fixed moment, the space moment with the moment of space-fixed forces at
    body-fixed points (skipped when there is none) turned in, the loads tabulated in time
    (`timed_moment`) and the damping moment ``-C w`` (`timed_damping`: both only in the
    kernels with the time). Inlined by numba (`rbstudy.numerics.jit.inline_jit` says why).

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    w : tuple of 3 floats
        Angular velocity, rad/s, body axes.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float or None
        Time (s); None in a batch without loads tabulated in time or damping
        (`rbstudy.numerics.clock`).

    Returns
    -------
    tuple of 3 floats
        N m, body axes.
    """
    space = read3(p, S.MOMENT_SPACE)
    if has_lever(p):
        space = add(space, lever_moment(q, read3(p, S.LEVER), read3(p, S.LEVER + 3), read3(p, S.LEVER + 6)))
    return moment_from(q, w, p, t, read3(p, S.MOMENT_BODY), space)


@inline_jit
def moment_from(q, w, p, t, body, space):
    """`body_moment` from its constant parts: the body-fixed moment ``body`` and the space
    moment ``space`` (N m, with that of a lever), to which the loads of the time are added.
    The block step of a scheme (`rbstudy.numerics.block`) calls it with ``t`` None, where
    ``p`` is never read.

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    w : tuple of 3 floats
        Angular velocity, rad/s, body axes.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM; anything where ``t`` is None.
    t : float or None
        Time (s).
    body, space : tuple of 3 floats
        N m, body and space axes.

    Returns
    -------
    tuple of 3 floats
        N m, body axes.
    """
    return sub(add(add(body, quat_rotate_inverse(q, space)), timed_moment(q, p, t)), timed_damping(w, p, t))


@inline_jit
def kick_momentum(q, w, p, t, d):
    """The change of the body angular momentum ``m = I w`` in a kick, the loads acting for a
    time ``d`` with the orientation ``q`` and the time ``t`` held (the splitting schemes'
    half kicks, `rbstudy.schemes._kicks`): ``d M`` with ``M = body_moment(q, w, p, t)``.

    Under a damping moment ``-C w`` the kick is the exact flow of ``dm_i/dt = M0_i -
    (C_i / I_i) m_i`` (``M0`` the other loads, held): ``dm_i = (1 - exp(-k_i d)) / k_i M_i``
    with ``k_i = C_i / I_i``, written ``(d - s_i) M_i`` (`kick_shortfall`). It is its own
    inverse at ``-d``, so that the symmetric schemes stay symmetric, keep their order and
    compose to higher ones (a plain ``d M`` would cost them their second order).

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    w : tuple of 3 floats
        Angular velocity, rad/s, body axes.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float or None
        Time (s); None in a batch without loads tabulated in time or damping.
    d : float
        The kick's length (s).

    Returns
    -------
    tuple of 3 floats
        N m s, body axes.
    """
    moment = body_moment(q, w, p, t)
    short = timed_shortfall(d, p, t)
    return ((d - short[0]) * moment[0], (d - short[1]) * moment[1], (d - short[2]) * moment[2])


@inline_jit
def space_force(q, p, t):
    """Total force in space: space force, body-fixed force turned out, weight, and the loads
    tabulated in time (`timed_force`). Inlined, as `body_moment` is.

    A body without a body-fixed force skips its rotation (a rotated zero is zero: the same
    numbers): the force then no longer waits on the orientation, and the 30 operations of
    the rotation leave every step. The same branch on the space moment in `body_moment` made
    leapfrog and euler slower (the compiled code was laid out worse) and was dropped.

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).
    t : float or None
        Time (s); None in a batch without loads tabulated in time (`rbstudy.numerics.clock`).

    Returns
    -------
    tuple of 3 floats
        N, space axes.
    """
    if p[S.FORCE_BODY] != 0.0 or p[S.FORCE_BODY + 1] != 0.0 or p[S.FORCE_BODY + 2] != 0.0:
        f = add(read3(p, S.FORCE_SPACE), quat_rotate(q, read3(p, S.FORCE_BODY)))
    else:
        f = read3(p, S.FORCE_SPACE)
    return force_from(q, p, t, p[S.MASS], read3(p, S.GRAVITY), f)


@inline_jit
def force_from(q, p, t, mass, gravity, space):
    """`space_force` from its constant parts: the weight ``mass gravity`` and the force in
    space ``space`` (N, the body-fixed force turned in), to which the loads of the time are
    added; ``p`` is never read where ``t`` is None (as in `moment_from`).

    Parameters
    ----------
    q : tuple of 4 floats
        Orientation, scalar last, body to space.
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM; anything where ``t`` is None.
    t : float or None
        Time (s).
    mass : float
        kg.
    gravity, space : tuple of 3 floats
        m/s^2 and N, space axes.

    Returns
    -------
    tuple of 3 floats
        N, space axes.
    """
    return add(axpy(mass, gravity, space), timed_force(q, p, t))


@jit
def euler_rates(w, inertia_, moment):
    """``dw/dt`` from Euler's equations ``I dw/dt = M - w x (I w)`` in the body frame.

    Parameters
    ----------
    w : tuple of 3 floats
        Body angular velocity (rad/s).
    inertia_ : tuple of 3 floats
        Principal inertias (kg m^2).
    moment : tuple of 3 floats
        Body-frame moment (N m).

    Returns
    -------
    tuple of 3 floats
        rad/s^2.
    """
    i1, i2, i3 = inertia_
    return (
        (moment[0] - (i3 - i2) * w[1] * w[2]) / i1,
        (moment[1] - (i1 - i3) * w[2] * w[0]) / i2,
        (moment[2] - (i2 - i1) * w[0] * w[1]) / i3,
    )


@jit
def momentum_rates(m, w, moment):
    """``dm/dt = m x w + M`` for the body angular momentum ``m = I w``.

    Parameters
    ----------
    m : tuple of 3 floats
        Body angular momentum (kg m^2/s).
    w : tuple of 3 floats
        Body angular velocity (rad/s).
    moment : tuple of 3 floats
        Body-frame moment (N m).

    Returns
    -------
    tuple of 3 floats
        N m.
    """
    return add(cross(m, w), moment)


# The invariants, as `rbstudy.numerics.algebra` writes them for numpy code too.
rotational_energy = jit(algebra.rotational_energy)
momentum_squared = jit(algebra.momentum_squared)


@jit
def _slots_free(p, at, slots):
    """True when the ``slots`` ((start, width) pairs, starts counted from ``at``) of row ``p``
    are all zero."""
    for start, width in slots:
        for k in range(width):
            if p[at + start + k] != 0.0:
                return False
    return True


@jit
def is_moment_free(p):
    """Whether no load that turns the body acts (`rbstudy.numerics.loads`: every kind with
    ``turns_body``), constant or tabulated, so that energy and angular momentum must be
    conserved.

    Parameters
    ----------
    p : ndarray, shape (W,)
        Parameter row, W >= N_PARAM (`rbstudy.numerics.state`).

    Returns
    -------
    bool
    """
    if not _slots_free(p, 0, TURNING_SLOTS):
        return False
    count = int(p[S.KNOTS])
    for k in range(count):
        if not _slots_free(p, S.N_PARAM + count + k * S.LOAD_RECORD, TURNING_RECORD_SLOTS):
            return False
    return True
