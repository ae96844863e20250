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
"""

import math

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, add4_inplace, normalize_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import inertia, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
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
from rbstudy.schemes._composition import COMPOSITION, composed_entry
from rbstudy.schemes._kicks import (
    compensated_drift_inplace,
    compensated_kick_inplace,
    drift_inplace,
    kick_inplace,
)
from rbstudy.schemes._registry import Scheme, Style, option_slots
from rbstudy.schemes._splitting import AXIS_ORDER, flow_sequence

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (AXIS_ORDER, COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)
_AXES = _SLOTS["axis_order"]


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


@jit
def axis_flow(q, m, inertia_, k, d):
    """Exact flow of ``T_k`` for time ``d``: rotate the frame about body axis ``k``.

    One sine-cosine pair per flow: the momentum's rotation by ``theta`` takes its cosine and
    sine from the quaternion's half angle by the double-angle formulas.
    """
    half = 0.5 * d * m[k] / inertia_[k]
    sh, ch = math.sin(half), math.cos(half)
    c, s = 1.0 - 2.0 * sh * sh, 2.0 * sh * ch
    return quat_mul_axis_rotation(q, k, sh, ch), turned_momentum(m, k, c, s, 1.0)


@jit
def compensated_axis_flow_inplace(y, inertia_, k, d, work):
    """`axis_flow` on the state row ``y`` (N_STATE,), its increments added with compensation
    (``cos - 1`` of both angles taken without cancellation)."""
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    half = 0.5 * d * m[k] / inertia_[k]
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
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring)."""
    kick_inplace(y, p, t, 0.5 * h)
    inertia_ = inertia(p)
    q = read4(y, S.QUATERNION)
    m = to_momentum(read3(y, S.OMEGA), inertia_)
    for k, fraction in flow_sequence(opt, _AXES):
        q, m = axis_flow(q, m, inertia_, k, fraction * h)
    write4(y, S.QUATERNION, quat_normalize(q))
    write3(y, S.OMEGA, to_omega(m, inertia_))
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, 0


SCHEME = Scheme(
    name="splitting",
    summary="DLM symplectic splitting into exact axis rotations; |L| and L kept exactly",
    step_seconds=1.74e-07,
    order=2,
    implicit=False,
    keeps=("momentum_vector",),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_nothing,
        N_WORK,
        _SLOTS["composition"],
        switch=switch(compensated_step, init_nothing, _SLOTS),
    ),
    reference="Dullweber, Leimkuhler & McLachlan, J. Chem. Phys. 107 (1997) 5840",
    options=_OPTIONS,
    # solid under no_squish's dashed line: their curves coincide on a symmetric top
    style=Style("tab:green", "o", "-"),
)
