"""Half kicks shared by the symmetric splitting schemes (midpoint, splitting).

Loads enter these schemes by Strang splitting: a kick of length d applies the loads at the
current orientation, ``m += d M_b``, ``v += d F / mass``; the free flow in between moves the
frame and the centre of mass. The composition kick(h/2) free(h) kick(h/2) is symmetric, so a
second-order free step stays second order under loads. Loads tabulated in time are taken at
the time of each kick, the start and the end of the step (time is a coordinate that the
free flow advances and the kicks hold), which keeps the composition symmetric.
The ``compensated_`` twins add the same increments with compensated summation
(`rbstudy.numerics.compensated`), the spin's as ``I^-1 dm``; `kick_block` and `drift_block`
step every lane of a block of bodies (`rbstudy.numerics.block`).
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import BLOCK, PARAM, STATE, column3, column4, loads_at, set_column3
from rbstudy.numerics.compensated import add3_inplace
from rbstudy.numerics.dynamics import inertia, kick_momentum, space_force, to_momentum, to_omega
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import add, axpy, read3, read4, scale, write3


@jit
def kick_inplace(y, p, t, d):
    """Apply the loads at time ``t`` for a time ``d`` to the velocities of state row ``y``
    (N_STATE,); the spin changes by `rbstudy.numerics.dynamics.kick_momentum`."""
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    inertia_ = inertia(p)
    m = add(to_momentum(w, inertia_), kick_momentum(q, w, p, t, d))
    write3(y, S.OMEGA, to_omega(m, inertia_))
    write3(y, S.VELOCITY, axpy(d / p[S.MASS], space_force(q, p, t), read3(y, S.VELOCITY)))


@jit
def kick_block(block, d):
    """`kick_inplace` of every lane of a block's rows ``block`` (N_ROWS * BLOCK,) whose loads
    do not depend on the time (`rbstudy.numerics.block`), in its bits (the kick without the
    time is ``d M``)."""
    for lane in range(BLOCK):
        q, w = column4(block, STATE + S.QUATERNION, lane), column3(block, STATE + S.OMEGA, lane)
        inertia_ = column3(block, PARAM + S.INERTIA, lane)
        moment, mass, force = loads_at(block, q, w, lane)
        m = add(to_momentum(w, inertia_), scale(d, moment))
        set_column3(block, STATE + S.OMEGA, lane, to_omega(m, inertia_))
        v = axpy(d / mass, force, column3(block, STATE + S.VELOCITY, lane))
        set_column3(block, STATE + S.VELOCITY, lane, v)


@jit
def drift_block(block, d):
    """`drift_inplace` of every lane of a block's rows ``block`` (N_ROWS * BLOCK,)."""
    for lane in range(BLOCK):
        x = column3(block, STATE + S.POSITION, lane)
        set_column3(block, STATE + S.POSITION, lane, axpy(d, column3(block, STATE + S.VELOCITY, lane), x))


@jit
def drift_inplace(y, d):
    """Move the centre of mass for a time ``d`` at its current velocity."""
    write3(y, S.POSITION, axpy(d, read3(y, S.VELOCITY), read3(y, S.POSITION)))


@jit
def compensated_kick_inplace(y, p, t, d, work, carry):
    """`kick_inplace` with its increments added with compensation, the carry at ``carry`` in
    the body's ``work``."""
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    add3_inplace(y, S.OMEGA, to_omega(kick_momentum(q, w, p, t, d), inertia(p)), work, carry)
    add3_inplace(y, S.VELOCITY, scale(d / p[S.MASS], space_force(q, p, t)), work, carry)


@jit
def compensated_drift_inplace(y, d, work, carry):
    """`drift_inplace` with compensation."""
    add3_inplace(y, S.POSITION, scale(d, read3(y, S.VELOCITY)), work, carry)
