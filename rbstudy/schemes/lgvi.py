"""`lgvi`: the Lie group variational integrator of Lee, Leok & McClamroch, whose free step is
the discrete Moser-Veselov algorithm (published group).

With ``Pi = I w`` the body momentum and ``J_d = tr(I)/2 - I`` the nonstandard inertia, the
free step finds the rotation ``F`` with

    h [Pi]x = F J_d - J_d F^T,    R+ = R F,    Pi+ = F^T Pi

which is Moser & Veselov's discrete rigid body (1991) with the time step written out. Loads
enter as the integrator itself takes them: ``h Pi + h^2/2 M_k = F J_d - J_d F^T`` and
``Pi+ = F^T (Pi + h/2 M_k) + h/2 M_{k+1}`` are exactly a half kick, the free step and a half
kick (`rbstudy.schemes._kicks.split_step`), and the centre of mass takes the same
kick-drift-kick (velocity Verlet).

With ``F = cay(f)`` (`rbstudy.numerics.rotation.quat_cayley`: the rotation by
``2 atan(|f|/2)`` about ``f``), the matrix equation is the vector equation

    G(f) = (1 + |f|^2/4) h Pi - I f - 1/2 f x I f = 0

(as ``F J_d - J_d F^T = [I f + 1/2 f x I f]x / (1 + |f|^2/4)``), solved by Newton from
``f = h w`` with the Jacobian ``1/2 h Pi f^T - I - 1/2 ([f]x I - [I f]x)``.

The step exists for small enough ``h`` only: about a principal axis ``k`` the equation is
``h w = sin(psi)`` for a turn ``psi``, so a steady spin turns by ``asin(h w)`` a step (the
exact flow at a stretched time) and past ``h w = 1`` no rotation solves it: the body ends
``not_converged`` there, as a result.

Order 2, implicit, symmetric and symplectic; order 4, 6 or 8 composed (option
``composition``). For the free body it keeps ``L = R Pi`` and ``|Pi|`` to round-off
(``R+ Pi+ = R F F^T Pi``), and the energy too: Moser & Veselov's discrete body is integrable
and keeps ``Pi . I^-1 Pi`` (measured: 7e-15 relative over 10,000 steps on I = (1, 2, 3)).
References: Lee, Leok & McClamroch, Comput. Methods Appl. Mech. Engrg. 196 (2007) 2907
(and Proc. IEEE CCA 2005); Moser & Veselov, Commun. Math. Phys. 139 (1991) 217.
"""

from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import to_momentum
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import (
    axpy,
    cross,
    dot,
    norm,
    quat_cayley,
    scale,
    solve3,
    sub,
)
from rbstudy.numerics.state import NOT_CONVERGED, OK
from rbstudy.schemes._composition import COMPOSITION, composed_entry
from rbstudy.schemes._kicks import split_step, turned_frame
from rbstudy.schemes._newton import NEWTON_RTOL, newton_test
from rbstudy.schemes._registry import Scheme, Style, option_slots

N_WORK = 0

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPOSITION,)
_SLOTS = option_slots(_OPTIONS)
_COMPOSITION = _SLOTS["composition"]


@jit
def residual(f, impulse, inertia_):
    """``G(f)`` for ``impulse = h Pi`` (module docstring)."""
    i_f = (inertia_[0] * f[0], inertia_[1] * f[1], inertia_[2] * f[2])
    return sub(scale(1.0 + 0.25 * dot(f, f), impulse), axpy(0.5, cross(f, i_f), i_f))


@jit
def jacobian(f, impulse, inertia_):
    """``dG/df = 1/2 h Pi f^T - I - 1/2 ([f]x I - [I f]x)`` at ``f``, by rows."""
    a, b, c = inertia_[0] * f[0], inertia_[1] * f[1], inertia_[2] * f[2]
    # [f]x I - [I f]x, entry (i, j): the skew matrices' difference
    return (
        (
            0.5 * impulse[0] * f[0] - inertia_[0],
            0.5 * impulse[0] * f[1] - 0.5 * (-f[2] * inertia_[1] + c),
            0.5 * impulse[0] * f[2] - 0.5 * (f[1] * inertia_[2] - b),
        ),
        (
            0.5 * impulse[1] * f[0] - 0.5 * (f[2] * inertia_[0] - c),
            0.5 * impulse[1] * f[1] - inertia_[1],
            0.5 * impulse[1] * f[2] - 0.5 * (-f[0] * inertia_[2] + a),
        ),
        (
            0.5 * impulse[2] * f[0] - 0.5 * (-f[1] * inertia_[0] + b),
            0.5 * impulse[2] * f[1] - 0.5 * (f[0] * inertia_[1] - a),
            0.5 * impulse[2] * f[2] - inertia_[2],
        ),
    )


@jit
def solve_rotation(impulse, inertia_, f):
    """Newton on ``G(f) = 0`` from ``f``; returns ``(f, iterations, converged)``."""
    converged, going_on, iterations = False, True, 0
    while going_on:
        iterations += 1
        correction = solve3(jacobian(f, impulse, inertia_), residual(f, impulse, inertia_))
        f = sub(f, correction)
        converged, _, going_on = newton_test(True, norm(correction), NEWTON_RTOL * norm(f), iterations)
    return f, iterations, converged


@jit
def free_step(q, w, inertia_, opt, h):
    """The discrete Moser-Veselov step: ``(status, iterations, q+, w+)``."""
    m = to_momentum(w, inertia_)
    f, iterations, converged = solve_rotation(scale(h, m), inertia_, scale(h, w))
    if not converged:
        return NOT_CONVERGED, iterations, q, w
    q_next, w_next = turned_frame(q, m, quat_cayley(f), inertia_)
    return OK, iterations, q_next, w_next


@jit
def symmetric_step(y, p, opt, t, h, work):
    """One second-order step (module docstring): the free step between half kicks."""
    return split_step(free_step, y, p, opt, t, h)


SCHEME = Scheme(
    name="lgvi",
    summary="Lee-Leok-McClamroch Lie group variational step (discrete Moser-Veselov); energy, L kept",
    # a body-step, one body after another (`rbstudy bench`, B = 1e4 on one core)
    step_seconds=2.02e-07,
    order=2,
    implicit=True,
    keeps=("energy", "momentum_vector"),
    run_bodies_inplace=composed_entry(symmetric_step, init_nothing, N_WORK, _COMPOSITION),
    reference="Lee, Leok & McClamroch, CMAME 196 (2007) 2907; Moser & Veselov, CMP 139 (1991) 217",
    options=_OPTIONS,
    group="published",
    style=Style("dodgerblue", "X", ":"),
)
