"""`rk4`: classical Runge-Kutta on (x, q, v, w), quaternion renormalised after each step.

The ODE (docs/theory.md s1): ``dx/dt = v``, ``dq/dt = 1/2 q * (w, 0)``, ``dv/dt = F/mass``,
``dw/dt = I^-1 (M_b - w x I w)``; the classical four-stage tableau, then ``q <- q/|q|``
(the projection that Fukushima 2008 recommends).

Order 4, explicit. Keeps no invariant exactly: the energy error drifts linearly in time, and
the scheme blows up near ``h |nu| = 2.8`` (``nu`` the nutation frequency).
Reference: Fukushima, AJ 135 (2008) 2298, "Simple, regular, and efficient numerical
integration of rotational motion".
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.driver import init_nothing, make_entry
from rbstudy.numerics.dynamics import body_moment, euler_rates, inertia, space_force
from rbstudy.numerics.jit import jit
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
from rbstudy.schemes._registry import Scheme, Style
from rbstudy.schemes._rk import rk4_sum3, rk4_sum4

N_WORK = 0


@jit
def rates(q, v, w, p, t):
    """Time derivatives ``(dx, dq, dv, dw)`` at orientation ``q``, velocity ``v``, spin ``w``
    and time ``t``."""
    dq = quat_mul(q, (0.5 * w[0], 0.5 * w[1], 0.5 * w[2], 0.0))
    dv = scale(1.0 / p[S.MASS], space_force(q, p, t))
    dw = euler_rates(w, inertia(p), body_moment(q, w, p, t))
    return v, dq, dv, dw


@jit
def step_inplace(y, p, opt, t, h, work):
    x, q = read3(y, S.POSITION), read4(y, S.QUATERNION)
    v, w = read3(y, S.VELOCITY), read3(y, S.OMEGA)
    k1 = rates(q, v, w, p, t)
    k2 = rates(
        axpy4(0.5 * h, k1[1], q), axpy(0.5 * h, k1[2], v), axpy(0.5 * h, k1[3], w), p, later(t, 0.5 * h)
    )
    k3 = rates(
        axpy4(0.5 * h, k2[1], q), axpy(0.5 * h, k2[2], v), axpy(0.5 * h, k2[3], w), p, later(t, 0.5 * h)
    )
    k4 = rates(axpy4(h, k3[1], q), axpy(h, k3[2], v), axpy(h, k3[3], w), p, later(t, h))
    write3(y, S.POSITION, rk4_sum3(h, x, k1[0], k2[0], k3[0], k4[0]))
    write4(y, S.QUATERNION, quat_normalize(rk4_sum4(h, q, k1[1], k2[1], k3[1], k4[1])))
    write3(y, S.VELOCITY, rk4_sum3(h, v, k1[2], k2[2], k3[2], k4[2]))
    write3(y, S.OMEGA, rk4_sum3(h, w, k1[3], k2[3], k3[3], k4[3]))
    return OK, 0


SCHEME = Scheme(
    name="rk4",
    summary="classical Runge-Kutta 4 on (q, w), quaternion renormalised each step",
    step_seconds=1.28e-07,
    order=4,
    implicit=False,
    keeps=(),
    run_bodies_inplace=make_entry(step_inplace, init_nothing, N_WORK),
    reference="Fukushima, Astron. J. 135 (2008) 2298",
    # solid under rkmk4's dashed line: their curves coincide on a symmetric top
    style=Style("tab:red", "o", "-"),
)
