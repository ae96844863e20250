"""`jolt`: the gyroscopic step of the Jolt physics engine, read from its public code as a
formula (published group).

Jolt (``MotionProperties::ApplyGyroscopicForceInternal``, then
``ApplyForceTorqueAndDragInternal`` and ``Body::AddRotationStep``) steps a body's spin by
an explicit Euler step of the gyroscopic term on the body momentum ``m = I w``, rescaled to
the length it had before the step so that no energy is pumped in, then adds the moment's
impulse and turns the frame with the new spin:

    m' = m + h m x w,    m' <- m' |m| / |m'|       (0 where m' = 0)
    w+ = I^-1 m' + h I^-1 M_b,    v+ = v + h F / mass
    x+ = x + h v+,    R+ = R exp(h [w+]x)

with ``M_b`` and ``F`` the loads at the step's start (Jolt's accumulated torque and force).
It is `leapfrog` with the body momentum rescaled after each gyroscopic update (a test shows
it). Jolt's engine settings are left out: its float32 arithmetic (this step is float64),
its clamp of |w| (47 rad/s by default), its damping, and its skip of rotations below 1e-6 rad.

Order 1, semi-implicit. For the free body it keeps ``|m|`` to round-off, nothing else: the
rescaled Euler step drains the energy of a body spinning about its major or minor axis
towards ``L^2 / (2 I_2)``, the energy of the intermediate axis (Avian PR 993's observation;
a test measures it).
Reference: Jolt Physics, Jolt/Physics/Body/MotionProperties.inl, ApplyGyroscopicForceInternal
(J. Rouwe, MIT licence, read 2026).
"""

import math

from rbstudy.numerics.block import TURN_ROWS
from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import momentum_rates, to_momentum, to_omega
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import inline_jit, jit
from rbstudy.numerics.rotation import add, axpy, dot, scale
from rbstudy.schemes._registry import Scheme, Style, scratch_rows
from rbstudy.schemes._turning import turning_block_step, turning_step

N_WORK = 0


@inline_jit
def rescaled_momentum(m, w, h):
    """Jolt's gyroscopic update of the body momentum ``m`` at spin ``w``: the Euler step
    ``m + h m x w`` scaled back to ``|m|`` (zero where the step lands on zero)."""
    stepped = axpy(h, momentum_rates(m, w, (0.0, 0.0, 0.0)), m)
    length_sq = dot(stepped, stepped)
    if length_sq > 0.0:
        return scale(math.sqrt(dot(m, m) / length_sq), stepped)
    return (0.0, 0.0, 0.0)


@inline_jit
def advance(x, v, w, inertia_, moment, mass, force, h):
    """The step of one body (module docstring; `rbstudy.schemes._turning` runs it): its
    position, velocity and spin after the step and the rotation vector ``h w+`` of its frame."""
    m = rescaled_momentum(to_momentum(w, inertia_), w, h)
    w_next = to_omega(axpy(h, moment, m), inertia_)
    v_next = axpy(h / mass, force, v)
    return add(x, scale(h, v_next)), v_next, w_next, scale(h, w_next)


@jit
def step_inplace(y, p, opt, t, h, work):
    return turning_step(advance, y, p, t, h)


# block scratch: the rotation vector h w+, then its quaternion (`turn_columns`)
(_TURN,) = scratch_rows("jolt", turn=TURN_ROWS)


@jit
def block_step(block, opt, h):
    """`step_inplace` of a block of bodies without a lever, a body-fixed force or loads in
    time: ``block`` (N_ROWS * BLOCK,) as `rbstudy.numerics.block` lays it out."""
    turning_block_step(advance, block, h, _TURN)


SCHEME = Scheme(
    name="jolt",
    summary="Jolt's gyroscopic step: Euler on m rescaled to |m|, then the frame; |L| kept",
    step_seconds=8.8e-08,
    # a body-step in blocks of bodies (`rbstudy bench`, B = 1e4 on one core)
    block_step_seconds=2.1e-08,
    order=1,
    implicit=False,
    kind="semi-implicit",
    keeps=("momentum_magnitude",),
    run_bodies_inplace=make_entry(step_inplace, init_nothing, N_WORK, block=block_step),
    reference="Jolt Physics, MotionProperties::ApplyGyroscopicForceInternal (J. Rouwe)",
    group="published",
    style=Style("olive", "P", "-"),
)
