"""What a scheme is, as the rest of rbstudy sees it: capabilities, options, compiled entry, and
how its lines are drawn."""

import math
import numbers
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np
from numba import types

from rbstudy.errors import SchemeError, one_line
from rbstudy.numerics import state as S

__all__ = ["Option", "Scheme", "Style", "INVARIANTS"]

INVARIANTS = S.INVARIANTS


@dataclass(frozen=True)
class Option:
    """A scheme option: its default, what it means, and how it is packed for the kernel.

    ``parse(value) -> tuple of floats`` validates a user value and returns the ``width`` floats
    stored at ``slot`` onward in the body's option row; it raises ``ValueError`` with the
    expectation. The slot is the option's own, not the scheme's: a kernel reads it as a
    constant, and an option shared by several schemes (``composition``) is read by one
    compiled function at one slot in all of them. The registry checks the layout when a
    scheme is registered (`Scheme`): every option inside the row, no two on one slot.
    ``sets_order``: the option's value is the scheme's nominal order (a composition).
    ``cost(value)``: how many plain steps one step takes with that value (the stages of a
    composition); None for an option that does not change the cost. ``long_name`` (at most
    60 characters: a plot's axis label) and ``units`` (CF, "1" for a number without; None for
    a label such as an axis order) label the option's coordinate in an archive that sweeps
    it; without a long_name the coordinate is labelled with the option's name.
    """

    name: str
    default: Any
    description: str
    slot: int
    parse: Callable[[Any], tuple]
    sets_order: bool = False
    cost: Callable[[Any], int] | None = None
    long_name: str = ""
    units: str | None = None
    width: int = 1

    @property
    def slots(self):
        """The slots of the option row the option fills."""
        return range(self.slot, self.slot + self.width)


class Style(NamedTuple):
    """How a scheme's lines are drawn in every figure: a matplotlib colour, marker and line
    style ("-" solid, "--", "-.", ":"). A solid line is drawn wide under large hollow markers,
    the others narrow over small filled ones, so that two schemes whose curves coincide stay
    visible when one is solid and the other not."""

    color: str
    marker: str
    dash: str


@dataclass(frozen=True)
class Scheme:
    """A registered integrator.

    Attributes
    ----------
    name : registry name used in configs and on the command line.
    summary : one line for `rbstudy schemes`.
    order : nominal global order of accuracy with the options' defaults (`nominal_order`).
    step_seconds : core-seconds one body-step takes, as `rbstudy bench` measured it on the
        development machine (one core, 1e4 bodies; dop853: per accepted step); the run-time
        forecast of `rbstudy validate` starts from it. A number above 0 and finite.
    implicit : solves a nonlinear system each step (Newton iterations are counted).
    keeps : invariants kept to round-off for the moment-free body (names of `INVARIANTS`).
    adaptive : chooses its own steps (dt only sets the output grid).
    options : the scheme's options.
    run_bodies_inplace : compiled entry point over a range of batch rows (`rbstudy.numerics.driver`),
        or that of a vectorised step (`rbstudy.numerics.batch_driver`).
    reference : literature reference.
    style : how its lines are drawn (`Style`); None: the figures give it a style no other
        line of the figure wears.
    origin : who provides it: "rbstudy", or a plug-in's package and version (set on loading).
    code_digest : a plug-in's digest of its package's sources, which enters its batch ids
        (None for rbstudy's own schemes: rbstudy's source digest covers them).
    loads_held : takes the loads at each step's start and holds them over the step, as a
        caller hands loads to an engine (docs/engines.md): under a moment it is then of
        order 1 at most, whatever its integrator's order.
    """

    name: str
    summary: str
    step_seconds: float
    order: int
    implicit: bool
    keeps: tuple
    run_bodies_inplace: Callable
    reference: str
    adaptive: bool = False
    options: tuple = field(default=())
    style: Style | None = None
    origin: str = "rbstudy"
    code_digest: str | None = None
    loads_held: bool = False

    def __post_init__(self):
        unknown = set(self.keeps) - set(INVARIANTS)
        if unknown:
            raise ValueError(f"scheme {self.name!r}: unknown invariants {sorted(unknown)}")
        # NaN, infinity or a negative number would reach the forecast ("kernels ~nan s")
        if not (isinstance(self.step_seconds, numbers.Real) and 0 < self.step_seconds < math.inf):
            raise ValueError(
                f"scheme {self.name!r}: step_seconds is {self.step_seconds!r}; "
                "give the core-seconds per body-step `rbstudy bench` measures, "
                "a number above 0"
            )
        _check_option_slots(self.name, self.options)

    def nominal_order(self, values: Mapping | None = None) -> int:
        """The nominal order with options ``values``: that of an option that sets it (a
        composition), else `order`."""
        for option in self.options:
            if option.sets_order and values and option.name in values:
                return int(values[option.name])
        return self.order

    def seconds_per_step(self, values: Mapping | None = None) -> float:
        """`step_seconds` with options ``values``: a composition's step costs its stages."""
        seconds = self.step_seconds
        for option in self.options:
            if option.cost is not None:
                seconds *= option.cost((values or {}).get(option.name, option.default))
        return seconds

    def option_row(self, values: Mapping | None = None) -> np.ndarray:
        """Validate option ``values`` and pack them (defaults filled) into a (N_OPTION,) row."""
        values = dict(values or {})
        known = {option.name: option for option in self.options}
        for name in values:
            if name not in known:
                valid = ", ".join(sorted(known)) or "none"
                raise SchemeError(f"scheme {self.name!r} has no option {name!r}", f"its options: {valid}")
        row = np.zeros(S.N_OPTION)
        for option in self.options:
            value = values.get(option.name, option.default)
            try:
                packed = option.parse(value)
            except (TypeError, ValueError, OverflowError) as exc:
                raise SchemeError(
                    f"scheme {self.name!r} option {option.name!r}: got {value!r}", one_line(exc)
                ) from None
            row[option.slot : option.slot + len(packed)] = packed
        return row

    def is_cached(self, timed: bool = False) -> bool:
        """Whether numba's cache holds the batch kernel's variant with the time (``timed``)
        or without, so that `ensure_compiled` only loads it. False where the entry point cannot
        tell (it has no ``is_cached``: dop853's tells of its compiled right-hand side)."""
        check = getattr(self.run_bodies_inplace, "is_cached", None)
        return bool(check and check(timed))

    def ensure_compiled(self, timed: bool = False) -> None:
        """Compile (or load from numba's cache) the batch kernel with a one-body, one-step run:
        its variant with the time when ``timed`` (a batch with loads tabulated in time), else
        its variant without (`rbstudy.numerics.clock`).

        A Python entry point (dop853) is warmed up the same way, which compiles its
        right-hand side; that costs a millisecond per call.
        """
        kernel = self.run_bodies_inplace
        if any(
            (signature[-1] == types.none) != timed for signature in getattr(kernel, "signatures", None) or ()
        ):
            return
        state0 = np.zeros((1, S.N_STATE))
        state0[0, S.QUATERNION + 3] = 1.0
        params = np.zeros((1, S.N_PARAM))
        params[0, S.MASS] = 1.0
        params[0, S.INERTIA : S.INERTIA + 3] = 1.0
        options = self.option_row()[None, :]
        kernel(
            0,
            1,
            state0,
            params,
            options,
            0.1,
            1,
            1,
            1.0,
            np.empty((1, 2, S.N_STATE)),
            np.empty((1, S.N_RESULT)),
            np.zeros(1, dtype=np.int64),
            0.0 if timed else None,
        )


def _check_option_slots(scheme, options):
    """Refuse, in one line, an option layout a kernel would misread: an option outside the
    row of `N_OPTION` slots, one whose default packs more or fewer floats than its width, or
    two options on one slot (each would read the other's value)."""
    holders = {}
    for option in options:
        if option.slot < 0 or option.slot + option.width > S.N_OPTION:
            raise ValueError(
                f"scheme {scheme!r}: option {option.name!r} takes slots "
                f"{option.slot}-{option.slot + option.width - 1} of a row of "
                f"{S.N_OPTION}; give it a slot from 0 to "
                f"{S.N_OPTION - option.width}"
            )
        packed = len(option.parse(option.default))
        if packed != option.width:
            raise ValueError(
                f"scheme {scheme!r}: option {option.name!r} packs {packed} "
                f"values into a width of {option.width}; declare width={packed}"
            )
        for slot in option.slots:
            if slot in holders:
                raise ValueError(
                    f"scheme {scheme!r}: options {holders[slot]!r} and "
                    f"{option.name!r} both claim slot {slot} of the option row; "
                    "move one to a free slot"
                )
            holders[slot] = option.name
