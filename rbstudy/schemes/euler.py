"""`euler`: explicit (forward) Euler on the body angular momentum and the frame.

Update, with ``m = I w``, ``M_b`` the body moment and ``F`` the space force (docs/theory.md s5):

    m+ = m + h (m x w + M_b)
    q+ = q * exp(h w / 2)         i.e. R+ = R exp(h [w]x), renormalised
    x+ = x + h v,    v+ = v + h F / mass

Option ``compensated`` adds the same increments with compensated summation
(`rbstudy.schemes._compensated`), the spin's as ``h I^-1 (m x w + M_b)``.

Order 1, explicit. Keeps no invariant: for the free body ``|m|^2`` grows by
``h^2 |m x w|^2`` every step and the energy grows too, so the error grows without bound.
Reference: Hairer, Lubich & Wanner, Geometric Numerical Integration (2006), ch. VII.
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import TURN_ROWS
from rbstudy.numerics.compensated import add3_inplace, turn_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import (
    body_moment,
    euler_rates,
    inertia,
    momentum_rates,
    space_force,
    to_momentum,
    to_omega,
)
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import axpy, quat_exp_minus_one, read3, read4, scale
from rbstudy.numerics.state import OK
from rbstudy.schemes._compensated import CARRY_WIDTH, COMPENSATED, switch
from rbstudy.schemes._registry import Scheme, Style, option_slots, scratch_rows
from rbstudy.schemes._turning import turning_block_step, turning_step

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPENSATED,)
_SLOTS = option_slots(_OPTIONS)


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    """`step_inplace` in increment form, the increments added with compensation."""
    q, w, v = read4(y, S.QUATERNION), read3(y, S.OMEGA), read3(y, S.VELOCITY)
    dw = scale(h, euler_rates(w, inertia(p), body_moment(q, w, p, t)))
    dv = scale(h / p[S.MASS], space_force(q, p, t))
    add3_inplace(y, S.POSITION, scale(h, v), work, _CARRY)
    add3_inplace(y, S.VELOCITY, dv, work, _CARRY)
    turn_inplace(y, quat_exp_minus_one(scale(h, w)), work, _CARRY)
    add3_inplace(y, S.OMEGA, dw, work, _CARRY)
    return OK, 0


@inline_jit
def advance(x, v, w, inertia_, moment, mass, force, h):
    """The step of one body (module docstring; `rbstudy.schemes._turning` runs it): its
    position, velocity and spin after the step and the rotation vector ``h w`` of its frame."""
    m = to_momentum(w, inertia_)
    m_next = axpy(h, momentum_rates(m, w, moment), m)
    acceleration = scale(1.0 / mass, force)
    return axpy(h, v, x), axpy(h, acceleration, v), to_omega(m_next, inertia_), scale(h, w)


@jit
def step_inplace(y, p, opt, t, h, work):
    return turning_step(advance, y, p, t, h)


# block scratch: the rotation vector h w, then its quaternion (`turn_columns`)
(_TURN,) = scratch_rows("euler", turn=TURN_ROWS)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out."""
    turning_block_step(advance, block, h, _TURN)


SCHEME = Scheme(
    name="euler",
    summary="explicit Euler on (m, R); energy and |L| grow every step",
    step_seconds=5.6e-08,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=1.8e-08,
    order=1,
    implicit=False,
    keeps=(),
    run_bodies_inplace=make_entry(
        step_inplace,
        init_nothing,
        N_WORK,
        switch=switch(compensated_step_inplace, init_nothing, _SLOTS),
        block=block_step,
    ),
    reference="Hairer, Lubich & Wanner, Geometric Numerical Integration, 2nd ed. (2006), VII",
    options=_OPTIONS,
    # solid under leapfrog's dashed line: their curves coincide on a symmetric top
    style=Style("tab:blue", "o", "-"),
)
