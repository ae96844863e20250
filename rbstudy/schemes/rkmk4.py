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
from rbstudy.schemes._rk import rk4_end3, rk4_stage

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPENSATED,)
_SLOTS = option_slots(_OPTIONS)


@jit
def rates_at(q, v, u, m, w, p, t):
    """The rates ``(dx, dv, du, dm)`` of one body at the stage ``R = R_n exp([u]x)``, given as
    the quaternion ``q``, velocity ``v``, momentum ``m``, spin ``w = I^-1 m``, time ``t``."""
    return rates_under(v, u, m, w, p[S.MASS], body_moment(q, w, p, t), space_force(q, p, t))


@jit
def rates_under(v, u, m, w, mass, moment, force):
    """`rates_at` under the body-frame ``moment`` and the space ``force``, for a body of
    ``mass``."""
    du = add(add(w, scale(0.5, cross(u, w))), scale(1.0 / 12.0, cross(u, cross(u, w))))
    dm = momentum_rates(m, w, moment)
    dv = scale(1.0 / mass, force)
    return v, dv, du, dm


@inline_jit
def start(omega, inertia_):
    """``(m, w)`` at the step's start, where the first stage takes its rates (``u = 0``: the
    frame ``R_n``): the momentum ``m = I omega`` and the spin ``I^-1 m`` from it, as at the
    later stages."""
    m = to_momentum(omega, inertia_)
    return m, to_omega(m, inertia_)


@inline_jit
def stage_turn(du, a):
    """``u = a du``, the rotation vector of the frame ``R_n exp([u]x)`` where a stage after the
    first takes its rates, ``du`` the last stage's."""
    return scale(a, du)


@inline_jit
def stage_point(q, turn, v, m, dv, dm, a, inertia_):
    """Where a stage after the first takes its rates: the frame ``q turn`` (``turn = exp(u)``,
    `stage_turn`), ``v + a dv``, ``m + a dm`` and the spin ``I^-1 m`` there; ``(dv, dm)`` the
    last stage's rates, ``(q, v, m)`` the step's start."""
    m = axpy(a, dm, m)
    return quat_mul(q, turn), axpy(a, dv, v), m, to_omega(m, inertia_)


@inline_jit
def accumulate(sums, k, weight):
    """``sums + weight k``: a stage's rates ``k`` added to the weighted sum of those before,
    each ``(dx, dv, du, dm)``."""
    return (
        axpy(weight, k[0], sums[0]),
        axpy(weight, k[1], sums[1]),
        axpy(weight, k[2], sums[2]),
        axpy(weight, k[3], sums[3]),
    )


@inline_jit
def ends(x, v, m, sums, h):
    """``(x, v, 0, m) + h/6 sums``, ``sums`` the weighted sum of the stages' rates: position,
    velocity, the rotation vector ``u_n+1`` and the momentum at the step's end (from zeros,
    the increments)."""
    turn = rk4_end3(h, (0.0, 0.0, 0.0), sums[2])  # u_n = 0
    return rk4_end3(h, x, sums[0]), rk4_end3(h, v, sums[1]), turn, rk4_end3(h, m, sums[3])


@inline_jit
def update(x, v, m, sums, h, inertia_):
    """Position, velocity and spin after the step from ``(x, v, m)``, and the rotation vector
    ``u_n+1`` that turns the frame (each path turns it: the single body at once, a block in
    one loop over its lanes, `rbstudy.numerics.block.turn_columns`)."""
    x, v, turn, m = ends(x, v, m, sums, h)
    return x, v, to_omega(m, inertia_), turn


# inlined by numba: left to LLVM, the single-body loop ran slower with lanes_math's sine in the
# four exponentials than with libm's, and as fast once inlined, though the two sines alone cost
# the same
@inline_jit
def _stage(q, v, m, p, t, h, i, k, sums):
    """Stage ``i`` (1 .. 3) of one body's step: its rates, and ``sums`` with them added, ``k``
    the last stage's rates; the exponential's sine and cosine are
    `rbstudy.numerics.lanes_math`'s, as the block step's (`block_step`)."""
    a, weight = rk4_stage(h, i)
    u = stage_turn(k[2], a)
    qa, va, ma, wa = stage_point(q, quat_exp_poly(u), v, m, k[1], k[3], a, inertia(p))
    k = rates_at(qa, va, u, ma, wa, p, later(t, a))
    return k, accumulate(sums, k, weight)


@inline_jit
def stages(q, v, m, w, p, t, h):
    """The weighted sum ``k1 + 2 k2 + 2 k3 + k4`` of the four stages' rates, each ``(dx, dv,
    du, dm)``, of a step of ``h`` from ``(q, v, m)`` (``w = I^-1 m``, `start`) at time ``t``,
    added stage by stage."""
    k = rates_at(q, v, (0.0, 0.0, 0.0), m, w, p, t)
    k, sums = _stage(q, v, m, p, t, h, 1, k, k)
    k, sums = _stage(q, v, m, p, t, h, 2, k, sums)
    _, sums = _stage(q, v, m, p, t, h, 3, k, sums)
    return sums


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    """`step_inplace` with its increments (``u_n+1`` for the frame, ``I^-1 dm`` for the spin)
    added with compensation (`rbstudy.numerics.compensated`)."""
    m, w = start(read3(y, S.OMEGA), inertia(p))
    sums = stages(read4(y, S.QUATERNION), read3(y, S.VELOCITY), m, w, p, t, h)
    zero = (0.0, 0.0, 0.0)
    dx, dv, u, dm = ends(zero, zero, zero, sums, h)
    add3_inplace(y, S.POSITION, dx, work, _CARRY)
    add3_inplace(y, S.VELOCITY, dv, work, _CARRY)
    turn_inplace(y, quat_exp_minus_one(u), work, _CARRY)
    add3_inplace(y, S.OMEGA, to_omega(dm, inertia(p)), work, _CARRY)
    return OK, 0


@jit
def step_inplace(y, p, opt, t, h, work):
    x, q = read3(y, S.POSITION), read4(y, S.QUATERNION)
    v = read3(y, S.VELOCITY)
    m, w = start(read3(y, S.OMEGA), inertia(p))
    x, v, w, turn = update(x, v, m, stages(q, v, m, w, p, t, h), h, inertia(p))
    write3(y, S.POSITION, x)
    write3(y, S.VELOCITY, v)
    write4(y, S.QUATERNION, quat_normalize(quat_mul(q, quat_exp_poly(turn))))
    write3(y, S.OMEGA, w)
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
    """`stage_turn` of every lane, over the last stage's ``du`` rows, and ``exp(u)``, as
    `_stage` gives them to `stage_point`."""
    for lane in range(B.BLOCK):
        B.set_column3(block, _DU, lane, stage_turn(B.column3(block, _DU, lane), a))
    B.quat_exp_columns(block, _DU, _EXP)


@jit
def _block_stage(block, first, a, weight):
    """A stage of `stages` for every lane of a block: the rates at `stage_point` with ``a``
    (``u``, ``exp(u)`` from `_block_frame`; at `start` for the ``first``, a literal:
    numba compiles that stage apart), stored over the last stage's, and added with ``weight``
    to the weighted sum (`accumulate`; they start it for the ``first``). A function of its own
    per loop, as rk4's (`rbstudy.schemes.rk4._block_stage`)."""
    for lane in range(B.BLOCK):
        q, v = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, B.STATE + S.VELOCITY, lane)
        omega = B.column3(block, B.STATE + S.OMEGA, lane)
        inertia_ = B.column3(block, B.PARAM + S.INERTIA, lane)
        m, w = start(omega, inertia_)
        u = (0.0, 0.0, 0.0)
        if not first:
            u, turn = B.column3(block, _DU, lane), B.column4(block, _EXP, lane)
            dv, dm = B.column3(block, _DV, lane), B.column3(block, _DM, lane)
            q, v, m, w = stage_point(q, turn, v, m, dv, dm, a, inertia_)
        moment, mass, force = B.loads_at(block, q, w, lane)
        k = rates_under(v, u, m, w, mass, moment, force)
        B.set_column3(block, _DV, lane, k[1])
        B.set_column3(block, _DU, lane, k[2])
        B.set_column3(block, _DM, lane, k[3])
        # the sums spelt out (`accumulate`): a loop over the four rates with a select between
        # ``k[i]`` and the sum left the stage's loop scalar (no packed instruction in its code)
        sums = k if first else accumulate(_sum_columns(block, lane), k, weight)
        _set_sum_columns(block, lane, sums)


@jit
def _block_update(block, h):
    """`update` of every lane, from the weighted sum of the stages, ``u_n+1`` into rows
    `_TURN`."""
    for lane in range(B.BLOCK):
        x, v = B.column3(block, B.STATE + S.POSITION, lane), B.column3(block, B.STATE + S.VELOCITY, lane)
        omega = B.column3(block, B.STATE + S.OMEGA, lane)
        inertia_ = B.column3(block, B.PARAM + S.INERTIA, lane)
        m, _ = start(omega, inertia_)
        x, v, w, turn = update(x, v, m, _sum_columns(block, lane), h, inertia_)
        B.set_column3(block, B.STATE + S.POSITION, lane, x)
        B.set_column3(block, B.STATE + S.VELOCITY, lane, v)
        B.set_column3(block, _TURN, lane, turn)
        B.set_column3(block, B.STATE + S.OMEGA, lane, w)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out, a loop over the
    lanes per stage and per stage's exponential (the lanes' sines in a loop of their own,
    `rbstudy.numerics.block.quat_exp_columns`). Each body's bits are those of
    `step_inplace`."""
    _block_stage(block, True, 0.0, 1.0)  # at the state, weight 1
    for i in range(1, 4):
        a, weight = rk4_stage(h, i)  # unpacked, as in `rbstudy.schemes.rk4.block_step`
        _block_frame(block, a)
        _block_stage(block, False, a, weight)
    _block_update(block, h)
    B.turn_columns(block, _TURN)


SCHEME = Scheme(
    name="rkmk4",
    summary="Runge-Kutta-Munthe-Kaas 4: RK4 in the Lie algebra, frame exactly on SO(3)",
    step_seconds=2.67e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
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
