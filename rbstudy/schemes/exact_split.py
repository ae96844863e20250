"""`exact_split`: the exact free flow between half kicks of the loads (Strang splitting).

A step is

    kick(h/2):  m += h/2 M_b(q, t),     v += h/2 F(q, t) / mass
    free(h):    (q, w) <- the exact force-free motion for a time h,  x += h v
    kick(h/2):  the loads at t + h

with the free motion of any principal inertias in closed form (Jacobi elliptic functions and
the elliptic integral of the third kind, `rbstudy.numerics.free_flow`; docs/theory.md s3):
its constants are computed once per step from the state after the first kick.

Without loads the step is the exact flow: a free body is integrated to round-off at any dt,
up to the whole run in one step. Under loads it is of order 2, symmetric and explicit; option
``composition`` raises it to 4, 6 or 8 (`rbstudy.schemes._composition`). For the free body
it keeps the energy, ``|m|`` and ``L`` to round-off (it is the exact flow); under loads only
the kicks change them, as the loads do. Option ``compensated`` adds the kicks', the drift's
and the free flow's increments with compensated summation, the flow's written as differences
from the start without cancellation (`rbstudy.numerics.free_increment`); the stages of a
composition share the carry. The integrated references run it so (docs/theory.md s6, s8).
Reference: Celledoni, Fasso, Safstrom & Zanna, SIAM J. Sci. Comput. 30 (2008) 2084.
"""

from rbstudy.numerics import state as S
from rbstudy.numerics.clock import later
from rbstudy.numerics.compensated import add3_inplace, add4_inplace, normalize_inplace
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import inertia
from rbstudy.numerics.free_flow import free_body, free_motion
from rbstudy.numerics.free_increment import free_increment
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import quat_normalize, read3, read4, write3, write4
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

# work: the carry of the compensated sums
_CARRY = 0
N_WORK = _CARRY + CARRY_WIDTH

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (COMPOSITION, COMPENSATED)
_SLOTS = option_slots(_OPTIONS)


@inline_jit
def symmetric_step(y, p, opt, t, h, work):
    """One Strang step (module docstring)."""
    kick_inplace(y, p, t, 0.5 * h)
    body = free_body(inertia(p), read3(y, S.OMEGA))
    q, w = free_motion(body, read4(y, S.QUATERNION), h)
    write4(y, S.QUATERNION, quat_normalize(q))
    write3(y, S.OMEGA, w)
    drift_inplace(y, h)
    kick_inplace(y, p, later(t, h), 0.5 * h)
    return OK, 0


@jit
def compensated_step(y, p, opt, t, h, work):
    """`symmetric_step` with every increment added with compensation."""
    compensated_kick_inplace(y, p, t, 0.5 * h, work, _CARRY)
    body = free_body(inertia(p), read3(y, S.OMEGA))
    dq, dw = free_increment(body, read4(y, S.QUATERNION), h)
    add4_inplace(y, S.QUATERNION, dq, work, _CARRY)
    add3_inplace(y, S.OMEGA, dw, work, _CARRY)
    normalize_inplace(y, work, _CARRY)
    compensated_drift_inplace(y, h, work, _CARRY)
    compensated_kick_inplace(y, p, later(t, h), 0.5 * h, work, _CARRY)
    return OK, 0


SCHEME = Scheme(
    name="exact_split",
    summary="exact free flow (elliptic functions) between half kicks; exact for a free body",
    step_seconds=1.0e-06,
    order=2,
    implicit=False,
    keeps=("energy", "momentum_vector"),
    run_bodies_inplace=composed_entry(
        symmetric_step,
        init_nothing,
        N_WORK,
        _SLOTS["composition"],
        switch=switch(compensated_step, init_nothing, _SLOTS),
    ),
    reference="Celledoni, Fasso, Safstrom & Zanna, SIAM J. Sci. Comput. 30 (2008) 2084",
    options=_OPTIONS,
    style=Style("tab:cyan", "v", "-"),
)
