"""`rkmk4`: Runge-Kutta-Munthe-Kaas of order 4 on SO(3) x R^3.

Within a step the frame is written ``R = R_n exp([u]x)``; the classical RK4 tableau is applied
to ``(x, v, u, m)`` with ``u(0) = 0`` and

    du/dt = w + 1/2 u x w + 1/12 u x (u x w)      (dexp^-1 truncated after the order-2 term)
    dm/dt = m x w + M_b(R),   w = I^-1 m
    dx/dt = v,   dv/dt = F(R) / mass

then ``R_n+1 = R_n exp([u_n+1]x)``. The frame stays exactly on SO(3) (the quaternion is a
product of unit quaternions). Order 4, explicit; keeps no invariant exactly. A sign error in
the commutator term silently drops the order to 2; the order test catches that. Option
``compensated`` adds the increments (the frame's as ``q_n (exp(u_n+1) - 1)``) with
compensated summation (`rbstudy.schemes._compensated`).
Reference: Munthe-Kaas, BIT 38 (1998) 92; Iserles, Munthe-Kaas, Norsett & Zanna, Acta
Numerica 9 (2000) 215.
"""

from rbstudy.numerics import block as B
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, turn_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import (
    body_moment,
    inertia,
    momentum_rates,
    space_force,
    to_momentum,
    to_omega,
)
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes_math import quat_exp_poly
from rbstudy.numerics.rotation import (
    add,
    axpy,
    cross,
    quat_exp_minus_one,
    quat_mul,
    quat_normalize,
    read3,
    read4,
    scale,
    write3,
    write4,
)
from rbstudy.numerics.state import OK
from rbstudy.schemes._compensated import CARRY_WIDTH, COMPENSATED, switch
from rbstudy.schemes._registry import Scheme, Style, option_slots, scratch_rows
from rbstudy.schemes._rk import rk4_sum3

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPENSATED,)
_SLOTS = option_slots(_OPTIONS)


# inlined by numba: left to LLVM, the single-body loop ran slower with lanes_math's sine in the
# four exponentials than with libm's, and as fast once inlined, though the two sines alone cost
# the same
@inline_jit
def rates(q_start, v, u, m, p, t):
    """``(dx, dv, du, dm)`` at the stage ``R = R_n exp([u]x)``, velocity ``v``, momentum ``m``,
    time ``t``; the exponential's sine and cosine are `rbstudy.numerics.lanes_math`'s, as the
    block step's (`block_step`)."""
    return rates_at(quat_mul(q_start, quat_exp_poly(u)), v, u, m, p, t)


@jit
def rates_at(q, v, u, m, p, t):
    """`rates` with the stage's frame ``R`` given as the quaternion ``q``."""
    w = to_omega(m, inertia(p))
    return rates_under(v, u, m, w, p[S.MASS], body_moment(q, w, p, t), space_force(q, p, t))


@jit
def rates_under(v, u, m, w, mass, moment, force):
    """`rates` at spin ``w = I^-1 m`` under the body-frame ``moment`` and the space ``force``,
    for a body of ``mass``."""
    du = add(add(w, scale(0.5, cross(u, w))), scale(1.0 / 12.0, cross(u, cross(u, w))))
    dm = momentum_rates(m, w, moment)
    dv = scale(1.0 / mass, force)
    return v, dv, du, dm


@inline_jit
def stages(q, v, m, p, t, h):
    """The four stages' rates ``k1 .. k4``, each ``(dx, dv, du, dm)``, of a step of ``h``
    from ``(q, v, m)`` at time ``t``."""
    k1 = rates_at(q, v, (0.0, 0.0, 0.0), m, p, t)  # u = 0: the frame R_n itself
    k2 = rates(
        q, axpy(0.5 * h, k1[1], v), scale(0.5 * h, k1[2]), axpy(0.5 * h, k1[3], m), p, later(t, 0.5 * h)
    )
    k3 = rates(
        q, axpy(0.5 * h, k2[1], v), scale(0.5 * h, k2[2]), axpy(0.5 * h, k2[3], m), p, later(t, 0.5 * h)
    )
    k4 = rates(q, axpy(h, k3[1], v), scale(h, k3[2]), axpy(h, k3[3], m), p, later(t, h))
    return k1, k2, k3, k4


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    """`step_inplace` with its increments (``u_n+1`` for the frame, ``I^-1 dm`` for the spin)
    added with compensation (`rbstudy.numerics.compensated`)."""
    inertia_ = inertia(p)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    k1, k2, k3, k4 = stages(read4(y, S.QUATERNION), read3(y, S.VELOCITY), m, p, t, h)
    zero = (0.0, 0.0, 0.0)
    add3_inplace(y, S.POSITION, rk4_sum3(h, zero, k1[0], k2[0], k3[0], k4[0]), work, _CARRY)
    add3_inplace(y, S.VELOCITY, rk4_sum3(h, zero, k1[1], k2[1], k3[1], k4[1]), work, _CARRY)
    turn_inplace(y, quat_exp_minus_one(rk4_sum3(h, zero, k1[2], k2[2], k3[2], k4[2])), work, _CARRY)
    dm = rk4_sum3(h, zero, k1[3], k2[3], k3[3], k4[3])
    add3_inplace(y, S.OMEGA, to_omega(dm, inertia_), work, _CARRY)
    return OK, 0


@jit
def step_inplace(y, p, opt, t, h, work):
    x, q = read3(y, S.POSITION), read4(y, S.QUATERNION)
    v = read3(y, S.VELOCITY)
    inertia_ = inertia(p)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    u = (0.0, 0.0, 0.0)
    k1, k2, k3, k4 = stages(q, v, m, p, t, h)
    write3(y, S.POSITION, rk4_sum3(h, x, k1[0], k2[0], k3[0], k4[0]))
    write3(y, S.VELOCITY, rk4_sum3(h, v, k1[1], k2[1], k3[1], k4[1]))
    u_next = rk4_sum3(h, u, k1[2], k2[2], k3[2], k4[2])
    write4(y, S.QUATERNION, quat_normalize(quat_mul(q, quat_exp_poly(u_next))))
    write3(y, S.OMEGA, to_omega(rk4_sum3(h, m, k1[3], k2[3], k3[3], k4[3]), inertia_))
    return OK, 0


# block scratch (`scratch_rows`): the last stage's (dv, du, dm), whose du rows hold the
# next stage's ``u`` once `_block_frame` has scaled them (its dx, ``v``, is summed already); the
# weighted sum so far of the stages' (dx, dv, du, dm); ``exp(u)``. The step's ``u_n+1`` and its
# quaternion (`rbstudy.numerics.block.turn_columns`) reuse the first rows.
_DV, _DU, _DM, _SUM, _EXP = scratch_rows("rkmk4", dv=3, du=3, dm=3, sum=12, exp=4)
(_TURN,) = scratch_rows("rkmk4", turn=B.TURN_ROWS)  # once the stages are summed


@jit
def _sum_columns(block, lane):
    """The weighted sum so far of lane ``lane``'s stages, ``(dx, dv, du, dm)``."""
    return (
        B.column3(block, _SUM, lane),
        B.column3(block, _SUM + 3, lane),
        B.column3(block, _SUM + 6, lane),
        B.column3(block, _SUM + 9, lane),
    )


@jit
def _set_sum_columns(block, lane, sums):
    """Store ``sums``, ``(dx, dv, du, dm)``, as lane ``lane``'s weighted sum."""
    for i in range(4):
        B.set_column3(block, _SUM + 3 * i, lane, sums[i])


@jit
def _block_frame(block, a):
    """``u = a du`` of the last stage, over its ``du`` rows, and ``exp(u)`` for every lane, as
    `stages` gives them to `rates`."""
    for lane in range(B.BLOCK):
        B.set_column3(block, _DU, lane, scale(a, B.column3(block, _DU, lane)))
    B.quat_exp_columns(block, _DU, _EXP)


@jit
def _block_stage(block, first, a, weight):
    """One stage of `stages` for every lane of a block: the rates at ``R_n exp([u]x)``, ``v +
    a dv``, ``m + a dm`` (``u``, ``exp(u)`` from `_block_frame`; ``u = 0``, ``v``, ``m`` for the
    ``first``), stored over the last stage's, and added with ``weight`` to the weighted sum
    (which they start for the ``first``) in the order of `rbstudy.schemes._rk.rk4_sum3`. A
    function of its own per loop, as rk4's (`rbstudy.schemes.rk4._block_stage`)."""
    for lane in range(B.BLOCK):
        q, v = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, B.STATE + S.VELOCITY, lane)
        inertia_ = B.column3(block, B.PARAM + S.INERTIA, lane)
        m = to_momentum(B.column3(block, B.STATE + S.OMEGA, lane), inertia_)
        u = (0.0, 0.0, 0.0)
        if not first:
            u, q = B.column3(block, _DU, lane), quat_mul(q, B.column4(block, _EXP, lane))
            v, m = axpy(a, B.column3(block, _DV, lane), v), axpy(a, B.column3(block, _DM, lane), m)
        w = to_omega(m, inertia_)
        moment, mass, force = B.loads_at(block, q, w, lane)
        k = rates_under(v, u, m, w, mass, moment, force)
        B.set_column3(block, _DV, lane, k[1])
        B.set_column3(block, _DU, lane, k[2])
        B.set_column3(block, _DM, lane, k[3])
        # the sums spelt out: a loop over the four rates with a select between ``k[i]`` and the
        # sum left the stage's loop scalar (no packed instruction in its code)
        if first:
            sums = k
        else:
            s = _sum_columns(block, lane)
            sums = (
                axpy(weight, k[0], s[0]),
                axpy(weight, k[1], s[1]),
                axpy(weight, k[2], s[2]),
                axpy(weight, k[3], s[3]),
            )
        _set_sum_columns(block, lane, sums)


@jit
def _block_update(block, h):
    """``x``, ``v`` and ``w`` of `step_inplace` for every lane, from the weighted sum of the
    stages, and ``u_n+1`` into rows `_TURN`."""
    c = h / 6.0
    zero = (0.0, 0.0, 0.0)
    for lane in range(B.BLOCK):
        x, v = B.column3(block, B.STATE + S.POSITION, lane), B.column3(block, B.STATE + S.VELOCITY, lane)
        inertia_ = B.column3(block, B.PARAM + S.INERTIA, lane)
        m = to_momentum(B.column3(block, B.STATE + S.OMEGA, lane), inertia_)
        B.set_column3(block, B.STATE + S.POSITION, lane, axpy(c, B.column3(block, _SUM, lane), x))
        B.set_column3(block, B.STATE + S.VELOCITY, lane, axpy(c, B.column3(block, _SUM + 3, lane), v))
        B.set_column3(block, _TURN, lane, axpy(c, B.column3(block, _SUM + 6, lane), zero))
        B.set_column3(
            block, B.STATE + S.OMEGA, lane, to_omega(axpy(c, B.column3(block, _SUM + 9, lane), m), inertia_)
        )


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out, a loop over the
    lanes per stage and per stage's exponential (the lanes' sines in a loop of their own,
    `rbstudy.numerics.block.quat_exp_columns`). Each body's bits are those of
    `step_inplace`."""
    _block_stage(block, True, 0.0, 1.0)
    _block_frame(block, 0.5 * h)
    _block_stage(block, False, 0.5 * h, 2.0)
    _block_frame(block, 0.5 * h)
    _block_stage(block, False, 0.5 * h, 2.0)
    _block_frame(block, h)
    _block_stage(block, False, h, 1.0)
    _block_update(block, h)
    B.turn_columns(block, _TURN)


SCHEME = Scheme(
    name="rkmk4",
    summary="Runge-Kutta-Munthe-Kaas 4: RK4 in the Lie algebra, frame exactly on SO(3)",
    step_seconds=2.67e-07,
    # in blocks of bodies, 4.4x the rate of one body after another (`rbstudy bench`,
    # one core, 1e4 bodies, before and after the block step: docs/performance.md)
    block_step_seconds=6.1e-08,
    order=4,
    implicit=False,
    keeps=(),
    run_bodies_inplace=make_entry(
        step_inplace,
        init_nothing,
        N_WORK,
        switch=switch(compensated_step_inplace, init_nothing, _SLOTS),
        block=block_step,
    ),
    reference="Munthe-Kaas, BIT 38 (1998) 92; Iserles et al., Acta Numerica 9 (2000) 215",
    options=_OPTIONS,
    # dashed over the solid lines of rk4 and exudyn_rk44, whose curves coincide with its own
    style=Style("tab:pink", "X", "--"),
)
