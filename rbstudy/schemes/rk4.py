"""`rk4`: classical Runge-Kutta on (x, q, v, w), quaternion renormalised after each step.

The ODE (docs/theory.md s1): ``dx/dt = v``, ``dq/dt = 1/2 q * (w, 0)``, ``dv/dt = F/mass``,
``dw/dt = I^-1 (M_b - w x I w)``; the classical four-stage tableau, then ``q <- q/|q|``
(the projection that Fukushima 2008 recommends). Option ``compensated`` adds
``h/6 (k1 + 2 k2 + 2 k3 + k4)`` with compensated summation and renormalises the
quaternion as an increment (`rbstudy.schemes._compensated`).

Order 4, explicit. Keeps no invariant exactly: the energy error drifts linearly in time, and
the scheme blows up near ``h |nu| = 2.8`` (``nu`` the nutation frequency).
Reference: Fukushima, AJ 135 (2008) 2298, "Simple, regular, and efficient numerical
integration of rotational motion".
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import (
    BLOCK,
    PARAM,
    STATE,
    column3,
    column4,
    loads_at,
    set_column3,
    set_column4,
)
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, add4_inplace, normalize_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import body_moment, euler_rates, inertia, space_force
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import (
    axpy,
    axpy4,
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
from rbstudy.schemes._rk import rk4_end3, rk4_end4, rk4_stage

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPENSATED,)
_SLOTS = option_slots(_OPTIONS)


@jit
def rates(q, v, w, p, t):
    """Time derivatives ``(dx, dq, dv, dw)`` at orientation ``q``, velocity ``v``, spin ``w``
    and time ``t``."""
    return rates_under(q, v, w, inertia(p), p[S.MASS], body_moment(q, w, p, t), space_force(q, p, t))


@jit
def rates_under(q, v, w, inertia_, mass, moment, force):
    """`rates` under the body-frame ``moment`` and the space ``force``, for a body of
    principal inertias ``inertia_`` and ``mass``."""
    dq = quat_mul(q, (0.5 * w[0], 0.5 * w[1], 0.5 * w[2], 0.0))
    dv = scale(1.0 / mass, force)
    dw = euler_rates(w, inertia_, moment)
    return v, dq, dv, dw


@inline_jit
def stage_point(q, v, w, k, a):
    """``(q, v, w) + a k``, where a stage after the first takes its rates, ``k`` the last
    stage's rates ``(dx, dq, dv, dw)``."""
    return axpy4(a, k[1], q), axpy(a, k[2], v), axpy(a, k[3], w)


@inline_jit
def accumulate(sums, k, weight):
    """``sums + weight k``: a stage's rates ``k`` added to the weighted sum of those before,
    each ``(dx, dq, dv, dw)``."""
    return (
        axpy(weight, k[0], sums[0]),
        axpy4(weight, k[1], sums[1]),
        axpy(weight, k[2], sums[2]),
        axpy(weight, k[3], sums[3]),
    )


@inline_jit
def ends(x, q, v, w, sums, h):
    """``(x, q, v, w) + h/6 sums``, ``sums`` the weighted sum of the stages' rates: the step's
    end before the quaternion's projection (from zeros, the increments)."""
    return rk4_end3(h, x, sums[0]), rk4_end4(h, q, sums[1]), rk4_end3(h, v, sums[2]), rk4_end3(h, w, sums[3])


@inline_jit
def update(x, q, v, w, sums, h):
    """The state after the step: `ends`, the quaternion renormalised."""
    x, q, v, w = ends(x, q, v, w, sums, h)
    return x, quat_normalize(q), v, w


@inline_jit
def _stage(q, v, w, p, t, h, i, k, sums):
    """Stage ``i`` (1 .. 3) of one body's step: its rates, and ``sums`` with them added, ``k``
    the last stage's rates."""
    a, weight = rk4_stage(h, i)
    qa, va, wa = stage_point(q, v, w, k, a)
    k = rates(qa, va, wa, p, later(t, a))
    return k, accumulate(sums, k, weight)


@inline_jit
def stages(q, v, w, p, t, h):
    """The weighted sum ``k1 + 2 k2 + 2 k3 + k4`` of the four stages' rates, each ``(dx, dq,
    dv, dw)``, of a step of ``h`` from ``(q, v, w)`` at time ``t``, added stage by stage."""
    k = rates(q, v, w, p, t)
    k, sums = _stage(q, v, w, p, t, h, 1, k, k)
    k, sums = _stage(q, v, w, p, t, h, 2, k, sums)
    _, sums = _stage(q, v, w, p, t, h, 3, k, sums)
    return sums


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    """`step_inplace` with the weighted sum of the stages added as an increment, with
    compensation, and the quaternion renormalised as one (`rbstudy.numerics.compensated`)."""
    sums = stages(read4(y, S.QUATERNION), read3(y, S.VELOCITY), read3(y, S.OMEGA), p, t, h)
    zero = (0.0, 0.0, 0.0)
    dx, dq, dv, dw = ends(zero, zero + (0.0,), zero, zero, sums, h)
    add3_inplace(y, S.POSITION, dx, work, _CARRY)
    add4_inplace(y, S.QUATERNION, dq, work, _CARRY)
    normalize_inplace(y, work, _CARRY)
    add3_inplace(y, S.VELOCITY, dv, work, _CARRY)
    add3_inplace(y, S.OMEGA, dw, work, _CARRY)
    return OK, 0


@jit
def step_inplace(y, p, opt, t, h, work):
    x, q = read3(y, S.POSITION), read4(y, S.QUATERNION)
    v, w = read3(y, S.VELOCITY), read3(y, S.OMEGA)
    x, q, v, w = update(x, q, v, w, stages(q, v, w, p, t, h), h)
    write3(y, S.POSITION, x)
    write4(y, S.QUATERNION, q)
    write3(y, S.VELOCITY, v)
    write3(y, S.OMEGA, w)
    return OK, 0


# block scratch: the last stage's rates (dx, dq, dv, dw) laid out as a state, then their
# weighted sum so far
_RATES, _SUM = scratch_rows("rk4", rates=S.N_STATE, sum=S.N_STATE)


@jit
def _columns(block, row, lane):
    """``(x, q, v, w)`` of lane ``lane``, from the rows from ``row`` on laid out as a state."""
    return (
        column3(block, row + S.POSITION, lane),
        column4(block, row + S.QUATERNION, lane),
        column3(block, row + S.VELOCITY, lane),
        column3(block, row + S.OMEGA, lane),
    )


@jit
def _set_columns(block, row, lane, x, q, v, w):
    """Store ``(x, q, v, w)`` of lane ``lane`` into the rows from ``row`` on."""
    set_column3(block, row + S.POSITION, lane, x)
    set_column4(block, row + S.QUATERNION, lane, q)
    set_column3(block, row + S.VELOCITY, lane, v)
    set_column3(block, row + S.OMEGA, lane, w)


@jit
def _block_stage(block, first, a, weight):
    """A stage of `stages` for every lane of a block: the rates at `stage_point` with ``a``,
    ``k`` the last stage's rates (at ``(q, v, w)`` for the ``first``, a literal: numba compiles
    that stage apart), stored over those, and added with ``weight`` to the weighted sum
    (`accumulate`; they start it for the ``first``). A function of its own per loop: inlined
    into one step, the helpers of the later stages were called instead of inlined by LLVM, and
    numba's inlining reference-counts the block on every call: either keeps the loop from
    vectorising."""
    for lane in range(BLOCK):
        _, q, v, w = _columns(block, STATE, lane)
        if not first:
            q, v, w = stage_point(q, v, w, _columns(block, _RATES, lane), a)
        moment, mass, force = loads_at(block, q, w, lane)
        k = rates_under(q, v, w, column3(block, PARAM + S.INERTIA, lane), mass, moment, force)
        _set_columns(block, _RATES, lane, k[0], k[1], k[2], k[3])
        if first:
            _set_columns(block, _SUM, lane, k[0], k[1], k[2], k[3])
        else:
            sums = accumulate(_columns(block, _SUM, lane), k, weight)
            _set_columns(block, _SUM, lane, sums[0], sums[1], sums[2], sums[3])


@jit
def _block_update(block, h):
    """`update` of every lane, from the weighted sum of the stages."""
    for lane in range(BLOCK):
        x, q, v, w = _columns(block, STATE, lane)
        x, q, v, w = update(x, q, v, w, _columns(block, _SUM, lane), h)
        _set_columns(block, STATE, lane, x, q, v, w)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out, a loop over the
    lanes per stage (one loop for the whole step did not vectorise). Each body's bits are
    those of `step_inplace`."""
    _block_stage(block, True, 0.0, 1.0)  # at the state, weight 1
    for i in range(1, 4):
        # unpacked: passed as ``*rk4_stage(h, i)``, they took ``first``'s literal type with them
        a, weight = rk4_stage(h, i)
        _block_stage(block, False, a, weight)
    _block_update(block, h)


SCHEME = Scheme(
    name="rk4",
    summary="classical Runge-Kutta 4 on (q, w), quaternion renormalised each step",
    step_seconds=1.28e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=2.9e-08,
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
    reference="Fukushima, Astron. J. 135 (2008) 2298",
    options=_OPTIONS,
    # solid under rkmk4's dashed line: their curves coincide on a symmetric top
    style=Style("tab:red", "o", "-"),
)
