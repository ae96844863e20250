"""`buss`: Buss's second-order and augmented second-order rotation steps (published group).

Buss (2000) keeps the space angular momentum ``L`` as the state and turns the frame by a
rotation vector built from the spin ``w`` and its rate ``alpha = dw/dt`` at the step's start.
In body axes, with ``m = I w`` and Euler's free rate ``alpha = I^-1 (m x w)``:

    theta = h w + h^2/2 alpha                      (second-order method)
    theta = h w + h^2/2 alpha + h^3/12 alpha x w   (augmented second-order method)
    R+ = R exp([theta]x),    m+ = exp(-[theta]x) m  (L = R m unchanged),    w+ = I^-1 m+

The ``h^3/12 alpha x w`` term is the first commutator of the Magnus expansion of the frame's
equation for a spin linear in time (option ``augmented``). Buss's paper treats the free body;
loads enter by rbstudy's Strang splitting (`rbstudy.schemes._kicks.split_step`): kick(h/2),
the rotation step, kick(h/2), which keeps order 2.

Order 2, explicit, not symmetric (so not composed). For the free body it keeps ``L`` and
``|m|`` to round-off (the frame turns, ``L`` does not); the energy is not kept. The
augmented term removes the commutator from the one-step error, which leaves ``h^3/6`` times
the spin's second derivative (a test checks that coefficient, so the term's sign is checked);
it does not by itself keep the energy better: on I = (1, 2, 3) over 300 s at h = 0.03 s the
largest energy error is 4.6e-3 (relative) with it off and 7.0e-3 with it on.
Reference: S. R. Buss, "Accurate and efficient simulation of rigid-body rotations",
J. Comput. Phys. 164 (2000) 377-406, section 3 (second-order and augmented second-order).
"""

from rbstudy.numerics.driver import init_nothing
from rbstudy.numerics.dynamics import to_momentum, to_omega
from rbstudy.numerics.entry import make_entry
from rbstudy.numerics.jit import jit
from rbstudy.numerics.rotation import (
    axpy,
    cross,
    quat_exp,
    scale,
)
from rbstudy.numerics.state import OK
from rbstudy.schemes._kicks import split_step, turned_frame
from rbstudy.schemes._registry import Option, Scheme, Style, flag_parser, option_slots

N_WORK = 0


AUGMENTED = Option(
    name="augmented",
    default=0,
    description="1: Buss's augmented second-order step (adds h^3/12 alpha x w to the rotation); "
    "0: his second-order step",
    parse=flag_parser("add Buss's h^3/12 term"),
    long_name="Buss's augmented second-order term",
    units="1",
)

# the option row as the registry lays it out (`option_slots`): where the kernels read each option
_OPTIONS = (AUGMENTED,)
_SLOTS = option_slots(_OPTIONS)
_AUGMENTED = _SLOTS["augmented"]


@jit
def rotation_vector(w, inertia_, h, augmented):
    """Buss's rotation vector ``theta`` (rad, body axes) for spin ``w`` (module docstring),
    with the ``h^3/12 alpha x w`` term when ``augmented``."""
    alpha = to_omega(cross(to_momentum(w, inertia_), w), inertia_)
    theta = axpy(0.5 * h * h, alpha, scale(h, w))
    if augmented:
        theta = axpy(h * h * h / 12.0, cross(alpha, w), theta)
    return theta


@jit
def free_step(q, w, inertia_, opt, h):
    """The free step: the frame turned by `rotation_vector`, the body momentum turned back by
    it (``L`` unchanged); ``(OK, 0, q+, w+)``."""
    turn = quat_exp(rotation_vector(w, inertia_, h, opt[_AUGMENTED] != 0.0))
    q_next, w_next = turned_frame(q, to_momentum(w, inertia_), turn, inertia_)
    return OK, 0, q_next, w_next


@jit
def step_inplace(y, p, opt, t, h, work):
    """One step (module docstring): the free step between half kicks."""
    return split_step(free_step, y, p, opt, t, h)


SCHEME = Scheme(
    name="buss",
    summary="Buss (2000) second-order rotation step (option augmented: his h^3/12 term); L kept",
    # a body-step, one body after another (`rbstudy bench`, B = 1e4 on one core)
    step_seconds=1.53e-07,
    order=2,
    implicit=False,
    keeps=("momentum_vector",),
    run_bodies_inplace=make_entry(step_inplace, init_nothing, N_WORK),
    reference="S. R. Buss, J. Comput. Phys. 164 (2000) 377",
    options=_OPTIONS,
    group="published",
    style=Style("crimson", "H", "--"),
)
