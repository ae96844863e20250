"""Symmetric compositions that raise a symmetric second-order step to order 4, 6 or 8.

For a step ``S(h)`` that is symmetric (its own adjoint, ``S(-h) S(h) = 1``) and of order 2,
the composition ``S(g_s h) ... S(g_2 h) S(g_1 h)`` with symmetric weights ``g_i = g_{s+1-i}``
summing to 1 is of order 4, 6 or 8 for the weights below (Hairer, Lubich & Wanner, Geometric
Numerical Integration, 2nd ed., section V.3.2). It inherits what every stage keeps: a
composition of a step that keeps ``L`` keeps ``L``. Option ``composition`` (2, 4, 6 or 8;
2 is the step itself) is packed per body, so one compiled kernel serves every order and a
sweep over it needs no recompilation.

- order 4: the triple jump, ``g = (w1, 1 - 2 w1, w1)``, ``w1 = 1 / (2 - 2^(1/3))``
  (Yoshida, Phys. Lett. A 150 (1990) 262);
- order 6: Kahan & Li's s9odr6a, 9 stages;
- order 8: Kahan & Li's s17odr8a, 17 stages
  (Kahan & Li, Math. Comp. 66 (1997) 1089; the digits as tabulated by Hairer, Lubich & Wanner,
  section V.3.2). Their error constants are much smaller than Yoshida's 7- and 15-stage
  solutions of the same orders.

Stage ``i`` starts at the time ``t + h (g_1 + ... + g_(i-1))``, which steps back in time where
a weight is negative; loads tabulated in time are taken there. The triple jump's stages
reach 0.35 h outside the step (`stage_reach`), across a knot or an end of the load tables,
so it is of order 2 only under loads tabulated in time (study validation warns); the stages
of the other two stay inside the step.
"""

from collections.abc import Callable
from typing import Any

import numpy as np

from rbstudy.numerics.clock import later
from rbstudy.numerics.entry import CachedEntry, make_entry
from rbstudy.numerics.jit import inline_jit
from rbstudy.numerics.state import OK
from rbstudy.schemes._registry import Option

__all__ = [
    "COMPOSITION",
    "ORDERS",
    "stage_weights",
    "stage_reach",
    "composed_step",
    "composed_block_step",
    "composed_entry",
]

_TRIPLE_JUMP = 1.0 / (2.0 - 2.0 ** (1.0 / 3.0))
# the weights from the outermost stage to the centre; the others mirror them
_OUTER_TO_CENTRE = {
    2: (1.0,),
    4: (_TRIPLE_JUMP, 1.0 - 2.0 * _TRIPLE_JUMP),
    6: (
        0.39216144400731413927925056,
        0.33259913678935943859974864,
        -0.70624617255763935980996482,
        0.08221359629355080023149045,
        0.79854399093482996339895035,
    ),
    8: (
        0.13020248308889008087881763,
        0.56116298177510838456196441,
        -0.38947496264484728640807860,
        0.15884190655515560089621075,
        -0.39590389413323757733623154,
        0.18453964097831570709183254,
        0.25837438768632204729397911,
        0.29501172360931029887096624,
        -0.60550853383003451169892108,
    ),
}
ORDERS = tuple(_OUTER_TO_CENTRE)


def stage_weights(order: int) -> tuple[float, ...]:
    """The weights ``g_1 .. g_s`` of the composition of ``order`` (a tuple of floats)."""
    half = _OUTER_TO_CENTRE[order]
    return half + half[-2::-1]


def stage_reach(order: int) -> tuple[float, float]:
    """``(earliest, latest)`` time of any stage of the composition of ``order``, as fractions
    of the step from its start: the triple jump reaches (-0.35, 1.35), outside its step; the
    Kahan-Li compositions stay inside it."""
    ends = np.cumsum((0.0,) + stage_weights(order))
    return float(ends.min()), float(ends.max())


def _stage_table():
    """(order + 1, most stages) weights, row ``order`` zero-padded, and the (order + 1,)
    stage counts: constants that numba compiles into the kernel."""
    table = np.zeros((max(ORDERS) + 1, len(stage_weights(max(ORDERS)))))
    counts = np.zeros(max(ORDERS) + 1, dtype=np.int64)
    for order in ORDERS:
        weights = stage_weights(order)
        counts[order] = len(weights)
        table[order, : len(weights)] = weights
    return table, counts


_STAGES, _STAGE_COUNT = _stage_table()


def _parse_composition(value):
    if isinstance(value, bool) or value not in ORDERS:
        raise ValueError(
            f"expected one of {', '.join(map(str, ORDERS))} "
            "(the order of the composition; 2 is the step itself)"
        )
    return (float(value),)


COMPOSITION = Option(
    name="composition",
    default=2,
    description=(
        "order of a symmetric composition of the step: 4 (triple jump, 3 stages), 6 (Kahan-Li, "
        "9 stages) or 8 (Kahan-Li, 17 stages); 2 is the step itself"
    ),
    parse=_parse_composition,
    sets_order=True,
    cost=lambda order: len(stage_weights(order)),
    long_name="order of the symmetric composition of the step",
    units="1",
)


# Inlined into each scheme's step (`composed_entry`): called, it would receive ``step`` as a
# value, a "dynamic global" that keeps numba from caching the step (numba 0.68). Each scheme inlines
# its symmetric step as well (`inline_jit`): called from the two sites below, LLVM kept it a
# call, which cost the plain step a share of its speed (rbstudy bench, splitting and midpoint).
@inline_jit
def composed_step(step, slot, y, p, opt, t, h, work):
    """Advance state row ``y`` (N_STATE,) by ``h`` with the composition of ``step`` (a compiled
    symmetric step ``step(y, p, opt, t, h, work)``) that option ``composition``, at ``slot``
    of ``opt`` (N_OPTION,), asks for (the default 0, and 2: the step itself). Returns
    ``(status, Newton iterations summed over the stages)``; a stage that fails ends the step
    with its status."""
    order = int(opt[slot])
    if order <= 2:
        return step(y, p, opt, t, h, work)
    iterations = 0
    elapsed = 0.0
    for i in range(_STAGE_COUNT[order]):
        d = _STAGES[order, i] * h
        status, stage_iterations = step(y, p, opt, later(t, elapsed), d, work)
        iterations += stage_iterations
        if status != OK:
            return status, iterations
        elapsed += d
    return OK, iterations


@inline_jit
def composed_block_step(step, slot, block, opt, h):
    """`composed_step` of a block step ``step(block, opt, h)`` (`rbstudy.numerics.block`) on
    a block whose bodies share the option row ``opt`` (N_OPTION,): the stages of every lane in
    turn, with the same stage lengths. A lane that fails in a stage sets its row ``VERDICT``,
    which the stages after it leave as it is (the block step's own business, as it is a step's
    to return its status)."""
    order = int(opt[slot])
    if order <= 2:
        step(block, opt, h)
        return
    for i in range(_STAGE_COUNT[order]):
        step(block, opt, _STAGES[order, i] * h)


def composed_entry(
    symmetric_step: Callable[..., Any],
    init: Callable[..., Any],
    n_work: int,
    slot: int,
    switch: tuple[int, Callable[..., Any], Callable[..., Any]] | None = None,
    block: Callable[..., Any] | None = None,
) -> CachedEntry:
    """The entry point (`rbstudy.numerics.entry.make_entry`) of a scheme whose step is its
    ``symmetric_step`` composed as option ``composition``, at ``slot`` of the scheme's option
    row (`rbstudy.schemes.option_slots`), asks (`composed_step`); a ``switch``'s step is
    composed alike; a ``block`` step composes itself (`composed_block_step`)."""
    return make_entry(symmetric_step, init, n_work, wrapper=(composed_step, slot), switch=switch, block=block)
