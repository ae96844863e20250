"""`hht`: Newmark / HHT-alpha on SO(3) in material form, as in implicit FE codes (Abaqus).

With body angular velocity ``W``, body angular acceleration ``A``, inertia ``J`` and body
moment ``T(R)`` (Simo & Vu-Quoc 1988; docs/theory.md s5):

    Theta   = h W_n + h^2 ((1/2 - beta) A_n + beta A_n+1)
    R_n+1   = R_n exp([Theta]x)
    W_n+1   = W_n + h ((1 - gamma) A_n + gamma A_n+1)
    r_k     = J A_k + W_k x J W_k - T(R_k, t_k)             (dynamic equilibrium residual)
    (1 + alpha) r_n+1 - alpha r_n = 0                       (HHT-alpha; solved for A_n+1)

with ``gamma = 1/2 - alpha`` and ``beta = (1 - alpha)^2 / 4``. Newton on ``A_n+1`` with the
Jacobian ``(1 + alpha) (J + h gamma ([W]x J - [J W]x + C))``, ``C`` the coefficients of a
damping moment ``-C W`` (diagonal); the dependence of a space-fixed
moment on ``R_n+1`` is left out of the Jacobian (a modified Newton step, which still
converges). The translation uses the same Newmark/HHT weights with ``mass a = F(R)``.
The carry ``(A_n, a_n)`` starts from equilibrium at t = 0.

Option ``alpha`` in [-1/3, 0]; ``alpha = 0`` (default) is the trapezoidal Newmark of the Abaqus
force-free benchmark, with no numerical damping. Order 2 at ``alpha = 0``, implicit; keeps
``w3`` of a free symmetric top exactly, but neither energy nor ``L`` to round-off.

``alpha < 0`` damps, and costs an order for the rigid body: with ``r_0 = 0`` the weighted
equation gives ``r_n = 0`` at every step, so the scheme is Newmark with
``gamma = 1/2 - alpha > 1/2``, which is first order. HHT keeps order 2 in structural
dynamics by weighting internal (stiffness) forces, and a rigid body has none: its gyroscopic
term is an inertia force. The tests check this first order. Option ``compensated`` adds the
updates as increments (the frame's as ``q_n (exp(Theta) - 1)``) with compensated summation
(`rbstudy.schemes._compensated`).
Reference: Simo & Vu-Quoc, Comput. Methods Appl. Mech. Eng. 66 (1988) 125; Hilber, Hughes &
Taylor, Earthq. Eng. Struct. Dyn. 5 (1977) 283.

The block step (`block_step`, bodies of a batch stepped side by side) runs Newton on every lane
of a block while any lane still iterates, a lane that has converged or failed keeping its
iterate; the rotation's sine is `rbstudy.numerics.lanes_math`'s on both paths, so that each
body takes the iterations, and gets the bits, of its solo run.
"""

from rbstudy.numerics import block as B
from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, turn_inplace
from rbstudy.numerics.dynamics import (
    body_moment,
    euler_rates,
    inertia,
    space_force,
    spin_damping,
    to_momentum,
)
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.lanes_math import quat_exp_poly
from rbstudy.numerics.rotation import (
    add,
    axpy,
    cross,
    norm,
    quat_exp_minus_one,
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
from rbstudy.schemes._newton import (
    NEWTON_MAX_ITERATIONS,
    NEWTON_RESIDUAL_RTOL,
    book_newton_pass,
    newton_test,
)
from rbstudy.schemes._registry import Option, Scheme, Style, option_slots, scratch_rows

# work: body angular acceleration A_n (3), translational acceleration a_n (3), then the carry
# of the compensated sums
_ANGULAR, _LINEAR, _CARRY = 0, 3, 6
N_WORK = _CARRY + CARRY_WIDTH

# HHT-alpha is unconditionally stable and second order for alpha in [-1/3, 0] (Hilber et al.).
ALPHA_MIN, ALPHA_MAX = -1.0 / 3.0, 0.0


def _parse_alpha(value):
    alpha = float(value)
    if not ALPHA_MIN <= alpha <= ALPHA_MAX:
        raise ValueError(f"expected a number in [{ALPHA_MIN:.6g}, {ALPHA_MAX:g}]")
    return (alpha,)


ALPHA = Option(
    name="alpha",
    default=0.0,
    description="HHT numerical dissipation, in [-1/3, 0]; 0 is trapezoidal Newmark (no damping)",
    parse=_parse_alpha,
    long_name="HHT numerical dissipation alpha",
    units="1",
)

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (ALPHA, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)
_ALPHA = _SLOTS["alpha"]


@jit
def residual(a, w, inertia_, moment):
    """Dynamic equilibrium residual ``J A + W x J W - T`` in the body frame."""
    jw = to_momentum(w, inertia_)
    return sub(add(to_momentum(a, inertia_), cross(w, jw)), moment)


@jit
def jacobian(w, inertia_, cw, alpha, d):
    """``(1 + alpha) (J + d ([W]x J - [J W]x + C))`` at spin ``w``, ``cw`` the damping
    coefficients ``C``, ``d = h gamma`` (module docstring)."""
    jw = to_momentum(w, inertia_)
    k = skew_matmul(w, inertia_)
    c = 1.0 + alpha
    return (
        (c * (inertia_[0] + d * (k[0][0] + cw[0])), c * d * (k[0][1] + jw[2]), c * d * (k[0][2] - jw[1])),
        (c * d * (k[1][0] - jw[2]), c * (inertia_[1] + d * (k[1][1] + cw[1])), c * d * (k[1][2] + jw[0])),
        (c * d * (k[2][0] + jw[1]), c * d * (k[2][1] - jw[0]), c * (inertia_[2] + d * (k[2][2] + cw[2]))),
    )


@jit
def newmark(alpha):
    """``(gamma, beta)`` of HHT-alpha (module docstring)."""
    return 0.5 - alpha, 0.25 * (1.0 - alpha) ** 2


@jit
def init_inplace(y, p, opt, t, h, work):
    q = read4(y, S.QUATERNION)
    w = read3(y, S.OMEGA)
    write3(work, _ANGULAR, euler_rates(w, inertia(p), body_moment(q, w, p, t)))
    write3(work, _LINEAR, scale(1.0 / p[S.MASS], space_force(q, p, t)))
    return OK


# The step's formulas, each written once for the single body (`advance`) and the block
# (`block_step`), which call them in the same order: `newton_start`, then per Newton pass
# `rotation`, the frame's exponential, `equilibrium`, `newton_test` and `newton_update`, then
# `step_end` (compensated: `translation` and `newmark_velocity` as increments).


@inline_jit
def newmark_velocity(v, a_old, a_new, h, gamma, increment):
    """Newmark's ``v + h ((1 - gamma) a_old + gamma a_new)``, or with ``increment`` (a
    constant where it is inlined) its increment."""
    start = scale(h * (1.0 - gamma), a_old) if increment else axpy(h * (1.0 - gamma), a_old, v)
    return axpy(h * gamma, a_new, start)


@inline_jit
def newmark_displacement(start, a_old, a_new, h, beta):
    """Newmark's ``start + h^2 ((1/2 - beta) a_old + beta a_new)``, ``start`` the
    displacement's ``x + h v`` or the increment's ``h v``."""
    return axpy(h * h * beta, a_new, axpy(h * h * (0.5 - beta), a_old, start))


@inline_jit
def newton_start(w, inertia_, a_old, moment_old):
    """``(r_n, residual scale, first iterate of A_n+1)`` of a body at spin ``w``, ``A_n`` =
    ``a_old``, body moment ``moment_old``."""
    r_old = residual(a_old, w, inertia_, moment_old)
    scale_ = (
        norm(to_momentum(w, inertia_)) * norm(w)
        + norm(to_momentum(a_old, inertia_))
        + norm(moment_old)
        + 1e-300
    )
    return r_old, scale_, a_old


@inline_jit
def rotation(w, a_old, a_new, h, gamma, beta):
    """``(W_n+1, Theta)`` at the iterate ``A_n+1`` = ``a_new`` (module docstring)."""
    w_new = newmark_velocity(w, a_old, a_new, h, gamma, False)
    return w_new, newmark_displacement(scale(h, w), a_old, a_new, h, beta)


@inline_jit
def equilibrium(a_new, w_new, inertia_, moment_new, r_old, alpha):
    """Newton's residual ``(1 + alpha) r_n+1 - alpha r_n`` at the iterate ``a_new``."""
    return sub(scale(1.0 + alpha, residual(a_new, w_new, inertia_, moment_new)), scale(alpha, r_old))


@inline_jit
def newton_update(a_new, w_new, inertia_, damping, alpha, d, g):
    """The next iterate from ``a_new`` and its residual ``g``, ``d = h gamma``, ``damping``
    the coefficients ``C`` of a damping moment. The Jacobian leaves out how a moment that
    turns with the body (a space moment, a space force at a node) changes with ``q_n+1``: a
    quasi-Newton step, converging all the same at the steps where the scheme is accurate."""
    return sub(a_new, solve3(jacobian(w_new, inertia_, damping, alpha, d), g))


@inline_jit
def translation(x, v, lin_old, f_old, f_new, mass, alpha, h, gamma, beta, increment):
    """``(x_n+1, v_n+1, a_n+1)``: the rotation's Newmark weights, and HHT's ``a_n+1 = F/m +
    alpha/(1+alpha) (a_n - F_n/m)``; with ``increment`` (a constant where it is inlined) the
    increments of ``x`` and ``v``."""
    f_old, f_new = scale(1.0 / mass, f_old), scale(1.0 / mass, f_new)
    lin_new = axpy(alpha / (1.0 + alpha), sub(lin_old, f_old), f_new)
    x_new = newmark_displacement(scale(h, v) if increment else axpy(h, v, x), lin_old, lin_new, h, beta)
    return x_new, newmark_velocity(v, lin_old, lin_new, h, gamma, increment), lin_new


@inline_jit
def step_end(x, v, q_new, lin_old, f_old, f_new, mass, alpha, h, gamma, beta):
    """``(x_n+1, v_n+1, a_n+1)`` (`translation`) and the frame ``q_n+1`` renormalised."""
    x, v, lin_new = translation(x, v, lin_old, f_old, f_new, mass, alpha, h, gamma, beta, False)
    return x, v, lin_new, quat_normalize(q_new)


@inline_jit
def advance(y, p, opt, t, h, work, compensated):
    """One step (module docstring), its updates added as increments with compensation when
    ``compensated`` (a constant where it is inlined, so each kernel keeps one of the two)."""
    alpha = opt[_ALPHA]
    gamma, beta = newmark(alpha)
    inertia_ = inertia(p)
    q, w = read4(y, S.QUATERNION), read3(y, S.OMEGA)
    a_old = read3(work, _ANGULAR)
    r_old, scale_, a_new = newton_start(w, inertia_, a_old, body_moment(q, w, p, t))
    converged, going_on, iterations = False, True, 0
    while going_on:
        w_new, theta = rotation(w, a_old, a_new, h, gamma, beta)
        q_new = quat_mul(q, quat_exp_poly(theta))
        g = equilibrium(a_new, w_new, inertia_, body_moment(q_new, w_new, p, later(t, h)), r_old, alpha)
        bound = NEWTON_RESIDUAL_RTOL * scale_
        converged, update, going_on = newton_test(True, norm(g), bound, iterations + 1)
        if update:
            # -dT/dW of a damping moment (zero without)
            a_new = newton_update(a_new, w_new, inertia_, spin_damping(p), alpha, h * gamma, g)
            iterations += 1
    if not converged:
        return NOT_CONVERGED, iterations

    v, x = read3(y, S.VELOCITY), read3(y, S.POSITION)
    lin_old = read3(work, _LINEAR)
    f_old, f_new, mass = space_force(q, p, t), space_force(q_new, p, later(t, h)), p[S.MASS]
    if compensated:
        dx, dv, lin_new = translation(x, v, lin_old, f_old, f_new, mass, alpha, h, gamma, beta, True)
        add3_inplace(y, S.POSITION, dx, work, _CARRY)
        add3_inplace(y, S.VELOCITY, dv, work, _CARRY)
        turn_inplace(y, quat_exp_minus_one(theta), work, _CARRY)
        add3_inplace(y, S.OMEGA, newmark_velocity(w, a_old, a_new, h, gamma, True), work, _CARRY)
    else:
        x, v, lin_new, q = step_end(x, v, q_new, lin_old, f_old, f_new, mass, alpha, h, gamma, beta)
        write3(y, S.POSITION, x)
        write3(y, S.VELOCITY, v)
        write4(y, S.QUATERNION, q)
        write3(y, S.OMEGA, w_new)
    write3(work, _ANGULAR, a_new)
    write3(work, _LINEAR, lin_new)
    return OK, iterations


@jit
def step_inplace(y, p, opt, t, h, work):
    return advance(y, p, opt, t, h, work, False)


@jit
def compensated_step_inplace(y, p, opt, t, h, work):
    return advance(y, p, opt, t, h, work, True)


# block rows: A_n and a_n, carried from step to step (the work's first six floats); scratch:
# each lane's r_n and residual scale, its A_n+1, whether it iterates and whether it converged,
# its iterations, the rotation vector Theta and its exponential, q_n+1 and W_n+1
_ANGULAR_ROWS, _LINEAR_ROWS = B.WORK + _ANGULAR, B.WORK + _LINEAR
_R_OLD, _SCALE, _A_NEW, _ACTIVE, _CONVERGED, _STEP_ITERATIONS, _THETA, _EXP, _Q_NEW, _W_NEW = scratch_rows(
    "hht",
    r_old=3,
    scale=1,
    a_new=3,
    active=1,
    converged=1,
    step_iterations=1,
    theta=3,
    exp=4,
    q_new=4,
    w_new=3,
)
# a block step runs only without loads in time, and so without a damping moment
_NO_DAMPING = (0.0, 0.0, 0.0)


@jit
def _block_start(block, alpha):
    """Each lane's `newton_start`; a lane iterates when booked."""
    for lane in range(B.BLOCK):
        q, w = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, B.STATE + S.OMEGA, lane)
        inertia_, a_old = B.column3(block, B.PARAM + S.INERTIA, lane), B.column3(block, _ANGULAR_ROWS, lane)
        r_old, scale_, a_new = newton_start(w, inertia_, a_old, B.loads_at(block, q, w, lane)[0])
        B.set_column3(block, _R_OLD, lane, r_old)
        block[_SCALE * B.BLOCK + lane] = scale_
        B.set_column3(block, _A_NEW, lane, a_new)
    B.start_newton(block, _ACTIVE)


@jit
def _block_rotation(block, h, alpha):
    """Each lane's `rotation` at its iterate."""
    gamma, beta = newmark(alpha)
    for lane in range(B.BLOCK):
        w, a_old = B.column3(block, B.STATE + S.OMEGA, lane), B.column3(block, _ANGULAR_ROWS, lane)
        w_new, theta = rotation(w, a_old, B.column3(block, _A_NEW, lane), h, gamma, beta)
        B.set_column3(block, _W_NEW, lane, w_new)
        B.set_column3(block, _THETA, lane, theta)


@jit
def _block_newton(block, h, alpha):
    """One pass of `advance`'s loop on every lane that iterates (selects): the residual at
    its iterate, the test, the update; returns how many lanes still iterate."""
    gamma, _ = newmark(alpha)
    active = 0
    for lane in range(B.BLOCK):
        inertia_ = B.column3(block, B.PARAM + S.INERTIA, lane)
        q, w_new = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, _W_NEW, lane)
        q_new = quat_mul(q, B.column4(block, _EXP, lane))
        a_new = B.column3(block, _A_NEW, lane)
        moment_new = B.loads_at(block, q_new, w_new, lane)[0]
        g = equilibrium(a_new, w_new, inertia_, moment_new, B.column3(block, _R_OLD, lane), alpha)
        iterating = B.at(block, _ACTIVE, lane) != 0.0
        taken = B.at(block, _STEP_ITERATIONS, lane)
        bound = NEWTON_RESIDUAL_RTOL * B.at(block, _SCALE, lane)
        converged, update, going_on = newton_test(iterating, norm(g), bound, taken + 1.0)
        a_next = newton_update(a_new, w_new, inertia_, _NO_DAMPING, alpha, h * gamma, g)
        B.set_column3(block, _A_NEW, lane, a_next if update else a_new)
        B.set_column4(block, _Q_NEW, lane, q_new if iterating else B.column4(block, _Q_NEW, lane))
        taken = taken + 1.0 if update else taken
        active += book_newton_pass(block, _ACTIVE, lane, converged, going_on, taken)
    return active


@jit
def _block_end(block, h, alpha):
    """`step_end` of every lane (a lane that did not converge is no longer booked), its spin,
    the carried accelerations, its verdict and iterations."""
    gamma, beta = newmark(alpha)
    for lane in range(B.BLOCK):
        q, w = B.column4(block, B.STATE + S.QUATERNION, lane), B.column3(block, B.STATE + S.OMEGA, lane)
        q_new, w_new = B.column4(block, _Q_NEW, lane), B.column3(block, _W_NEW, lane)
        _, mass, f_old = B.loads_at(block, q, w, lane)
        _, _, f_new = B.loads_at(block, q_new, w_new, lane)
        v, x = B.column3(block, B.STATE + S.VELOCITY, lane), B.column3(block, B.STATE + S.POSITION, lane)
        lin_old = B.column3(block, _LINEAR_ROWS, lane)
        x, v, lin_new, q = step_end(x, v, q_new, lin_old, f_old, f_new, mass, alpha, h, gamma, beta)
        B.set_column3(block, B.STATE + S.POSITION, lane, x)
        B.set_column3(block, B.STATE + S.VELOCITY, lane, v)
        B.set_column4(block, B.STATE + S.QUATERNION, lane, q)
        B.set_column3(block, B.STATE + S.OMEGA, lane, w_new)
        B.set_column3(block, _ANGULAR_ROWS, lane, B.column3(block, _A_NEW, lane))
        B.set_column3(block, _LINEAR_ROWS, lane, lin_new)
    B.end_newton(block, _ACTIVE)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time, that share the option row ``opt`` (N_OPTION,): ``block`` (N_ROWS * BLOCK,) as
    `rbstudy.numerics.block` lays it out, Newton's passes while any lane iterates. Each body's
    bits, status and iterations are those of `step_inplace`."""
    alpha = opt[_ALPHA]
    _block_start(block, alpha)
    for _ in range(NEWTON_MAX_ITERATIONS + 1):
        _block_rotation(block, h, alpha)
        B.quat_exp_columns(block, _THETA, _EXP)
        if _block_newton(block, h, alpha) == 0:
            break
    _block_end(block, h, alpha)


SCHEME = Scheme(
    name="hht",
    summary="Newmark/HHT-alpha on SO(3), material form (Abaqus implicit dynamics)",
    step_seconds=1.59e-07,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=5.0e-08,
    order=2,
    implicit=True,
    keeps=(),
    run_bodies_inplace=make_entry(
        step_inplace,
        init_inplace,
        N_WORK,
        switch=switch(compensated_step_inplace, init_inplace, _SLOTS),
        block=block_step,
    ),
    reference="Simo & Vu-Quoc, CMAME 66 (1988) 125; Hilber, Hughes & Taylor, EESD 5 (1977) 283",
    options=_OPTIONS,
    style=Style("tab:brown", "D", "-"),
)
