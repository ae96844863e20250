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

The block step (`block_step`, bodies of a batch stepped side by side) runs Newton on every lane
of a block at once, as long as any lane still iterates; a lane that has converged or failed
keeps its solution, so that each body takes the iterations, and gets the bits, of its solo run.
"""

from rbstudy.numerics import block as B
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
from rbstudy.schemes._composition import COMPOSITION, composed_block_step, composed_entry
from rbstudy.schemes._kicks import (
    compensated_drift_inplace,
    compensated_kick_inplace,
    drift_block,
    drift_inplace,
    kick_block,
    kick_inplace,
)
from rbstudy.schemes._newton import NEWTON_MAX_ITERATIONS, NEWTON_RTOL, newton_test
from rbstudy.schemes._registry import Scheme, Style, option_slots, scratch_rows

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)
_COMPOSITION = _SLOTS["composition"]


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


# The step's formulas, each written once for the single body (`symmetric_step`,
# `compensated_step`) and the block (`symmetric_block_step`), which call them in the same
# order: `newton_start`, `newton_update` and `newton_test` per iteration, then `frame_and_spin`.


@inline_jit
def momentum_at_midpoint(m, u, increment):
    """``mbar`` from Newton's unknown ``u``: ``u`` itself, or ``m + u`` with ``increment``."""
    return add(m, u) if increment else u


@inline_jit
def newton_start(w, inertia_, h, increment):
    """``(m, first iterate)`` at spin ``w``: the explicit predictor ``m + h/2 m x w`` of
    ``mbar``, or with ``increment`` its half increment ``h/2 m x w``."""
    m = to_momentum(w, inertia_)
    d = scale(0.5 * h, cross(m, to_omega(m, inertia_)))
    return m, (d if increment else add(d, m))


@inline_jit
def newton_update(m, u, inertia_, h, increment):
    """One Newton iteration of `solve_midpoint` from ``u``: ``(u, size of the correction)``.
    Inlined, so that ``increment`` is a constant of each copy: called, it kept the loop over a
    block's lanes from vectorising."""
    inverse = (1.0 / inertia_[0], 1.0 / inertia_[1], 1.0 / inertia_[2])
    z = momentum_at_midpoint(m, u, increment)
    w = to_omega(z, inertia_)
    half_step = u if increment else sub(z, m)
    residual = sub(scale(2.0, half_step), scale(h, cross(z, w)))
    correction = solve3(newton_matrix(z, w, inverse, h), residual)
    return sub(u, correction), norm(correction)


@jit
def solve_midpoint(m, u, inertia_, h, increment):
    """Newton solve of the free midpoint equation from `newton_start`'s ``(m, u)``; returns
    ``(u, iterations, converged)`` with ``u = mbar``, or with ``increment`` the half increment
    ``d = mbar - m``, solved for as the root of ``2 d - h (m + d) x I^-1 (m + d)`` so that it
    comes to its own relative accuracy (``mbar - m`` would carry the rounding of ``mbar``, an
    ulp of ``m``)."""
    converged, going_on, iterations = False, True, 0
    while going_on:
        iterations += 1
        u, size = newton_update(m, u, inertia_, h, increment)
        converged, _, going_on = newton_test(True, size, NEWTON_RTOL * norm(u), iterations)
    return u, iterations, converged


@inline_jit
def frame_and_spin(q, m, u, inertia_, h, increment):
    """The end of the free step from Newton's solution ``u``: the frame ``q cay(h wbar)``
    renormalised and the spin ``I^-1 (2 mbar - m)``, or with ``increment`` (a constant where it
    is inlined) their increments ``cay(h wbar) - 1`` (to turn ``q`` by) and ``I^-1 2 d``."""
    turn = scale(h, to_omega(momentum_at_midpoint(m, u, increment), inertia_))
    if increment:
        return quat_cayley_minus_one(turn), to_omega(scale(2.0, u), inertia_)
    return quat_normalize(quat_mul(q, quat_cayley(turn))), to_omega(sub(scale(2.0, u), m), inertia_)


@jit
def compensated_step(y, p, opt, t, h, work):
    """`symmetric_step` with every increment added with compensation: the momentum's
    ``2 d``, the frame's ``q (cay(h wbar) - 1)``."""
    compensated_kick_inplace(y, p, t, 0.5 * h, work, _CARRY)
    inertia_ = inertia(p)
    m, d = newton_start(read3(y, S.OMEGA), inertia_, h, True)
    d, iterations, converged = solve_midpoint(m, d, inertia_, h, True)
    if not converged:
        return NOT_CONVERGED, iterations
    turn, dw = frame_and_spin(read4(y, S.QUATERNION), m, d, inertia_, h, True)
    turn_inplace(y, turn, work, _CARRY)
    add3_inplace(y, S.OMEGA, dw, work, _CARRY)
    compensated_drift_inplace(y, h, work, _CARRY)
    compensated_kick_inplace(y, p, later(t, h), 0.5 * h, work, _CARRY)
    return OK, iterations


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring)."""
    kick_inplace(y, p, t, 0.5 * h)
    inertia_ = inertia(p)
    m, u = newton_start(read3(y, S.OMEGA), inertia_, h, False)
    mbar, iterations, converged = solve_midpoint(m, u, inertia_, h, False)
    if not converged:
        return NOT_CONVERGED, iterations
    q, w = frame_and_spin(read4(y, S.QUATERNION), m, mbar, inertia_, h, False)
    write4(y, S.QUATERNION, q)
    write3(y, S.OMEGA, w)
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, iterations


# block scratch: each lane's momentum after the first kick, its Newton iterate, whether it
# iterates and whether it converged, its iterations in this stage, then Newton's next iterate
# and the size of its correction
_MOMENTUM, _ITERATE, _ACTIVE, _CONVERGED, _STAGE_ITERATIONS, _NEXT, _SIZE = scratch_rows(
    "midpoint", momentum=3, iterate=3, active=1, converged=1, stage_iterations=1, next=3, size=1
)


@jit
def _block_start(block, h):
    """The first kick of every lane and its `newton_start`; a lane iterates when it is booked
    and has not failed in an earlier stage."""
    kick_block(block, 0.5 * h)
    for lane in range(B.BLOCK):
        w = B.column3(block, B.STATE + S.OMEGA, lane)
        m, u = newton_start(w, B.column3(block, B.PARAM + S.INERTIA, lane), h, False)
        B.set_column3(block, _MOMENTUM, lane, m)
        B.set_column3(block, _ITERATE, lane, u)
    B.start_newton(block, _ACTIVE)


@jit
def _block_newton(block, h, iteration):
    """Newton iteration ``iteration`` of `solve_midpoint` on every lane, kept by the lanes that
    still iterate (selects); returns how many still do. Two loops: as one, LLVM did not
    vectorise it."""
    for lane in range(B.BLOCK):
        m, u = B.column3(block, _MOMENTUM, lane), B.column3(block, _ITERATE, lane)
        u_next, size = newton_update(m, u, B.column3(block, B.PARAM + S.INERTIA, lane), h, False)
        B.set_column3(block, _NEXT, lane, u_next)
        block[_SIZE * B.BLOCK + lane] = size
    active = 0
    for lane in range(B.BLOCK):
        u_next, size = B.column3(block, _NEXT, lane), B.at(block, _SIZE, lane)
        iterating = B.at(block, _ACTIVE, lane) != 0.0
        converged, _, going_on = newton_test(iterating, size, NEWTON_RTOL * norm(u_next), iteration)
        B.set_column3(block, _ITERATE, lane, u_next if iterating else B.column3(block, _ITERATE, lane))
        # booked here, not by `_newton.book_newton_pass` as hht's lanes are: this loop
        # vectorises, and through that helper it ran slower (`rbstudy bench`, B = 1e4)
        taken = B.at(block, _STAGE_ITERATIONS, lane)
        block[_STAGE_ITERATIONS * B.BLOCK + lane] = iteration if iterating else taken
        block[_CONVERGED * B.BLOCK + lane] = 1.0 if converged else B.at(block, _CONVERGED, lane)
        block[_ACTIVE * B.BLOCK + lane] = 1.0 if going_on else 0.0
        active += 1 if going_on else 0
    return active


@jit
def _block_end(block, h):
    """`frame_and_spin` of every lane, the drift and the last kick (in every lane: a lane that
    did not converge is no longer booked), and each lane's verdict and iterations."""
    for lane in range(B.BLOCK):
        m, mbar = B.column3(block, _MOMENTUM, lane), B.column3(block, _ITERATE, lane)
        q = B.column4(block, B.STATE + S.QUATERNION, lane)
        q, w = frame_and_spin(q, m, mbar, B.column3(block, B.PARAM + S.INERTIA, lane), h, False)
        B.set_column4(block, B.STATE + S.QUATERNION, lane, q)
        B.set_column3(block, B.STATE + S.OMEGA, lane, w)
    drift_block(block, h)
    kick_block(block, 0.5 * h)
    B.end_newton(block, _ACTIVE)


@jit
def symmetric_block_step(block, opt, h):
    """`symmetric_step` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out, Newton's
    iterations while any lane iterates. Each body's bits, status and iterations are those of
    `symmetric_step`."""
    _block_start(block, h)
    for iteration in range(1, NEWTON_MAX_ITERATIONS + 1):
        if _block_newton(block, h, iteration) == 0:
            break
    _block_end(block, h)


@jit
def block_step(block, opt, h):
    """`symmetric_block_step` composed as option ``composition`` asks (`composed_step`)."""
    composed_block_step(symmetric_block_step, _COMPOSITION, block, opt, h)


SCHEME = Scheme(
    name="midpoint",
    summary="implicit midpoint on m with Cayley frame update; energy and L kept exactly",
    step_seconds=1.53e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=3.5e-08,
    order=2,
    implicit=True,
    keeps=("energy", "momentum_vector"),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_nothing,
        N_WORK,
        _COMPOSITION,
        switch=switch(compensated_step, init_nothing, _SLOTS),
        block=block_step,
    ),
    reference="Austin, Krishnaprasad & Wang, J. Comput. Phys. 107 (1993) 105",
    options=_OPTIONS,
    style=Style("tab:purple", "^", "-."),
)
