"""What a scheme is, as the rest of rbstudy sees it: capabilities, options, compiled entry, and
how its lines are drawn."""

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
from numba import types

from rbstudy.errors import SchemeError, one_line
from rbstudy.numerics import state as S
from rbstudy.numerics.block import N_TEMP, TEMP

__all__ = [
    "Option",
    "Scheme",
    "Style",
    "GROUPS",
    "INVARIANTS",
    "KINDS",
    "flag_parser",
    "option_slots",
    "scratch_rows",
]

INVARIANTS = S.INVARIANTS
# What a scheme's step solves, as `rbstudy schemes` lists it: kind -> what it means.
KINDS = {
    "explicit": "every stage from values already known",
    "semi-implicit": "the velocities from the forces at the step's start, then the positions "
    "and the frame with the new velocities (symplectic Euler)",
    "linearly implicit": "one linear solve a step: the forces linearised in the new velocity "
    "(no Newton iterations)",
    "implicit": "a nonlinear system solved each step by Newton iterations",
    "adaptive": "chooses its own steps",
}
# The group a scheme of rbstudy's own belongs to, as `scheme: <group>` names it: ``builtin``
# (which ``all`` stands for) or ``published``.
GROUPS = {
    "builtin": "rbstudy's own fixed-step schemes (what `scheme: all` sweeps)",
    "published": "rotation steps that game engines and papers publish, each written from its "
    "source (docs/theory.md s5)",
}


@dataclass(frozen=True)
class Option:
    """A scheme option: its default, what it means, and how it is packed for the kernel.

    ``parse(value) -> tuple of floats`` validates a user value and returns the ``width`` floats
    stored in the body's option row; it raises ``ValueError`` with the expectation. Where they
    are stored is the registry's choice, not the option's: `option_slots` lays out a scheme's
    row from its options, and the scheme's kernels read the slots it gives as constants.
    ``slot`` pins an option to a slot instead (a plug-in written before the registry
    allocated them); the registry checks it like its own layout.
    ``sets_order``: the option's value is the scheme's nominal order (a composition).
    ``cost(value)``: how many plain steps' time one step takes with that value (the stages
    of a composition, the extra sums of a compensated step); None for an option that does not
    change the cost. ``long_name`` (at most
    60 characters: a plot's axis label) and ``units`` (CF, "1" for a number without; None for
    a label such as an axis order) label the option's coordinate in an archive that sweeps
    it; without a long_name the coordinate is labelled with the option's name.
    """

    name: str
    default: Any
    description: str
    slot: int | None = None
    parse: Callable[[Any], tuple] | None = None
    sets_order: bool = False
    cost: Callable[[Any], float] | None = None
    long_name: str = ""
    units: str | None = None
    width: int = 1

    def __post_init__(self) -> None:
        if self.parse is None:
            raise TypeError(f"option {self.name!r}: give parse(value) -> tuple of floats")


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
        development machine (one core, 1e4 bodies, one body after another; dop853: per
        accepted step); the run-time forecast of `rbstudy validate` starts from it. A number
        above 0 and finite.
    implicit : solves a nonlinear system each step (Newton iterations are counted).
    kind : what its step solves, one of `KINDS`; None: "adaptive", "implicit" or "explicit"
        from ``adaptive`` and ``implicit``. An engine's semi-implicit or linearly implicit
        step says so here (set on registering where None).
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
    block_step_seconds : core-seconds a body-step takes where the scheme steps blocks of
        bodies across SIMD lanes (`rbstudy.numerics.block`: batches of 16 bodies or more),
        measured as `step_seconds` is; None: it has no block step. The forecast takes it
        for such batches (`block_seconds_per_step`).
    group : the group of `GROUPS` a scheme of rbstudy's own belongs to (``builtin``: what
        ``scheme: all`` sweeps; ``published``: a step written from an engine's or a paper's
        publication). An engine's or a plug-in's scheme keeps the default; its group is its
        engine's or none.
    slots : where its kernels read each option: name -> first slot of the (N_OPTION,) row,
        as `option_slots` lays it out from ``options`` (set on registering).
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
    block_step_seconds: float | None = None
    kind: str | None = None
    group: str = "builtin"
    slots: Mapping = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        unknown = set(self.keeps) - set(INVARIANTS)
        if unknown:
            raise ValueError(f"scheme {self.name!r}: unknown invariants {sorted(unknown)}")
        # NaN, infinity or a negative number would reach the forecast ("kernels ~nan s")
        given = {"step_seconds": self.step_seconds}
        if self.block_step_seconds is not None:  # optional: a scheme without a block step
            given["block_step_seconds"] = self.block_step_seconds
        for name, seconds in given.items():
            if not (isinstance(seconds, numbers.Real) and 0 < seconds < math.inf):
                raise ValueError(
                    f"scheme {self.name!r}: {name} is {seconds!r}; "
                    "give the core-seconds per body-step `rbstudy bench` measures, "
                    "a number above 0"
                )
        if self.kind is None:  # frozen: set once, here
            derived = "adaptive" if self.adaptive else "implicit" if self.implicit else "explicit"
            object.__setattr__(self, "kind", derived)
        if self.kind not in KINDS:
            raise ValueError(f"scheme {self.name!r}: kind {self.kind!r}; give one of {', '.join(KINDS)}")
        if self.group not in GROUPS:
            raise ValueError(f"scheme {self.name!r}: group {self.group!r}; give one of {', '.join(GROUPS)}")
        # frozen: set once, here, from the options (the same layout the scheme's file computes)
        object.__setattr__(self, "slots", option_slots(self.options, self.name))

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

    def block_seconds_per_step(self, values: Mapping | None = None) -> float | None:
        """`seconds_per_step` in blocks across SIMD lanes (`block_step_seconds`); None where
        the scheme has no block step, or options ``values`` send its rows to kernels of
        their own (``compensated``), which step one body at a time."""
        steps_blocks = getattr(self.run_bodies_inplace, "steps_blocks", None)
        if (
            self.block_step_seconds is None
            or steps_blocks is None
            or not steps_blocks(self.option_row(values))
        ):
            return None
        return self.seconds_per_step(values) * self.block_step_seconds / self.step_seconds

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
            start = self.slots[option.name]
            row[start : start + len(packed)] = packed
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


def flag_parser(meaning: str) -> Callable[[Any], tuple]:
    """The ``parse`` of an `Option` that is 0 or 1 (``false`` or ``true``), ``meaning`` what
    1 asks for (the error's words)."""

    def parse(value):
        if value not in (0, 1):  # True and False compare equal to 1 and 0
            raise ValueError(f"expected 0 or 1 (false or true): whether to {meaning}")
        return (float(value),)

    return parse


def option_slots(options: Sequence[Option], scheme: str = "this scheme") -> Mapping[str, int]:
    """Lay out a scheme's option row: the first slot of each of its ``options``.

    An option that pins its ``slot`` keeps it; the others, in the order given, take the first
    run of ``width`` free slots. The layout depends on nothing but the options and their
    order, so a scheme file computes it once (``SLOTS = option_slots(OPTIONS)``) and its
    kernels read the slots as compile-time constants, and numba's cache, keyed on the sources,
    never holds a kernel that reads another layout. An option shared by several schemes
    (``composition``, ``compensated``) may sit at another slot in each; its compiled readers
    take the slot from the scheme (`rbstudy.schemes._composition.composed_entry`).

    Parameters
    ----------
    options : sequence of Option
        The scheme's options, in the order it declares them.
    scheme : str
        The scheme's name, for the errors.

    Returns
    -------
    mapping of str to int
        Option name -> its first slot of the (N_OPTION,) row; it fills ``width`` slots.

    Raises
    ------
    ValueError
        In one line: a row of `N_OPTION` slots too short for the options, a pinned slot
        outside it or claimed twice (each option would read the other's value), or a default
        that packs more or fewer floats than the option's width.
    """
    holders: list[str | None] = [None] * S.N_OPTION
    slots: dict[str, int] = {}

    def claim(option, start):
        for k in range(start, start + option.width):
            if holders[k] is not None:
                raise ValueError(
                    f"scheme {scheme!r}: options {holders[k]!r} and {option.name!r} both claim "
                    f"slot {k} of the option row; leave out the slot and the registry lays out the row"
                )
            holders[k] = option.name
        slots[option.name] = start

    for option in options:
        assert option.parse is not None  # Option.__post_init__ refuses an option without one
        packed = len(option.parse(option.default))
        if packed != option.width:
            raise ValueError(
                f"scheme {scheme!r}: option {option.name!r} packs {packed} "
                f"values into a width of {option.width}; declare width={packed}"
            )
    for option in options:
        pinned = option.slot
        if pinned is None:
            continue
        if not 0 <= pinned <= S.N_OPTION - option.width:
            raise ValueError(
                f"scheme {scheme!r}: option {option.name!r} takes slots "
                f"{pinned}-{pinned + option.width - 1} of a row of {S.N_OPTION}; "
                "leave out the slot and the registry lays out the row"
            )
        claim(option, pinned)
    for option in (option for option in options if option.slot is None):
        free = (
            start
            for start in range(S.N_OPTION - option.width + 1)
            if all(holder is None for holder in holders[start : start + option.width])
        )
        start = next(free, None)
        if start is None:
            raise ValueError(
                f"scheme {scheme!r}: no {option.width} free slots left for option "
                f"{option.name!r} in a row of {S.N_OPTION}; the options fill "
                f"{sum(o.width for o in options)} slots"
            )
        claim(option, start)
    return MappingProxyType(slots)


def scratch_rows(scheme: str, **widths: int) -> tuple[int, ...]:
    """Lay out a block step's scratch rows (`rbstudy.numerics.block`: ``N_TEMP`` rows from
    ``TEMP``): each of ``widths`` (name=rows, in the order given) takes the next free rows.
    As `option_slots` does for the option row, the layout depends on the widths alone, so a
    scheme file unpacks it once into module constants, which its block step reads as
    compile-time constants. A step that reuses rows for another purpose later in the step
    lays that purpose out in a second call.

    Parameters
    ----------
    scheme : str
        The scheme's name, for the error.
    **widths : int
        Rows of each field, each at least 1.

    Returns
    -------
    tuple of int
        The first row of each field, in the order given.

    Raises
    ------
    ValueError
        In one line: a width below 1, or fields that need more than the ``N_TEMP`` rows of a
        block (a field would overwrite the carried rows that follow them).
    """
    starts: list[int] = []
    at = TEMP
    for name, width in widths.items():
        if not isinstance(width, numbers.Integral) or width < 1:
            raise ValueError(
                f"scheme {scheme!r}: block scratch {name!r} takes {width!r} rows; give 1 or more"
            )
        starts.append(at)
        at += width
    if at - TEMP > N_TEMP:
        raise ValueError(
            f"scheme {scheme!r}: block scratch {', '.join(f'{n} ({w})' for n, w in widths.items())} "
            f"takes {at - TEMP} rows of the {N_TEMP} a block has; reuse rows in a second layout, "
            "or raise rbstudy.numerics.block.N_TEMP"
        )
    return tuple(starts)
