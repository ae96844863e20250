"""Half kicks shared by the symmetric splitting schemes (midpoint, splitting, exact_split, and
the published steps buss, lgvi and simo_wong through `split_step`; no_squish takes their drift
and velocity kick).

Loads enter these schemes by Strang splitting: a kick of length d applies the loads at the
current orientation, ``m += d M_b``, ``v += d F / mass``; the free flow in between moves the
frame and the centre of mass. The composition kick(h/2) free(h) kick(h/2) is symmetric, so a
second-order free step stays second order under loads. Loads tabulated in time are taken at
the time of each kick, the start and the end of the step (time is a coordinate that the
free flow advances and the kicks hold), which keeps the composition symmetric.
The ``compensated_`` twins add the same increments with compensated summation
(`rbstudy.numerics.compensated`), the spin's as ``I^-1 dm``; `kick_block` and `drift_block`
step every lane of a block of bodies (`rbstudy.numerics.block`). A kick's and a drift's
formulas are written once, over values (`kicked`, `drifted`), for the single body and the
block alike: each path reads its operands, evaluates the loads its own way and writes back.
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import BLOCK, PARAM, STATE, column3, column4, loads_at, set_column3
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace
from rbstudy.numerics.dynamics import inertia, kick_momentum, space_force, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import (
    add,
    axpy,
    quat_mul,
    quat_normalize,
    quat_rotate_inverse,
    read3,
    read4,
    scale,
    write3,
    write4,
)
from rbstudy.numerics.state import OK


@inline_jit
def kicked_velocity(v, d, mass, force):
    """``v + d F / mass``: the velocity after a kick of the space force ``force`` for a time
    ``d`` (`kicked`'s, and `rbstudy.schemes.no_squish`'s)."""
    return axpy(d / mass, force, v)


@inline_jit
def kicked(w, v, inertia_, impulse, d, mass, force):
    """The spin and the velocity after a kick of length ``d``: the momentum ``I w`` plus the
    ``impulse`` (`kick_inplace` passes `rbstudy.numerics.dynamics.kick_momentum`, `kick_block`
    ``d M``), the velocity by `kicked_velocity`."""
    m = add(to_momentum(w, inertia_), impulse)
    return to_omega(m, inertia_), kicked_velocity(v, d, mass, force)


@inline_jit
def drifted(x, v, d):
    """``x + d v``: the centre of mass after a drift of length ``d``."""
    return axpy(d, v, x)


@jit
def kick_inplace(y, p, t, d):
    """Apply the loads at time ``t`` for a time ``d`` to the velocities of state row ``y``
    (N_STATE,); the spin changes by `rbstudy.numerics.dynamics.kick_momentum`."""
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    impulse = kick_momentum(q, w, p, t, d)
    w, v = kicked(w, read3(y, S.VELOCITY), inertia(p), impulse, d, p[S.MASS], space_force(q, p, t))
    write3(y, S.OMEGA, w)
    write3(y, S.VELOCITY, v)


@jit
def kick_block(block, d):
    """`kick_inplace` of every lane of a block's rows ``block`` (N_ROWS * BLOCK,) whose loads
    do not depend on the time (`rbstudy.numerics.block`), in its bits (the kick without the
    time is ``d M``)."""
    for lane in range(BLOCK):
        q, w = column4(block, STATE + S.QUATERNION, lane), column3(block, STATE + S.OMEGA, lane)
        moment, mass, force = loads_at(block, q, w, lane)
        v = column3(block, STATE + S.VELOCITY, lane)
        w, v = kicked(w, v, column3(block, PARAM + S.INERTIA, lane), scale(d, moment), d, mass, force)
        set_column3(block, STATE + S.OMEGA, lane, w)
        set_column3(block, STATE + S.VELOCITY, lane, v)


@jit
def drift_block(block, d):
    """`drift_inplace` of every lane of a block's rows ``block`` (N_ROWS * BLOCK,)."""
    for lane in range(BLOCK):
        x = drifted(column3(block, STATE + S.POSITION, lane), column3(block, STATE + S.VELOCITY, lane), d)
        set_column3(block, STATE + S.POSITION, lane, x)


@jit
def drift_inplace(y, d):
    """Move the centre of mass for a time ``d`` at its current velocity."""
    write3(y, S.POSITION, drifted(read3(y, S.POSITION), read3(y, S.VELOCITY), d))


@jit
def compensated_kick_inplace(y, p, t, d, work, carry):
    """`kick_inplace` with its increments added with compensation, the carry at ``carry`` in
    the body's ``work``."""
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    add3_inplace(y, S.OMEGA, to_omega(kick_momentum(q, w, p, t, d), inertia(p)), work, carry)
    compensated_velocity_kick_inplace(y, p, t, d, work, carry)


@jit
def compensated_velocity_kick_inplace(y, p, t, d, work, carry):
    """The velocity's part of `compensated_kick_inplace`, ``v += d F / mass`` (also
    `rbstudy.schemes.no_squish`'s)."""
    force = space_force(read4(y, S.QUATERNION), p, t)
    add3_inplace(y, S.VELOCITY, scale(d / p[S.MASS], force), work, carry)


@jit
def compensated_drift_inplace(y, d, work, carry):
    """`drift_inplace` with compensation."""
    add3_inplace(y, S.POSITION, scale(d, read3(y, S.VELOCITY)), work, carry)


@inline_jit
def turned_frame(q, m, turn, inertia_):
    """The end of a free step that turns the frame by the unit quaternion ``turn`` (body
    axes) and keeps the space momentum ``L = R m``: ``(q turn`` renormalised, the spin
    ``I^-1 turn^-1 m)``."""
    return quat_normalize(quat_mul(q, turn)), to_omega(quat_rotate_inverse(turn, m), inertia_)


@inline_jit
def split_step(free, y, p, opt, t, h):
    """One step of a scheme whose free step is ``free``, under loads by Strang splitting:
    kick(h/2), ``free`` for ``h``, drift(h), kick(h/2) on the state row ``y`` (N_STATE,) with
    parameters ``p`` (N_PARAM,) and option row ``opt``.

    ``free(q, w, inertia, opt, h) -> (status, iterations, q+, w+)`` turns the frame and the
    spin of a body free of loads (body axes; ``q`` scalar last). Inlined with ``free`` passed
    as a value (as `rbstudy.schemes._turning` passes ``advance``), so each scheme's kernel is
    its own. Returns ``(status, iterations)``; a free step that fails leaves ``y`` kicked."""
    kick_inplace(y, p, t, 0.5 * h)
    status, iterations, q, w = free(read4(y, S.QUATERNION), read3(y, S.OMEGA), inertia(p), opt, h)
    if status != OK:
        return status, iterations
    write4(y, S.QUATERNION, q)
    write3(y, S.OMEGA, w)
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, iterations
