"""Option ``compensated``: compensated summation of a fixed-step scheme's state updates.

Each scheme that offers it writes its step a second time in increment form and adds the
increments with `rbstudy.numerics.compensated` (docs/theory.md s8); the plain step is left as
it was, so that a run without the option gives the same bits as before it existed. The entry
point runs the rows with the option set with the compensated kernels (`switch`, passed to
`rbstudy.numerics.entry.make_entry`): the choice is made per body, not per step, so the
plain step keeps its speed. The carry sits in the scheme's work array from the offset the
scheme passes (`CARRY_WIDTH` floats).
"""

from collections.abc import Callable, Mapping
from typing import Any

from rbstudy.numerics.compensated import CARRY_WIDTH
from rbstudy.schemes._registry import Option, flag_parser

__all__ = ["COMPENSATED", "CARRY_WIDTH", "switch"]


# What a compensated step costs, in plain steps: between what the schemes that offer it were
# measured at, rkmk4 the least and splitting the most (docs/performance.md); `rbstudy
# validate` forecasts with this.
COST = 1.5


COMPENSATED = Option(
    name="compensated",
    default=0,
    description=(
        "1: add each step's increments with compensated summation (Kahan), so that a long run "
        "rounds like its increments, dt times finer; 0: plain sums"
    ),
    parse=flag_parser("compensate the sums"),
    cost=lambda value: COST if value else 1.0,
    long_name="compensated summation of the state updates",
    units="1",
)


def switch(
    step: Callable[..., Any], init: Callable[..., Any], slots: Mapping[str, int]
) -> tuple[int, Callable[..., Any], Callable[..., Any]]:
    """The ``switch`` of `rbstudy.numerics.entry.make_entry` that runs the bodies whose
    option ``compensated`` is set with the compensated kernels ``step`` and ``init``; ``slots``
    is the scheme's layout of its option row (`rbstudy.schemes.option_slots`)."""
    return (slots[COMPENSATED.name], step, init)
