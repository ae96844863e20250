"""`splitting`: the Dullweber-Leimkuhler-McLachlan (DLM) symplectic splitting.

The kinetic energy splits into ``T_k = m_k^2 / (2 I_k)``; each part's flow is an exact
rotation about body axis ``k`` by the angle ``theta = d m_k / I_k`` (docs/theory.md):

    R <- R Rot(e_k, theta),    m <- Rot(e_k, theta)^T m

and a step is the symmetric composition ``T_a(h/2) T_b(h/2) T_c(h) T_b(h/2) T_a(h/2)`` for the
axis order ``abc`` (option ``axis_order``, default ``123``; `rbstudy.schemes._splitting`),
wrapped in half kicks of the loads (``m += h/2 M_b``, ``v += h/2 F/mass``; see
`rbstudy.schemes._kicks`).

Order 2, explicit, symplectic and time-reversible; option ``composition`` composes the step
to order 4, 6 or 8 (`rbstudy.schemes._composition`). Keeps ``|m|`` and the space vector ``L``
to round-off (every sub-flow is a rotation that leaves ``R m`` fixed); the energy error stays
bounded. The axis order changes the error constant a lot (Fasso 2003). Option ``compensated``
adds each sub-flow's and kick's increments with compensated summation
(`rbstudy.schemes._compensated`); the stages of a composition share the carry.
Reference: Dullweber, Leimkuhler & McLachlan, J. Chem. Phys. 107 (1997) 5840; Fasso, J.
Comput. Phys. 189 (2003) 527.

The sine and cosine of the sub-flows are `rbstudy.numerics.lanes_math`'s, so that the block
step (`block_step`, bodies of a batch stepped side by side) gives each body the bits of its
solo run.
"""

import math

from rbstudy.numerics import block as B
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, add4_inplace, normalize_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import inertia, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes_math import sin_cos
from rbstudy.numerics.rotation import (
    cos_minus_one,
    quat_mul_axis_rotation,
    quat_normalize,
    read3,
    read4,
    write3,
    write4,
)
from rbstudy.numerics.state import OK
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
from rbstudy.schemes._registry import Scheme, Style, option_slots, scratch_rows
from rbstudy.schemes._splitting import AXIS_ORDER, flow_sequence, on_axis

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (AXIS_ORDER, COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)
_AXES = _SLOTS["axis_order"]
_COMPOSITION = _SLOTS["composition"]


@jit
def turned_momentum(m, k, c, s, along):
    """``Rot(e_k, theta)^T m`` for ``c, s`` the cosine and sine of ``theta``, the component
    along the axis multiplied by ``along``: 1 gives the turned momentum; with ``c - 1`` for
    ``c`` and 0 for ``along``, its increment."""
    if k == 0:
        return (along * m[0], c * m[1] + s * m[2], c * m[2] - s * m[1])
    if k == 1:
        return (c * m[0] - s * m[2], along * m[1], c * m[2] + s * m[0])
    return (c * m[0] + s * m[1], c * m[1] - s * m[0], along * m[2])


@inline_jit
def half_angle(m_k, inertia_k, d):
    """Half the angle ``theta = d m_k / I_k`` of the flow of ``T_k`` for a time ``d``, from
    the momentum ``m_k`` and the inertia ``I_k`` about axis ``k``."""
    return 0.5 * d * m_k / inertia_k


@jit
def axis_flow(q, m, inertia_, k, d):
    """Exact flow of ``T_k`` for time ``d``: rotate the frame about body axis ``k``.

    One sine-cosine pair per flow: the momentum's rotation by ``theta`` takes its cosine and
    sine from the quaternion's half angle by the double-angle formulas.
    """
    sh, ch = sin_cos(half_angle(m[k], inertia_[k], d))
    return turned(q, m, k, sh, ch)


@jit
def turned(q, m, k, sh, ch):
    """``(q, m)`` after the rotation about body axis ``k`` of half angle sine ``sh`` and cosine
    ``ch`` (`axis_flow`)."""
    c, s = 1.0 - 2.0 * sh * sh, 2.0 * sh * ch
    return quat_mul_axis_rotation(q, k, sh, ch), turned_momentum(m, k, c, s, 1.0)


@jit
def compensated_axis_flow_inplace(y, inertia_, k, d, work):
    """`axis_flow` on the state row ``y`` (N_STATE,), its increments added with compensation
    (``cos - 1`` of both angles taken without cancellation)."""
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    half = half_angle(m[k], inertia_[k], d)
    sh, ch = math.sin(half), math.cos(half)
    dm = turned_momentum(m, k, -2.0 * sh * sh, 2.0 * sh * ch, 0.0)
    dq = quat_mul_axis_rotation(read4(y, S.QUATERNION), k, sh, cos_minus_one(sh, ch))
    add4_inplace(y, S.QUATERNION, dq, work, _CARRY)
    add3_inplace(y, S.OMEGA, to_omega(dm, inertia_), work, _CARRY)


@jit
def compensated_step(y, p, opt, t, h, work):
    """`symmetric_step` with every increment added with compensation."""
    compensated_kick_inplace(y, p, t, 0.5 * h, work, _CARRY)
    inertia_ = inertia(p)
    for k, fraction in flow_sequence(opt, _AXES):
        compensated_axis_flow_inplace(y, inertia_, k, fraction * h, work)
    normalize_inplace(y, work, _CARRY)
    compensated_drift_inplace(y, h, work, _CARRY)
    compensated_kick_inplace(y, p, later(t, h), 0.5 * h, work, _CARRY)
    return OK, 0


@inline_jit
def settled(q, m, inertia_):
    """The frame renormalised and the spin from the momentum, as the sub-flows end."""
    return quat_normalize(q), to_omega(m, inertia_)


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring), in the phases of
    `symmetric_block_step`."""
    kick_inplace(y, p, t, 0.5 * h)
    inertia_ = inertia(p)
    q = read4(y, S.QUATERNION)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    for k, fraction in flow_sequence(opt, _AXES):
        q, m = axis_flow(q, m, inertia_, k, fraction * h)
    q, w = settled(q, m, inertia_)
    write4(y, S.QUATERNION, q)
    write3(y, S.OMEGA, w)
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, 0


# block scratch: each lane's momentum m = I w between the sub-flows, then a sub-flow's half
# angle and its sine and cosine (the rows after it, as `rbstudy.numerics.block.sin_cos_columns`
# writes them)
_MOMENTUM, _HALF = scratch_rows("splitting", momentum=3, half=B.SIN_COS_ROWS)
_SINE, _COSINE = _HALF + 1, _HALF + 2


@jit
def _block_start(block, d):
    """The first kick, for a time ``d``, of every lane, and its momentum for the sub-flows."""
    kick_block(block, d)
    for lane in range(B.BLOCK):
        w, inertia_ = B.column3(block, B.STATE + S.OMEGA, lane), B.column3(block, B.PARAM + S.INERTIA, lane)
        B.set_column3(block, _MOMENTUM, lane, to_momentum(w, inertia_))


@inline_jit
def _axis_flow_loops(block, k, d):
    """`axis_flow` of every lane about axis ``k`` for a time ``d``: the half angles, their
    sines (`rbstudy.numerics.block.sin_cos_columns`), then the turn."""
    for lane in range(B.BLOCK):
        half = half_angle(B.at(block, _MOMENTUM + k, lane), B.at(block, B.PARAM + S.INERTIA + k, lane), d)
        block[_HALF * B.BLOCK + lane] = half
    B.sin_cos_columns(block, _HALF)
    for lane in range(B.BLOCK):
        q, m = turned(
            B.column4(block, B.STATE + S.QUATERNION, lane),
            B.column3(block, _MOMENTUM, lane),
            k,
            B.at(block, _SINE, lane),
            B.at(block, _COSINE, lane),
        )
        B.set_column4(block, B.STATE + S.QUATERNION, lane, q)
        B.set_column3(block, _MOMENTUM, lane, m)


@jit
def _block_axis_flow(block, k, d):
    """`_axis_flow_loops` about axis ``k`` (`on_axis`). A function of its own per sub-flow:
    inlined five times into one step, LLVM called the later ones instead of inlining them (as
    `rbstudy.schemes.rk4._block_stage` says)."""
    on_axis(_axis_flow_loops, block, k, d)


@jit
def _block_end(block, h):
    """The end of `symmetric_step` for every lane: the frame renormalised, the spin from the
    momentum, the drift and the last kick, for a step ``h``."""
    for lane in range(B.BLOCK):
        q, m = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, _MOMENTUM, lane)
        q, w = settled(q, m, B.column3(block, B.PARAM + S.INERTIA, lane))
        B.set_column4(block, B.STATE + S.QUATERNION, lane, q)
        B.set_column3(block, B.STATE + S.OMEGA, lane, w)
    drift_block(block, h)
    kick_block(block, 0.5 * h)


@jit
def symmetric_block_step(block, opt, h):
    """`symmetric_step` of a block of bodies without a lever, a body-fixed force or loads in
    time, that share the option row ``opt`` (N_OPTION,): ``block`` (N_ROWS * B.BLOCK,) as
    `rbstudy.numerics.block` lays it out. Each body's bits are those of `symmetric_step`."""
    _block_start(block, 0.5 * h)
    for k, fraction in flow_sequence(opt, _AXES):
        _block_axis_flow(block, k, fraction * h)
    _block_end(block, h)


@jit
def block_step(block, opt, h):
    """`symmetric_block_step` composed as option ``composition`` asks (`composed_step`)."""
    composed_block_step(symmetric_block_step, _COMPOSITION, block, opt, h)


SCHEME = Scheme(
    name="splitting",
    summary="DLM symplectic splitting into exact axis rotations; |L| and L kept exactly",
    step_seconds=1.74e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=3.4e-08,
    order=2,
    implicit=False,
    keeps=("momentum_vector",),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_nothing,
        N_WORK,
        _COMPOSITION,
        switch=switch(compensated_step, init_nothing, _SLOTS),
        block=block_step,
    ),
    reference="Dullweber, Leimkuhler & McLachlan, J. Chem. Phys. 107 (1997) 5840",
    options=_OPTIONS,
    # solid under no_squish's dashed line: their curves coincide on a symmetric top
    style=Style("tab:green", "o", "-"),
)
