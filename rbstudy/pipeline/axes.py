"""The ``sweep:`` block of a study -> its dimensions, each of one or more swept `Axis`.

A sweep maps axis names to values. Each axis is its own dimension (a product), except the
axes grouped under ``zip:``, which share one named dimension::

    sweep:
      scheme: all                         # every fixed-step scheme
      dt: {halving: 0.01, count: 6}       # 0.01, 0.005, ..., 0.0003125 (stored ascending)
      inertia_ratio: [0.1, 0.5, 1.5, 2.0]
      zip:
        spin_tilt:                        # dimension name
          spin: [1.0, 2.0, 4.0]
          tilt: [5.0, 10.0, 20.0]

An axis is a short name (`SHORT_NAMES`) or a dotted path into the study: ``scene.body.mass``,
``scene.initial.angular_velocity.body.2`` (list entries by index), ``run.options.alpha``.
Values: a non-empty list, ``{linspace: [start, stop, count]}``, ``{logspace: [start, stop,
count]}`` (the end points themselves, not exponents) or ``{halving: start, count: n}``. A bad
value fails with the axis and value named, through the study's
`rbstudy.inputs.reader.Reader`. The grid of cases the dimensions span is
`rbstudy.pipeline.grid`'s.
"""

from __future__ import annotations

import collections
import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.archive.variables import COORDINATES, VARIABLES, coordinate_units
from rbstudy.errors import InputError, did_you_mean
from rbstudy.inputs.reader import Reader
from rbstudy.schemes import Option, get_scheme, scheme_groups

__all__ = [
    "Axis",
    "Dimension",
    "SHORT_NAMES",
    "RESERVED_NAMES",
    "ALL_SCHEMES",
    "MAX_CASES",
    "MAX_AXIS_VALUES",
    "MAX_HALVINGS",
    "parse_sweep",
    "touches_scene",
    "label_options",
]

# `scheme: all` sweeps the fixed-step schemes; dop853 is the reference, its dt is meaningless.
ALL_SCHEMES = "all"

SHORT_NAMES = {
    "scheme": "the integration scheme (run.scheme)",
    "dt": "the time step in s (run.dt)",
    "inertia_ratio": "I3 / I1 of a body symmetric about axis 3: inertia becomes [I1, I1, r I1]",
    "spin": "the initial |w| in rad/s, direction kept",
    "tilt": "the angle in degrees between the initial w and body axis 3, |w| and azimuth kept",
}

# Swept values must leave one output grid for every case.
_NOT_SWEEPABLE = {"scene.duration": "all cases share one output grid"}


def _list_fix(key: str) -> str:
    """How to sweep what is a list rather than one value: a load's table by its file, a
    vector entry by entry."""
    if ".loads." in key and key.endswith(".table"):
        return "sweep load tables by file name (write each table to a file)"
    return "sweep a vector one entry at a time (path.0, path.1...)"


# Names the dataset already uses: a zipped dimension may not take them.
RESERVED_NAMES = frozenset(("time", "node", "axis", "component", "case", "scheme", "dt")) | frozenset(
    VARIABLES
)
# A study has at most this many cases, and an axis at most this many values, checked before
# any list is built, so that a count of 1e12 is an error, not an allocation.
MAX_CASES = 1_000_000
MAX_AXIS_VALUES = MAX_CASES
# Halvings of a step: 60 divide it by 1e18, beyond any study (and a float by 2^1074 is 0).
MAX_HALVINGS = 60
# Batches group cases by scheme and dt, and the convergence fit runs along dt: both must be
# dimensions of their own.
_NOT_ZIPPABLE = ("scheme", "dt")


@dataclass(frozen=True)
class Axis:
    """One swept quantity: ``target`` (short name or dotted path), its values, its name in the
    dataset (``coordinate``), the units of its values and its ``long_name`` there."""

    target: str
    values: tuple[Any, ...]
    coordinate: str
    units: str | None
    long_name: str


@dataclass(frozen=True)
class Dimension:
    """A dimension of the study: one axis (product) or several of equal length (zip)."""

    name: str
    axes: tuple[Axis, ...]

    @property
    def size(self) -> int:
        return len(self.axes[0].values)


def _scalar_values(reader: Reader, key: str, values: Sequence[Any]) -> tuple[Any, ...]:
    """``values`` if each is a number, a name or a flag and none repeats."""
    for i, value in enumerate(values):
        if not isinstance(value, (int, float, str)):  # a bool is an int
            reader.fail(
                f"{key}[{i}]",
                f"sweep values must be numbers, names or true/false, got {value!r:.80}",
                _list_fix(key),
            )
        if not isinstance(value, (str, bool)):
            reader.number(value, f"{key}[{i}]")  # finite
    # a flag is kept apart from the number it equals (true == 1)
    counts = collections.Counter(
        (type(v) is bool, v if isinstance(v, (str, bool)) else float(v)) for v in values
    )
    repeated = sorted(str(v) for (_, v), n in counts.items() if n > 1)
    if repeated:
        reader.fail(key, f"{', '.join(repeated)} given twice", "each value once")
    return tuple(values)


def _scheme_names(reader: Reader, key: str, spec: list[Any]) -> list[Any]:
    """A list of scheme names with each group (`rbstudy.schemes.scheme_groups`; ``all`` is
    ``builtin``) replaced by every scheme it stands for, installed here or not, each name once:
    a config means the same study wherever it runs, and a scheme not installed is refused
    with its fix as if named. Each name is checked here, under the key the config gives it
    (``sweep.scheme[2]``), not under the ``run.scheme`` of the case it makes."""
    groups = scheme_groups()
    groups[ALL_SCHEMES] = groups["builtin"]
    grouped = [isinstance(name, str) and name in groups for name in spec]
    for position, (name, group) in enumerate(zip(spec, grouped, strict=True)):
        if not group:
            try:
                get_scheme(name)
            except InputError as error:
                raise reader.locate(error, f"{key}[{position}]") from None
    if not any(grouped):
        return spec  # names only: a name given twice is refused as in any sweep
    names = [
        member
        for name, group in zip(spec, grouped, strict=True)
        for member in (groups[name] if group else [name])
    ]
    return list(dict.fromkeys(names))


def _values(reader: Reader, key: str, spec: Any) -> tuple[Any, ...]:
    """The tuple of values of one axis from its YAML spec."""
    # a group alone (``all``, ``engines``, ``mujoco``) stands for its schemes as a list would
    group = isinstance(spec, str) and (spec == ALL_SCHEMES or spec in scheme_groups())
    if key.endswith("scheme") and (group or isinstance(spec, list)):
        spec = _scheme_names(reader, key, [spec] if group else spec)
    if isinstance(spec, list):
        if not spec:
            reader.fail(key, "empty sweep", "give at least one value")
        return _scalar_values(reader, key, spec)
    if isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in ("linspace", "logspace"):
        form, triple = next(iter(spec.items()))
        if not isinstance(triple, list) or len(triple) != 3:
            reader.fail(f"{key}.{form}", f"expected [start, stop, count], got {triple!r}")
        start = reader.number(triple[0], f"{key}.{form}[0]")
        stop = reader.number(triple[1], f"{key}.{form}[1]")
        count = reader.count(triple[2], f"{key}.{form}[2]", MAX_AXIS_VALUES)
        if form == "linspace":
            return tuple(float(v) for v in np.linspace(start, stop, count))
        if start <= 0 or stop <= 0:
            reader.fail(f"{key}.logspace", f"end points must be > 0, got {triple!r}")
        return tuple(float(v) for v in np.geomspace(start, stop, count))
    if isinstance(spec, dict) and set(spec) == {"halving", "count"}:
        start = reader.number(spec["halving"], f"{key}.halving")
        count = reader.count(spec["count"], f"{key}.count", MAX_HALVINGS)
        return tuple(start * 0.5**i for i in range(count))
    forms = ("linspace", "logspace", "halving", "count")
    slip = (
        "".join(did_you_mean(name, forms) for name in spec if name not in forms)
        if isinstance(spec, dict)
        else ""
    )  # {halving: 0.01, cout: 3}: 'count' was meant
    reader.fail(
        key,
        f"expected a list of values, {{linspace: [start, stop, count]}}, "
        f"{{logspace: [start, stop, count]}} or {{halving: start, count: n}}, "
        f"got {spec!r}{slip}",
    )


def _coordinate(target: str) -> str:
    """The dataset name of an axis: short names as they are, ``run.options.alpha`` -> ``alpha``,
    ``scene.body.mass`` -> ``body_mass``."""
    if target in SHORT_NAMES:
        return target
    parts = target.split(".")
    if parts[:2] == ["run", "options"]:
        return "_".join(parts[2:])
    return "_".join(parts[1:])


def _axis(reader: Reader, key: str, target: str, spec: Any) -> Axis:
    if target in ("run.scheme", "run.dt"):
        target = target[4:]
    if target not in SHORT_NAMES:
        head = target.split(".")[0]
        if (
            head not in ("scene", "run")
            or target.count(".") < 1
            or (head == "run" and not target.startswith("run.options."))
        ):
            reader.fail(
                key,
                f"unknown sweep axis {target!r}",
                f"use a short name ({', '.join(SHORT_NAMES)}) or a dotted path such as "
                "scene.body.mass or run.options.alpha",
            )
        if target in _NOT_SWEEPABLE:
            reader.fail(key, f"{target} cannot be swept: {_NOT_SWEEPABLE[target]}")
    values = _values(reader, key, spec)
    if target == "dt" and all(
        isinstance(v, (int, float)) and not isinstance(v, bool) for v in values
    ):  # else refused, by its key, with its run
        # ascending, whatever order the config gives: xarray's ds.sel(dt=slice(0.001, 0.01))
        # finds nothing along a descending index
        values = tuple(sorted(values))
    return Axis(
        target=target,
        values=values,
        coordinate=_coordinate(target),
        units=coordinate_units(target),
        long_name=COORDINATES[target][1] if target in COORDINATES else target,
    )


def label_options(dimensions: Iterable[Dimension], schemes: Iterable[str]) -> tuple[Dimension, ...]:
    """``dimensions`` with each swept scheme option (``run.options.<name>``) labelled by the
    option itself: its ``long_name`` and ``units`` (`rbstudy.schemes.Option`), from the first
    of the study's ``schemes`` (names) that has it; an option without a long_name keeps its
    path."""
    options: dict[str, Option] = {}
    for name in schemes:
        for option in get_scheme(name).options:
            options.setdefault(option.name, option)

    def labelled(axis: Axis) -> Axis:
        option = options.get(axis.target.removeprefix("run.options."))
        if not axis.target.startswith("run.options.") or option is None:
            return axis
        return dataclasses.replace(axis, units=option.units, long_name=option.long_name or axis.long_name)

    return tuple(Dimension(d.name, tuple(map(labelled, d.axes))) for d in dimensions)


def _zipped(reader: Reader, name: Any, group: Any) -> Dimension:
    """The dimension ``name`` of the zipped axes ``group``."""
    key = f"sweep.zip.{name}"
    if not isinstance(name, str) or not name.isidentifier():
        reader.fail(key, "a dimension name needs letters, digits and '_' only")
    if name in RESERVED_NAMES:
        reader.fail(key, f"{name!r} is a name the dataset already uses", "choose another")
    if not isinstance(group, dict) or not group:
        reader.fail(key, f"expected a mapping of axis -> values, got {group!r}")
    axes = tuple(_axis(reader, f"{key}.{target}", target, values) for target, values in group.items())
    for axis in axes:
        if axis.target in _NOT_ZIPPABLE:
            reader.fail(
                f"{key}.{axis.target}", f"{axis.target} cannot be zipped", "sweep it as an axis of its own"
            )
    sizes = {axis.target: len(axis.values) for axis in axes}
    if len(set(sizes.values())) != 1:
        reader.fail(key, f"zipped axes need equal lengths, got {sizes}")
    return Dimension(name, axes)


def parse_sweep(reader: Reader, spec: Any) -> tuple[Dimension, ...]:
    """The dimensions of a ``sweep:`` mapping (empty for a one-case study)."""
    if spec is None:
        return ()
    if not isinstance(spec, dict) or not spec:
        reader.fail("sweep", f"expected a mapping of axis -> values, got {spec!r}")
    dimensions = []
    for name, value in spec.items():
        if name != "zip":
            axis = _axis(reader, f"sweep.{name}", name, value)
            dimensions.append(Dimension(axis.coordinate, (axis,)))
            continue
        if not isinstance(value, dict) or not value:
            reader.fail("sweep.zip", "expected a mapping of dimension name -> {axis: values}")
        dimensions += [_zipped(reader, dim, group) for dim, group in value.items()]
    names = [d.name for d in dimensions] + [
        a.coordinate for d in dimensions for a in d.axes if a.coordinate != d.name
    ]
    targets = [a.target for d in dimensions for a in d.axes]
    for seen in (names, targets):
        repeated = sorted({n for n in seen if seen.count(n) > 1})
        if repeated:
            reader.fail("sweep", f"{', '.join(repeated)} swept twice", "sweep each quantity once")
    return tuple(dimensions)


def touches_scene(axis: Axis) -> bool:
    """Whether ``axis`` changes the scene (the body, its start, its loads), not the run."""
    return axis.target in _SCENE_SHORT_NAMES or axis.target.startswith("scene.")


_SCENE_SHORT_NAMES = ("inertia_ratio", "tilt", "spin")
