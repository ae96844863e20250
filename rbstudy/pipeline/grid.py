"""The sweep grid: the ``sweep:`` block of a study -> dimensions -> one `Case` per grid point.

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
count]}`` (the end points themselves, not exponents) or ``{halving: start, count: n}``.

A case is the study's scene and run with one value of every axis written in. The scene axes
(short names that change the body or its spin, ``scene.`` paths) are written in as columns,
one entry per distinct scene, and all scenes are read and checked at once
(`rbstudy.inputs.scenes.scene_table`); the run axes (scheme, dt, ``run.options.``) give the
few distinct runs. A case is a pair of rows, built into a `Case` only when asked for, so
that validating a study costs microseconds per case. A bad value fails with the axis and
value named; every failure goes through the study's `rbstudy.inputs.reader.Reader`.
"""

import collections
import collections.abc
import copy
import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np

from rbstudy.archive.variables import COORDINATES, VARIABLES, coordinate_units
from rbstudy.errors import InputError, did_you_mean
from rbstudy.inputs.scenes import scene_table
from rbstudy.physics.analytic import symmetry_axes
from rbstudy.physics.scenes import Scene, SceneTable
from rbstudy.physics.time_grid import steps_per
from rbstudy.schemes import SCHEMES, get_scheme, scheme_groups

__all__ = [
    "Axis",
    "Dimension",
    "Case",
    "Cases",
    "Run",
    "SHORT_NAMES",
    "RESERVED_NAMES",
    "ALL_SCHEMES",
    "MAX_CASES",
    "MAX_AXIS_VALUES",
    "MAX_HALVINGS",
    "parse_sweep",
    "expand",
    "option_notes",
    "touches_scene",
    "label_options",
    "read_dt",
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

# Applied after dotted paths, in this order (spin and tilt commute: one sets the length of w,
# the other its direction).
_SHORT_ORDER = ("scheme", "dt", "inertia_ratio", "tilt", "spin")

# Swept values must leave one output grid for every case.
_NOT_SWEEPABLE = {"scene.duration": "all cases share one output grid"}


def _list_fix(key):
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
    values: tuple
    coordinate: str
    units: str | None
    long_name: str


@dataclass(frozen=True)
class Dimension:
    """A dimension of the study: one axis (product) or several of equal length (zip)."""

    name: str
    axes: tuple

    @property
    def size(self):
        return len(self.axes[0].values)


# --- the sweep block -> dimensions ---------------------------------------------------------


def _scalar_values(reader, key, values):
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


def _scheme_names(reader, key, spec):
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


def _values(reader, key, spec):
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


def _coordinate(target):
    """The dataset name of an axis: short names as they are, ``run.options.alpha`` -> ``alpha``,
    ``scene.body.mass`` -> ``body_mass``."""
    if target in SHORT_NAMES:
        return target
    parts = target.split(".")
    if parts[:2] == ["run", "options"]:
        return "_".join(parts[2:])
    return "_".join(parts[1:])


def _axis(reader, key, target, spec):
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


def label_options(dimensions, schemes):
    """``dimensions`` with each swept scheme option (``run.options.<name>``) labelled by the
    option itself: its ``long_name`` and ``units`` (`rbstudy.schemes.Option`), from the first
    of the study's ``schemes`` (names) that has it; an option without a long_name keeps its
    path."""
    options = {}
    for name in schemes:
        for option in get_scheme(name).options:
            options.setdefault(option.name, option)

    def labelled(axis):
        option = options.get(axis.target.removeprefix("run.options."))
        if not axis.target.startswith("run.options.") or option is None:
            return axis
        return dataclasses.replace(axis, units=option.units, long_name=option.long_name or axis.long_name)

    return tuple(Dimension(d.name, tuple(map(labelled, d.axes))) for d in dimensions)


def _zipped(reader, name, group):
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


def parse_sweep(reader, spec):
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


# --- the distinct scenes: scene axes as columns of one mapping -----------------------------


def _set_path(spec, dotted, value):
    """Write ``value`` at a dotted path (list entries by index) into nested ``spec``."""
    *parents, leaf = dotted.split(".")
    node = spec
    for depth, part in enumerate(parents):
        if isinstance(node, list):
            node = node[_list_index(dotted, node, part)]
        elif isinstance(node, dict):
            if part not in node:  # a made-up mapping would only fail later, less clearly
                raise InputError(
                    f"{'.'.join(parents[: depth + 1])} is not in the study",
                    "give it there, then sweep its entries",
                    key=dotted,
                )
            node = node[part]
        else:
            raise InputError(
                f"{'.'.join(parents[:depth])} holds {node!r}, not a mapping or list",
                "sweep a path that exists in the study",
                key=dotted,
            )
    if isinstance(node, list):
        node[_list_index(dotted, node, leaf)] = value
    elif isinstance(node, dict):
        node[leaf] = value
    else:
        raise InputError(
            f"{'.'.join(parents)} holds {node!r}, not a mapping or list",
            "sweep a path that exists in the study",
            key=dotted,
        )


def _list_index(dotted, node, part):
    if not part.isdigit() or int(part) >= len(node):
        raise InputError(
            f"{part!r} is not an entry of a list of {len(node)}", f"use 0..{len(node) - 1}", key=dotted
        )
    return int(part)


def _column(values):
    """Axis values as a column: flags when all are true or false, objects when names are
    among them, else floats."""
    if all(isinstance(v, bool) for v in values):
        return np.array(values, dtype=bool)
    if any(isinstance(v, (str, bool)) for v in values):
        return np.array(values, dtype=object)
    return np.array(values, dtype=float)


def _fail_at(bad, message, fix=None, key=None):
    """Raise an `InputError` at the first row where ``bad`` (n,) holds."""
    if bad.any():
        row = int(np.argmax(bad))
        raise InputError(message(row), fix, key=key, row=row)


def _entry(value, row):
    """The value of a leaf (a number, or a column) in scene ``row``, as a Python value."""
    if not isinstance(value, np.ndarray):
        return value
    entry = value[row]
    return entry.item() if isinstance(entry, np.generic) else entry


def _as_floats(value, size):
    """A leaf as (size,) floats, NaN where it is not a number."""
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return value
    entries = value.tolist() if isinstance(value, np.ndarray) else [value] * size
    return np.array([_float_or_nan(entry) for entry in entries])


def _float_or_nan(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    try:
        return float(value)
    except OverflowError:  # an integer beyond any float
        return math.nan


def _vector_rows(values, size, key):
    """A vector of 3 numbers or swept columns as (size, 3) floats; an `InputError` at ``key``
    otherwise, on the first bad row."""
    if not isinstance(values, list) or len(values) != 3:
        raise InputError(f"expected a list of 3 finite numbers, got {values!r:.80}", key=key)
    with np.errstate(over="ignore"):
        rows = np.stack([_as_floats(value, size) for value in values], axis=-1)
    _fail_at(
        ~np.isfinite(rows).all(axis=-1),
        lambda row: (
            f"expected a list of 3 finite numbers, got {[_entry(value, row) for value in values]!r:.80}"
        ),
        key=key,
    )
    return rows


_OMEGA_KEY = "scene.initial.angular_velocity"


def _body_omega(scene, name, size):
    """The initial angular velocity mapping, its frame and its vectors (size, 3)."""
    omega = _inside(scene, "initial", "angular_velocity")
    if not isinstance(omega, dict) or not any(key in omega for key in ("body", "space")):
        raise InputError(
            f"{name} needs the initial angular velocity",
            "give its .body (or .space) components",
            key=_OMEGA_KEY,
        )
    frame = "body" if "body" in omega else "space"
    if name == "tilt" and frame != "body":
        raise InputError(
            "tilt is measured from body axis 3",
            "give the angular velocity in body axes (.body)",
            key=_OMEGA_KEY,
        )
    return omega, frame, _vector_rows(omega[frame], size, f"{_OMEGA_KEY}.{frame}")


def _inside(mapping, *keys):
    """The value at ``keys`` in nested mappings, None where one is missing or not a mapping."""
    for key in keys:
        mapping = mapping.get(key) if isinstance(mapping, dict) else None
    return mapping


def _short_numbers(name, column):
    """A short name's column (n,) as floats: every value a finite number (spin > 0)."""
    if column.dtype.kind in "bO":
        _fail_at(
            np.array([isinstance(v, (str, bool, np.bool_)) for v in column]),
            lambda row: f"{name} takes a number, got {_entry(column, row)!r}",
        )
    numbers = column.astype(float)
    if name == "spin":
        _fail_at(
            numbers <= 0.0,
            lambda row: f"spin must be > 0 rad/s, got {_entry(column, row)!r}",
            "a body at rest has no rotation to study: sweep a positive spin",
        )
    return numbers


def _apply_short(scene, name, column):
    """Write a short name's values (a column of n) into the columnar scene mapping."""
    values = _short_numbers(name, column)
    size = len(values)
    if name == "inertia_ratio":
        if "assembly" in scene:
            raise InputError(
                "inertia_ratio has no meaning for a body assembled from nodes",
                "sweep its nodes' masses or positions, or assembly.scale",
                key="scene.assembly",
            )
        inertia = _inside(scene, "body", "inertia")
        key, fix = "scene.body.inertia", "give inertia: [I1, I1, I3]"
        if not isinstance(inertia, list) or len(inertia) != 3:
            raise InputError(
                f"inertia_ratio needs a body symmetric about axis 3, got {inertia!r:.80}", fix, key=key
            )
        moments = _vector_rows(inertia, size, key)
        _fail_at(
            symmetry_axes(moments) != 2,
            lambda row: f"inertia_ratio needs a body symmetric about axis 3, got {moments[row].tolist()}",
            fix,
            key=key,
        )
        scene["body"]["inertia"] = [inertia[0], inertia[0], values * inertia[0]]
        return
    omega, frame, vector = _body_omega(scene, name, size)
    # scaled: no underflow to 0 for a tiny w, as the norm had
    length = np.hypot(np.hypot(vector[:, 0], vector[:, 1]), vector[:, 2])
    if name == "spin":
        _fail_at(
            length == 0.0,
            lambda row: "spin keeps the direction of the initial w, which is zero",
            "give a non-zero initial angular velocity",
            key=_OMEGA_KEY,
        )
        with np.errstate(over="ignore", invalid="ignore"):  # the scene refuses it, by key
            omega[frame] = list((vector * (values / length)[:, None]).T)
        return
    azimuth = np.arctan2(vector[:, 1], vector[:, 0])
    tilt = np.radians(values)
    omega[frame] = [
        length * np.sin(tilt) * np.cos(azimuth),
        length * np.sin(tilt) * np.sin(azimuth),
        length * np.cos(tilt),
    ]


def touches_scene(axis):
    """Whether ``axis`` changes the scene (the body, its start, its loads), not the run."""
    return axis.target in _SCENE_SHORT_NAMES or axis.target.startswith("scene.")


_SCENE_SHORT_NAMES = ("inertia_ratio", "tilt", "spin")


def _scene_table(reader, base, dimensions):
    """The distinct scenes of the grid, a `SceneTable` in C order of ``dimensions`` (the
    dimensions with a scene axis; one scene when there is none)."""
    shape = tuple(d.size for d in dimensions)
    size = math.prod(shape)
    rows = np.unravel_index(np.arange(size), shape) if shape else ()
    scene = {"scene": copy.deepcopy(base["scene"])}
    chosen = {
        axis.target: _column(axis.values)[rows[k]]
        for k, dimension in enumerate(dimensions)
        for axis in dimension.axes
        if touches_scene(axis)
    }
    for target, column in chosen.items():
        if target not in SHORT_NAMES:
            _set_path(scene, target, column)
    for name in _SHORT_ORDER:
        if name in chosen:
            _apply_short(scene["scene"], name, chosen[name])
    return scene_table(scene["scene"], source=reader.source, size=size)


# --- the distinct runs: scheme, options and dt -----------------------------------------------


@dataclass(frozen=True)
class Run:
    """How a case is integrated: a scheme, the options it has, a time step (s)."""

    scheme: str
    options: dict
    dt: float


def read_dt(reader, value, output_interval=None):
    """The time step ``value`` of ``run.dt`` (as written, or swept) in s: a positive number
    that divides ``output_interval`` (s; None when the step itself is the output interval);
    else a `ConfigError` at ``run.dt``."""
    dt = reader.number(value, "run.dt", positive=True)
    if output_interval is not None:
        try:
            steps_per(output_interval, dt, "dt", "output interval")
        except InputError as error:
            raise reader.locate(error, "run.dt") from None
    return dt


def _run(reader, base, dimensions, index, output_interval):
    """The run at ``index`` of the run ``dimensions``; an `InputError` keyed within it."""
    run = base["run"]
    scheme_name, dt = run.get("scheme"), run.get("dt")
    spec = {"run": {"options": dict(run.get("options") or {})}}
    for dimension, i in zip(dimensions, index, strict=True):
        for axis in dimension.axes:
            if axis.target == "scheme":
                scheme_name = axis.values[i]
            elif axis.target == "dt":
                dt = axis.values[i]
            elif axis.target.startswith("run."):
                _set_path(spec, axis.target, axis.values[i])
    try:
        scheme = get_scheme(scheme_name)
    except InputError as error:
        raise reader.locate(error, "run.scheme") from None
    known = {option.name for option in scheme.options}
    options = {name: value for name, value in spec["run"]["options"].items() if name in known}
    try:
        scheme.option_row(options)
    except InputError as error:
        raise reader.locate(error, "run.options") from None
    return Run(scheme=scheme.name, options=options, dt=read_dt(reader, dt, output_interval))


# --- every case ------------------------------------------------------------------------------


@dataclass(frozen=True)
class Case:
    """One grid point of a study.

    index : position along each dimension. scene : the validated scene. scheme, options, dt :
    its run.
    """

    index: tuple
    scene: Scene
    scheme: str
    options: dict
    dt: float


@dataclass(frozen=True, eq=False)
class Cases(collections.abc.Sequence):
    """Every case of a study, in C order of its dimensions, each built when asked for.

    A case is a distinct scene and a distinct run: ``scenes`` (a `SceneTable`) and ``runs``
    (`Run`s) hold them, ``scene_rows`` and ``run_rows`` (cases,) say which each case has, so
    that a study of 1e5 cases holds no 1e5 Python objects.
    """

    shape: tuple
    scenes: SceneTable
    runs: tuple
    scene_rows: np.ndarray
    run_rows: np.ndarray

    def __len__(self):
        return len(self.scene_rows)

    def __getitem__(self, number):
        if not isinstance(number, (int, np.integer)):
            raise TypeError("cases are numbered: index them with an integer")
        number = range(len(self))[number]  # negative numbers, and IndexError past the end
        run = self.runs[self.run_rows[number]]
        return Case(
            index=tuple(int(i) for i in np.unravel_index(number, self.shape)),
            scene=self.scenes.scene(int(self.scene_rows[number])),
            scheme=run.scheme,
            options=run.options,
            dt=run.dt,
        )

    def __iter__(self):
        return (self[number] for number in range(len(self)))


def _where(dimensions, index):
    """``sweep (dt[2] = 0.0025, scheme[0] = 'euler')``: names a case in an error."""
    return (
        "sweep ("
        + ", ".join(
            f"{axis.coordinate}[{i}] = {axis.values[i]!r}"
            for dim, i in zip(dimensions, index, strict=True)
            for axis in dim.axes
        )
        + ")"
    )


def _rows_of(dimensions, chosen, shape):
    """For each case of the grid ``shape``, its row in the product of the ``chosen``
    dimensions (positions among ``dimensions``)."""
    size = math.prod(shape)
    if not chosen:
        return np.zeros(size, dtype=np.int64)
    index = np.unravel_index(np.arange(size), shape)
    return np.ravel_multi_index([index[k] for k in chosen], [shape[k] for k in chosen])


def _given_options(base, dimensions):
    """Each scheme option the study gives -> the key it is given under: ``run.options.alpha``,
    or the sweep's ``sweep.run.options.alpha`` (``sweep.zip.<dimension>.run.options.alpha``)."""
    given = {name: f"run.options.{name}" for name in base["run"].get("options") or {}}
    for d in dimensions:
        for axis in d.axes:
            if axis.target.startswith("run.options."):
                zipped = len(d.axes) > 1 or d.name != axis.coordinate
                given[axis.target.removeprefix("run.options.")] = (
                    f"sweep.zip.{d.name}.{axis.target}" if zipped else f"sweep.{axis.target}"
                )
    return given


def _takers(option, schemes):
    """The names of the `Scheme`s of ``schemes`` that take the option named ``option``."""
    return [scheme.name for scheme in schemes if any(o.name == option for o in scheme.options)]


def option_notes(base, dimensions, runs):
    """A line for each scheme option the study gives that only some of its schemes take
    (``runs``: its `Run`s): the others run without it, and a study of several schemes
    (an engine beside hht) needs no option written for each."""
    schemes = [get_scheme(name) for name in sorted({run.scheme for run in runs})]
    notes = []
    for name in _given_options(base, dimensions):
        takers = _takers(name, schemes)
        if takers and len(takers) < len(schemes):
            notes.append(
                f"run.options.{name} applies to {', '.join(takers)} only; the other schemes run without it"
            )
    return tuple(notes)


def expand(reader, base, dimensions, output_interval):
    """Every case of the grid as `Cases`, every distinct scene and run built and checked.

    ``base`` is the study mapping (``scene``, ``run``); a bad scene or run fails through
    ``reader``, naming the swept values of its dimensions (``sweep (dt[1] = 0.003)``) and the
    key within the case. An option that no scheme of the study has is an error.
    """
    shape = tuple(d.size for d in dimensions)
    of_scenes = [k for k, d in enumerate(dimensions) if any(map(touches_scene, d.axes))]
    of_runs = [k for k, d in enumerate(dimensions) if not all(map(touches_scene, d.axes))]
    scene_dimensions = [dimensions[k] for k in of_scenes]
    try:
        scenes = _scene_table(reader, base, scene_dimensions)
    except InputError as error:
        where = None
        if scene_dimensions and error.row is None:  # not one scene's value: every scene's
            where = "sweep"
        elif scene_dimensions:
            at = np.unravel_index(error.row, [d.size for d in scene_dimensions])
            where = _where(scene_dimensions, tuple(int(i) for i in at))
        raise reader.locate(error, where) from None
    run_dimensions = [dimensions[k] for k in of_runs]
    runs = []
    for index in itertools.product(*(range(d.size) for d in run_dimensions)):
        try:
            runs.append(_run(reader, base, run_dimensions, index, output_interval))
        except InputError as error:
            raise reader.locate(error, _where(run_dimensions, index) if index else None) from None
    given = _given_options(base, dimensions)
    unknown = sorted(set(given) - {name for run in runs for name in run.options})
    if unknown:
        schemes = sorted({run.scheme for run in runs})
        options = {option.name for name in schemes for option in get_scheme(name).options}
        key, takers = given[unknown[0]], _takers(unknown[0], SCHEMES.values())
        # run.options as written can go from the command line too
        remove = "remove it" + (" (or --set 'run.options={}')" if key.startswith("run.") else "")
        reader.fail(
            key,
            f"{', '.join(unknown)} is an option of none of the study's "
            f"schemes ({', '.join(schemes)})"
            f"{did_you_mean(unknown[0], options)}",
            f"{remove}, or sweep a scheme that takes it ({', '.join(takers)})"
            if takers
            else f"{remove}; `rbstudy schemes` lists each scheme's options",
        )
    return Cases(
        shape=shape,
        scenes=scenes,
        runs=tuple(runs),
        scene_rows=_rows_of(dimensions, of_scenes, shape),
        run_rows=_rows_of(dimensions, of_runs, shape),
    )
