"""`midpoint`: the implicit midpoint rule on the body angular momentum (a Lie-Poisson method).

Free step (Austin, Krishnaprasad & Wang 1993), with ``m = I w`` and ``cay`` the Cayley map:

    m+ = m + h mbar x (I^-1 mbar),   mbar = (m + m+) / 2
    R+ = R cay(h [wbar]x),           wbar = I^-1 mbar

solved for ``mbar`` by Newton on ``g(z) = 2 (z - m) - h z x I^-1 z`` with the 3x3 Jacobian
``2 - h (-[I^-1 z]x + [z]x I^-1)``, starting from the explicit predictor
``z = m + h/2 m x w`` (fixed-point iteration would stop converging near ``h |w| = 2.7``).
Loads enter by Strang splitting around the free step: kick(h/2), free(h), kick(h/2)
(see `rbstudy.schemes._kicks`); the centre of mass drifts at the kicked velocity.

Order 2, implicit; order 4, 6 or 8 composed (option ``composition``,
`rbstudy.schemes._composition`). For the free body it keeps the energy, ``|m|`` and the space vector
``L = R m`` to round-off: ``cay(h [wbar]x) m+ = m`` follows from the update itself.
Option ``compensated`` solves for the increment ``mbar - m`` instead and adds the
increments with compensated summation (`rbstudy.schemes._compensated`).
Reference: Austin, Krishnaprasad & Wang, J. Comput. Phys. 107 (1993) 105.
"""

import math

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, turn_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import inertia, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import (
    add,
    cross,
    norm,
    quat_cayley,
    quat_cayley_minus_one,
    quat_mul,
    quat_normalize,
    read3,
    read4,
    scale,
    skew_matmul,
    solve3,
    sub,
    write3,
    write4,
)
from rbstudy.numerics.state import NOT_CONVERGED, OK
from rbstudy.schemes._compensated import CARRY_WIDTH, COMPENSATED, switch
from rbstudy.schemes._composition import COMPOSITION, composed_entry
from rbstudy.schemes._kicks import (
    compensated_drift_inplace,
    compensated_kick_inplace,
    drift_inplace,
    kick_inplace,
)
from rbstudy.schemes._newton import NEWTON_MAX_ITERATIONS, NEWTON_RTOL
from rbstudy.schemes._registry import Scheme, Style, option_slots

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)


@jit
def newton_matrix(z, w, inverse, h):
    """The Jacobian ``2 - h (-[I^-1 z]x + [z]x I^-1)`` of the midpoint equation at ``z``,
    ``w = I^-1 z``, ``inverse`` the inverse principal inertias."""
    a = skew_matmul(z, inverse)
    return (
        (2.0 - h * a[0][0], -h * (w[2] + a[0][1]), h * (w[1] - a[0][2])),
        (h * (w[2] - a[1][0]), 2.0 - h * a[1][1], -h * (w[0] + a[1][2])),
        (-h * (w[1] + a[2][0]), h * (w[0] - a[2][1]), 2.0 - h * a[2][2]),
    )


@jit
def solve_midpoint(m, inertia_, h, increment):
    """Newton solve of the free midpoint equation; returns ``(u, iterations, converged)``
    with ``u = mbar``, or with ``increment`` the half increment ``d = mbar - m``, solved for
    as the root of ``2 d - h (m + d) x I^-1 (m + d)`` so that it comes to its own relative
    accuracy (``mbar - m`` would carry the rounding of ``mbar``, an ulp of ``m``)."""
    inverse = (1.0 / inertia_[0], 1.0 / inertia_[1], 1.0 / inertia_[2])
    predicted = scale(0.5 * h, cross(m, to_omega(m, inertia_)))
    u = predicted if increment else add(predicted, m)
    for iteration in range(1, NEWTON_MAX_ITERATIONS + 1):
        z = add(m, u) if increment else u
        w = to_omega(z, inertia_)
        half_step = u if increment else sub(z, m)
        residual = sub(scale(2.0, half_step), scale(h, cross(z, w)))
        correction = solve3(newton_matrix(z, w, inverse, h), residual)
        u = sub(u, correction)
        size = norm(correction)
        if not math.isfinite(size):
            return u, iteration, False
        if size <= NEWTON_RTOL * norm(u):
            return u, iteration, True
    return u, NEWTON_MAX_ITERATIONS, False


@jit
def compensated_step(y, p, opt, t, h, work):
    """`symmetric_step` with every increment added with compensation: the momentum's
    ``2 d``, the frame's ``q (cay(h wbar) - 1)``."""
    compensated_kick_inplace(y, p, t, 0.5 * h, work, _CARRY)
    inertia_ = inertia(p)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    d, iterations, converged = solve_midpoint(m, inertia_, h, True)
    if not converged:
        return NOT_CONVERGED, iterations
    turn_inplace(y, quat_cayley_minus_one(scale(h, to_omega(add(m, d), inertia_))), work, _CARRY)
    add3_inplace(y, S.OMEGA, to_omega(scale(2.0, d), inertia_), work, _CARRY)
    compensated_drift_inplace(y, h, work, _CARRY)
    compensated_kick_inplace(y, p, later(t, h), 0.5 * h, work, _CARRY)
    return OK, iterations


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring)."""
    kick_inplace(y, p, t, 0.5 * h)
    inertia_ = inertia(p)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    mbar, iterations, converged = solve_midpoint(m, inertia_, h, False)
    if not converged:
        return NOT_CONVERGED, iterations
    q = read4(y, S.QUATERNION)
    write4(y, S.QUATERNION, quat_normalize(quat_mul(q, quat_cayley(scale(h, to_omega(mbar, inertia_))))))
    write3(y, S.OMEGA, to_omega(sub(scale(2.0, mbar), m), inertia_))
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, iterations


SCHEME = Scheme(
    name="midpoint",
    summary="implicit midpoint on m with Cayley frame update; energy and L kept exactly",
    step_seconds=1.53e-07,
    order=2,
    implicit=True,
    keeps=("energy", "momentum_vector"),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_nothing,
        N_WORK,
        _SLOTS["composition"],
        switch=switch(compensated_step, init_nothing, _SLOTS),
    ),
    reference="Austin, Krishnaprasad & Wang, J. Comput. Phys. 107 (1993) 105",
    options=_OPTIONS,
    style=Style("tab:purple", "^", "-."),
)
