"""`no_squish`: the NO_SQUISH splitting on the quaternion and its conjugate momentum.

The state is the unit quaternion ``q`` and its conjugate momentum ``P = 2 q * (m, 0)`` (kept
in the work array between steps; the body angular momentum is ``m_k = 1/2 P . (q * e_k)``).
With ``P_k x = x * (e_k, 0)`` (Miller's permutation matrices, scalar-last here), the free flow
of ``T_k`` for a time ``d`` is the rotation in the (x, P_k x) planes

    zeta = P . P_k q / (4 I_k)
    q <- cos(zeta d) q + sin(zeta d) P_k q,    P <- cos(zeta d) P + sin(zeta d) P_k P

composed as ``T_a(h/2) T_b(h/2) T_c(h) T_b(h/2) T_a(h/2)`` (option ``axis_order``,
`rbstudy.schemes._splitting`) between
half kicks ``P += h q * (M_b, 0)``, ``v += h/2 F/mass`` (LAMMPS' fix rigid/nve form). This is
the DLM splitting written in other variables: equal to `splitting` with the same axis order
up to round-off (a test checks it).

Order 2, explicit, symplectic; order 4, 6 or 8 composed (option ``composition``,
`rbstudy.schemes._composition`). Keeps ``|m|`` and ``L`` to round-off, energy error bounded.
Option ``compensated`` adds the increments of ``q`` and ``P`` with compensated summation
(`rbstudy.schemes._compensated`), ``P``'s with a carry of its own.
Reference: Miller, Eleftheriou, Pattnaik, Ndirango, Newns & Martyna, J. Chem. Phys. 116 (2002)
8649.

The sine and cosine of the flows are `rbstudy.numerics.lanes_math`'s, so that the block step
(`block_step`, bodies of a batch stepped side by side, ``P`` carried in the block's `WORK`
rows) gives each body the bits of its solo run.
"""

import math

from rbstudy.numerics import block as B
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add4_inplace
from rbstudy.numerics.dynamics import inertia, kick_momentum, space_force, to_momentum, to_omega
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes_math import sin_cos
from rbstudy.numerics.rotation import (
    axpy4,
    cos_minus_one,
    dot4,
    quat_mul,
    quat_times_axis,
    read3,
    read4,
    scale,
    write3,
    write4,
)
from rbstudy.numerics.state import OK
from rbstudy.schemes._compensated import CARRY_WIDTH, COMPENSATED, switch
from rbstudy.schemes._composition import COMPOSITION, composed_block_step, composed_entry
from rbstudy.schemes._kicks import (
    compensated_drift_inplace,
    compensated_velocity_kick_inplace,
    drift_block,
    drift_inplace,
    kicked_velocity,
)
from rbstudy.schemes._registry import Scheme, Style, option_slots, scratch_rows
from rbstudy.schemes._splitting import AXIS_ORDER, flow_sequence, on_axis

# work: conjugate momentum P (4), then the carries of the compensated sums: the state's
# (its OMEGA entries unused: the spin is computed from P) and P's
_MOMENTUM, _CARRY = 0, 4
_MOMENTUM_CARRY = _CARRY + CARRY_WIDTH
N_WORK = _MOMENTUM_CARRY + 4

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (AXIS_ORDER, COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)
_AXES = _SLOTS["axis_order"]
_COMPOSITION = _SLOTS["composition"]


@jit
def conjugate_momentum(q, m):
    """``P = 2 q * (m, 0)`` for body angular momentum ``m``."""
    return quat_mul(q, (2.0 * m[0], 2.0 * m[1], 2.0 * m[2], 0.0))


@jit
def body_momentum(q, momentum):
    """``m_k = 1/2 P . (q * e_k)``."""
    return (
        0.5 * dot4(momentum, quat_times_axis(q, 0)),
        0.5 * dot4(momentum, quat_times_axis(q, 1)),
        0.5 * dot4(momentum, quat_times_axis(q, 2)),
    )


@inline_jit
def plane_rotation(x, k, c, s):
    """``c x + s P_k x``: the flow's rotation of ``x`` in its ``(x, P_k x)`` plane; with
    ``cos - 1`` for ``c``, its increment."""
    return axpy4(s, quat_times_axis(x, k), (c * x[0], c * x[1], c * x[2], c * x[3]))


@inline_jit
def spin(q, momentum, inertia_):
    """The body's spin ``w = I^-1 m`` from ``(q, P)`` (`body_momentum`)."""
    return to_omega(body_momentum(q, momentum), inertia_)


@inline_jit
def flow_angle(q, momentum, inertia_k, k, d):
    """The angle ``zeta d`` of the flow of ``T_k`` for a time ``d``, ``zeta = P . P_k q /
    (4 I_k)``, for ``inertia_k`` the inertia ``I_k``."""
    zeta = dot4(momentum, quat_times_axis(q, k)) / (4.0 * inertia_k)
    return zeta * d


@inline_jit
def rotated(q, momentum, k, c, s):
    """``(q, P)`` after the flow of ``T_k`` whose angle has the cosine ``c`` and sine ``s``."""
    return plane_rotation(q, k, c, s), plane_rotation(momentum, k, c, s)


@jit
def axis_flow(q, momentum, inertia_, k, d):
    """Exact flow of ``T_k`` for time ``d`` on ``(q, P)``."""
    s, c = sin_cos(flow_angle(q, momentum, inertia_[k], k, d))
    return rotated(q, momentum, k, c, s)


@inline_jit
def kicked_conjugate(q, momentum, v, impulse, d, mass, force):
    """``P`` and ``v`` after a kick of length ``d``: ``P + 2 q * (dm, 0)`` for ``dm`` the body
    momentum's ``impulse``, the velocity by `rbstudy.schemes._kicks.kicked_velocity`."""
    return axpy4(1.0, conjugate_momentum(q, impulse), momentum), kicked_velocity(v, d, mass, force)


@jit
def kick_inplace(y, p, momentum, t, d):
    """Loads at time ``t`` for a time ``d``: ``P += 2 q * (dm, 0)`` with ``dm`` the body
    momentum's change (`rbstudy.numerics.dynamics.kick_momentum`: ``d M_b``),
    ``v += d F / mass``; returns P."""
    q, v = read4(y, S.QUATERNION), read3(y, S.VELOCITY)
    impulse = kick_impulse(q, momentum, p, t, d)
    momentum, v = kicked_conjugate(q, momentum, v, impulse, d, p[S.MASS], space_force(q, p, t))
    write3(y, S.VELOCITY, v)
    return momentum


@inline_jit
def kick_impulse(q, momentum, p, t, d):
    """The body momentum's change ``dm`` in a kick of the loads at time ``t`` for ``d``
    (`rbstudy.numerics.dynamics.kick_momentum`), at the spin of ``(q, P)``."""
    w = spin(q, momentum, inertia(p))  # the spin now: y's is the step's start
    return kick_momentum(q, w, p, t, d)


@jit
def compensated_kick_inplace(y, p, t, d, work):
    """`kick_inplace` on ``P`` in ``work``, the increments added with compensation."""
    compensated_velocity_kick_inplace(y, p, t, d, work, _CARRY)
    q, momentum = read4(y, S.QUATERNION), read4(work, _MOMENTUM)
    dp = conjugate_momentum(q, kick_impulse(q, momentum, p, t, d))
    add4_inplace(work, _MOMENTUM, dp, work, _MOMENTUM_CARRY)


@jit
def compensated_step(y, p, opt, t, h, work):
    """`symmetric_step` with every increment added with compensation, that of ``P`` with a
    carry of its own in ``work``."""
    inertia_ = inertia(p)
    compensated_kick_inplace(y, p, t, 0.5 * h, work)
    for k, fraction in flow_sequence(opt, _AXES):
        q, momentum = read4(y, S.QUATERNION), read4(work, _MOMENTUM)
        angle = flow_angle(q, momentum, inertia_[k], k, fraction * h)
        c, s = math.cos(angle), math.sin(angle)
        add4_inplace(y, S.QUATERNION, plane_rotation(q, k, cos_minus_one(s, c), s), work, _CARRY)
        dp = plane_rotation(momentum, k, cos_minus_one(s, c), s)
        add4_inplace(work, _MOMENTUM, dp, work, _MOMENTUM_CARRY)
    compensated_drift_inplace(y, h, work, _CARRY)
    compensated_kick_inplace(y, p, later(t, h), 0.5 * h, work)
    write3(y, S.OMEGA, spin(read4(y, S.QUATERNION), read4(work, _MOMENTUM), inertia_))
    return OK, 0


@jit
def init_inplace(y, p, opt, t, h, work):
    q = read4(y, S.QUATERNION)
    write4(work, _MOMENTUM, conjugate_momentum(q, to_momentum(read3(y, S.OMEGA), inertia(p))))
    return OK


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order symmetric step (module docstring), in the phases of
    `symmetric_block_step`."""
    inertia_ = inertia(p)
    momentum = kick_inplace(y, p, read4(work, 0), t, 0.5 * h)
    q = read4(y, S.QUATERNION)
    for k, fraction in flow_sequence(opt, _AXES):
        q, momentum = axis_flow(q, momentum, inertia_, k, fraction * h)
    write4(y, S.QUATERNION, q)
    drift_inplace(y, h)
    momentum = kick_inplace(y, p, momentum, later(t, h), 0.5 * h)
    write4(work, 0, momentum)
    write3(y, S.OMEGA, spin(q, momentum, inertia_))
    return OK, 0


# block rows: P, carried from step to step (its work's first four floats); scratch: a flow's
# angle and its sine and cosine
_P = B.WORK
# (its sine and cosine in the two rows after it, as `rbstudy.numerics.block.sin_cos_columns`
# writes them)
(_ANGLE,) = scratch_rows("no_squish", angle=B.SIN_COS_ROWS)


@jit
def _block_kick(block, d):
    """`kick_inplace` of every lane for a time ``d``, its P in rows `_P`."""
    for lane in range(B.BLOCK):
        q, momentum = B.column4(block, B.STATE + S.QUATERNION, lane), B.column4(block, _P, lane)
        w = spin(q, momentum, B.column3(block, B.PARAM + S.INERTIA, lane))
        moment, mass, force = B.loads_at(block, q, w, lane)
        v = B.column3(block, B.STATE + S.VELOCITY, lane)
        momentum, v = kicked_conjugate(q, momentum, v, scale(d, moment), d, mass, force)
        B.set_column3(block, B.STATE + S.VELOCITY, lane, v)
        B.set_column4(block, _P, lane, momentum)


@inline_jit
def _axis_flow_loops(block, k, d):
    """`axis_flow` of every lane about axis ``k`` for a time ``d``: the angles, their sines
    (`rbstudy.numerics.block.sin_cos_columns`), then the rotations."""
    for lane in range(B.BLOCK):
        q, momentum = B.column4(block, B.STATE + S.QUATERNION, lane), B.column4(block, _P, lane)
        angle = flow_angle(q, momentum, B.at(block, B.PARAM + S.INERTIA + k, lane), k, d)
        block[_ANGLE * B.BLOCK + lane] = angle
    B.sin_cos_columns(block, _ANGLE)
    for lane in range(B.BLOCK):
        s, c = B.at(block, _ANGLE + 1, lane), B.at(block, _ANGLE + 2, lane)
        q, momentum = B.column4(block, B.STATE + S.QUATERNION, lane), B.column4(block, _P, lane)
        q, momentum = rotated(q, momentum, k, c, s)
        B.set_column4(block, B.STATE + S.QUATERNION, lane, q)
        B.set_column4(block, _P, lane, momentum)


@jit
def _block_axis_flow(block, k, d):
    """`_axis_flow_loops` about axis ``k``, a function of its own as splitting's."""
    on_axis(_axis_flow_loops, block, k, d)


@jit
def _block_spin(block):
    """Every lane's spin from its P and orientation, as `symmetric_step` ends."""
    for lane in range(B.BLOCK):
        q, momentum = B.column4(block, B.STATE + S.QUATERNION, lane), B.column4(block, _P, lane)
        w = spin(q, momentum, B.column3(block, B.PARAM + S.INERTIA, lane))
        B.set_column3(block, B.STATE + S.OMEGA, lane, w)


@jit
def symmetric_block_step(block, opt, h):
    """`symmetric_step` of a block of bodies without a lever, a body-fixed force or loads in
    time, that share the option row ``opt`` (N_OPTION,): ``block`` (N_ROWS * BLOCK,) as
    `rbstudy.numerics.block` lays it out. Each body's bits are those of `symmetric_step`."""
    _block_kick(block, 0.5 * h)
    for k, fraction in flow_sequence(opt, _AXES):
        _block_axis_flow(block, k, fraction * h)
    drift_block(block, h)
    _block_kick(block, 0.5 * h)
    _block_spin(block)


@jit
def block_step(block, opt, h):
    """`symmetric_block_step` composed as option ``composition`` asks (`composed_step`)."""
    composed_block_step(symmetric_block_step, _COMPOSITION, block, opt, h)


SCHEME = Scheme(
    name="no_squish",
    summary="NO_SQUISH: DLM splitting on quaternion + conjugate momentum (LAMMPS form)",
    step_seconds=2.32e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=4.0e-08,
    order=2,
    implicit=False,
    keeps=("momentum_vector",),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_inplace,
        N_WORK,
        _COMPOSITION,
        switch=switch(compensated_step, init_inplace, _SLOTS),
        block=block_step,
    ),
    reference="Miller et al., J. Chem. Phys. 116 (2002) 8649",
    options=_OPTIONS,
    # dashed over splitting's solid line: their curves coincide on a symmetric top
    style=Style("tab:olive", "P", "--"),
)
