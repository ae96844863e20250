"""Half kicks shared by the symmetric splitting schemes (midpoint, splitting).

Loads enter these schemes by Strang splitting: a kick of length d applies the loads at the
current orientation, ``m += d M_b``, ``v += d F / mass``; the free flow in between moves the
frame and the centre of mass. The composition kick(h/2) free(h) kick(h/2) is symmetric, so a
second-order free step stays second order under loads. Loads tabulated in time are taken at
the time of each kick, the start and the end of the step (time is a coordinate that the
free flow advances and the kicks hold), which keeps the composition symmetric.
The ``compensated_`` twins add the same increments with compensated summation
(`rbstudy.numerics.compensated`), the spin's as ``I^-1 dm``; `kicked` is the kick of one
lane of a block of bodies (`rbstudy.numerics.block`).
"""

from rbstudy.numerics import state as S
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
def kicked(w, v, inertia_, moment, mass, force, d):
    """`kick_inplace` of a body of spin ``w``, velocity ``v``, principal inertias ``inertia_``
    and ``mass`` under loads that do not depend on the time, the body-frame ``moment`` and the
    space ``force``: ``(w, v)`` kicked, in the bits of `kick_inplace` (whose kick without the
    time is ``d M``). Scalars only, for the block steps (`rbstudy.numerics.block`)."""
    m = add(to_momentum(w, inertia_), scale(d, moment))
    return to_omega(m, inertia_), axpy(d / mass, force, v)


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
