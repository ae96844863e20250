"""`leapfrog`: the explicit central difference of OpenRadioss rigid bodies.

Velocities live at half steps; the stored ``v`` and ``w`` are ``v(n-1/2)`` and ``w(n-1/2)``
(the initial velocities are taken as those at ``-1/2``, as an explicit code starts).
With ``I`` principal inertias and ``M_b``, ``F`` the loads at ``R_n`` and ``t_n``
(docs/theory.md s4):

    alpha_i   = (M_i - (I_k - I_j) w_j w_k) / I_i     with w = w(n-1/2): lagged gyroscopic term
    w(n+1/2)  = w(n-1/2) + h alpha
    v(n+1/2)  = v(n-1/2) + h F / mass
    x(n+1)    = x(n) + h v(n+1/2)
    R(n+1)    = R(n) Rot(w(n+1/2), h |w(n+1/2)|)    exact rotation (Rodrigues), as a quaternion

Option ``compensated`` adds the same increments with compensated summation
(`rbstudy.schemes._compensated`).

Order 1, explicit: the ``w`` update is forward Euler on Euler's equations. Keeps nothing: for
an asymmetric free body ``|m|^2`` grows by ``h^2 |m x w|^2`` each step, so there is no stable
time step for the gyroscopic term; OpenRadioss itself flags ``(h |w|)^2 > 1``.
Reference: Altair OpenRadioss Theory Manual, "Rigid Body" (time integration).
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.block import TURN_ROWS
from rbstudy.numerics.compensated import add3_inplace, turn_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import body_moment, euler_rates, inertia, space_force
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
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    add3_inplace(y, S.OMEGA, scale(h, euler_rates(w, inertia(p), body_moment(q, w, p, t))), work, _CARRY)
    add3_inplace(y, S.VELOCITY, scale(h / p[S.MASS], space_force(q, p, t)), work, _CARRY)
    add3_inplace(y, S.POSITION, scale(h, read3(y, S.VELOCITY)), work, _CARRY)
    turn_inplace(y, quat_exp_minus_one(scale(h, read3(y, S.OMEGA))), work, _CARRY)
    return OK, 0


@inline_jit
def advance(x, v, w, inertia_, moment, mass, force, h):
    """The step of one body (module docstring; `rbstudy.schemes._turning` runs it): its
    position, its half-step velocity and spin, and the rotation vector ``h w(n+1/2)`` of its
    frame."""
    w_half = axpy(h, euler_rates(w, inertia_, moment), w)
    v_half = axpy(h / mass, force, v)
    return axpy(h, v_half, x), v_half, w_half, scale(h, w_half)


@jit
def step_inplace(y, p, opt, t, h, work):
    return turning_step(advance, y, p, t, h)


# block scratch: the rotation vector h w(n+1/2), then its quaternion (`turn_columns`)
(_TURN,) = scratch_rows("leapfrog", turn=TURN_ROWS)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out."""
    turning_block_step(advance, block, h, _TURN)


SCHEME = Scheme(
    name="leapfrog",
    summary="OpenRadioss central difference: lagged gyroscopic term, Rodrigues frame update",
    step_seconds=7.5e-08,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=2.2e-08,
    order=1,
    implicit=False,
    keeps=(),
    run_bodies_inplace=make_entry(
        step_inplace,
        init_nothing,
        N_WORK,
        lanes=2,
        switch=switch(compensated_step_inplace, init_nothing, _SLOTS),
        block=block_step,
    ),
    reference="Altair OpenRadioss Theory Manual, Rigid Body (time integration, eqs. 13-18)",
    options=_OPTIONS,
    # dashed over euler's solid line: their curves coincide on a symmetric top
    style=Style("tab:orange", "s", "--"),
)
