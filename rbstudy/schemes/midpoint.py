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
Reference: Austin, Krishnaprasad & Wang, J. Comput. Phys. 107 (1993) 105.
"""

import math

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import inertia, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import (
    axpy,
    cross,
    norm,
    quat_cayley,
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
from rbstudy.schemes._composition import COMPOSITION, composed_entry
from rbstudy.schemes._kicks import drift_inplace, kick_inplace
from rbstudy.schemes._newton import NEWTON_MAX_ITERATIONS, NEWTON_RTOL
from rbstudy.schemes._registry import Scheme, Style

N_WORK = 0


@jit
def solve_midpoint(m, inertia_, h):
    """Newton solve of the free midpoint equation; returns ``(mbar, iterations, converged)``."""
    inverse = (1.0 / inertia_[0], 1.0 / inertia_[1], 1.0 / inertia_[2])
    z = axpy(0.5 * h, cross(m, to_omega(m, inertia_)), m)
    for iteration in range(1, NEWTON_MAX_ITERATIONS + 1):
        w = to_omega(z, inertia_)
        residual = sub(scale(2.0, sub(z, m)), scale(h, cross(z, w)))
        a = skew_matmul(z, inverse)
        jacobian = (
            (2.0 - h * a[0][0], -h * (w[2] + a[0][1]), h * (w[1] - a[0][2])),
            (h * (w[2] - a[1][0]), 2.0 - h * a[1][1], -h * (w[0] + a[1][2])),
            (-h * (w[1] + a[2][0]), h * (w[0] - a[2][1]), 2.0 - h * a[2][2]),
        )
        correction = solve3(jacobian, residual)
        z = sub(z, correction)
        size = norm(correction)
        if not math.isfinite(size):
            return z, iteration, False
        if size <= NEWTON_RTOL * norm(z):
            return z, iteration, True
    return z, NEWTON_MAX_ITERATIONS, False


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring)."""
    kick_inplace(y, p, t, 0.5 * h)
    inertia_ = inertia(p)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    mbar, iterations, converged = solve_midpoint(m, inertia_, h)
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
    run_bodies_inplace=composed_entry(symmetric_step, init_nothing, N_WORK),
    reference="Austin, Krishnaprasad & Wang, J. Comput. Phys. 107 (1993) 105",
    options=(COMPOSITION,),
    style=Style("tab:purple", "^", "-."),
)
