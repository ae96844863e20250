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
from rbstudy.schemes._rk import rk4_sum3, rk4_sum4

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
def stages(q, v, w, p, t, h):
    """The four stages' rates ``k1 .. k4``, each ``(dx, dq, dv, dw)``, of a step of ``h``
    from ``(q, v, w)`` at time ``t``."""
    k1 = rates(q, v, w, p, t)
    k2 = rates(
        axpy4(0.5 * h, k1[1], q), axpy(0.5 * h, k1[2], v), axpy(0.5 * h, k1[3], w), p, later(t, 0.5 * h)
    )
    k3 = rates(
        axpy4(0.5 * h, k2[1], q), axpy(0.5 * h, k2[2], v), axpy(0.5 * h, k2[3], w), p, later(t, 0.5 * h)
    )
    k4 = rates(axpy4(h, k3[1], q), axpy(h, k3[2], v), axpy(h, k3[3], w), p, later(t, h))
    return k1, k2, k3, k4


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    """`step_inplace` with the weighted sum of the stages added as an increment, with
    compensation, and the quaternion renormalised as one (`rbstudy.numerics.compensated`)."""
    k1, k2, k3, k4 = stages(read4(y, S.QUATERNION), read3(y, S.VELOCITY), read3(y, S.OMEGA), p, t, h)
    zero = (0.0, 0.0, 0.0)
    add3_inplace(y, S.POSITION, rk4_sum3(h, zero, k1[0], k2[0], k3[0], k4[0]), work, _CARRY)
    add4_inplace(y, S.QUATERNION, rk4_sum4(h, zero + (0.0,), k1[1], k2[1], k3[1], k4[1]), work, _CARRY)
    normalize_inplace(y, work, _CARRY)
    add3_inplace(y, S.VELOCITY, rk4_sum3(h, zero, k1[2], k2[2], k3[2], k4[2]), work, _CARRY)
    add3_inplace(y, S.OMEGA, rk4_sum3(h, zero, k1[3], k2[3], k3[3], k4[3]), work, _CARRY)
    return OK, 0


@jit
def step_inplace(y, p, opt, t, h, work):
    x, q = read3(y, S.POSITION), read4(y, S.QUATERNION)
    v, w = read3(y, S.VELOCITY), read3(y, S.OMEGA)
    k1, k2, k3, k4 = stages(q, v, w, p, t, h)
    write3(y, S.POSITION, rk4_sum3(h, x, k1[0], k2[0], k3[0], k4[0]))
    write4(y, S.QUATERNION, quat_normalize(rk4_sum4(h, q, k1[1], k2[1], k3[1], k4[1])))
    write3(y, S.VELOCITY, rk4_sum3(h, v, k1[2], k2[2], k3[2], k4[2]))
    write3(y, S.OMEGA, rk4_sum3(h, w, k1[3], k2[3], k3[3], k4[3]))
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
    """One stage of `stages` for every lane of a block: the rates at ``(q, v, w) + a k``,
    ``k`` the last stage's rates (at ``(q, v, w)`` for the ``first``), stored over those, and
    added with ``weight`` to the weighted sum (which they start for the ``first``): the sums
    of `rbstudy.schemes._rk.rk4_sum3` in their order. A function of its own per loop: inlined
    into one step, the helpers of the later stages were called instead of inlined by LLVM, and
    numba's inlining reference-counts the block on every call: either keeps the loop from
    vectorising."""
    for lane in range(BLOCK):
        _, q, v, w = _columns(block, STATE, lane)
        if not first:
            _, kq, kv, kw = _columns(block, _RATES, lane)
            q, v, w = axpy4(a, kq, q), axpy(a, kv, v), axpy(a, kw, w)
        moment, mass, force = loads_at(block, q, w, lane)
        k = rates_under(q, v, w, column3(block, PARAM + S.INERTIA, lane), mass, moment, force)
        _set_columns(block, _RATES, lane, k[0], k[1], k[2], k[3])
        if first:
            _set_columns(block, _SUM, lane, k[0], k[1], k[2], k[3])
        else:
            sx, sq, sv, sw = _columns(block, _SUM, lane)
            sums = (
                axpy(weight, k[0], sx),
                axpy4(weight, k[1], sq),
                axpy(weight, k[2], sv),
                axpy(weight, k[3], sw),
            )
            _set_columns(block, _SUM, lane, sums[0], sums[1], sums[2], sums[3])


@jit
def _block_update(block, h):
    """``y + h/6 (k1 + 2 k2 + 2 k3 + k4)`` of `step_inplace`, quaternion renormalised, for
    every lane, from the weighted sum of the stages."""
    c = h / 6.0
    for lane in range(BLOCK):
        x, q, v, w = _columns(block, STATE, lane)
        sx, sq, sv, sw = _columns(block, _SUM, lane)
        _set_columns(
            block,
            STATE,
            lane,
            axpy(c, sx, x),
            quat_normalize(axpy4(c, sq, q)),
            axpy(c, sv, v),
            axpy(c, sw, w),
        )


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out, a loop over the
    lanes per stage (one loop for the whole step did not vectorise). Each body's bits are
    those of `step_inplace`."""
    _block_stage(block, True, 0.0, 1.0)
    _block_stage(block, False, 0.5 * h, 2.0)
    _block_stage(block, False, 0.5 * h, 2.0)
    _block_stage(block, False, h, 1.0)
    _block_update(block, h)


SCHEME = Scheme(
    name="rk4",
    summary="classical Runge-Kutta 4 on (q, w), quaternion renormalised each step",
    step_seconds=1.28e-07,
    # in blocks of bodies, 4.45x the rate of one body after another (`rbstudy bench`,
    # one core, 1e4 bodies, before and after the block steps: docs/performance.md)
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
