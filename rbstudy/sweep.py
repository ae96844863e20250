"""Sweeps: the ``sweep:`` block of a study -> dimensions -> one `Case` per grid point.

A sweep maps axis names to values. Each axis is its own dimension (a product), except the
axes grouped under ``zip:``, which share one named dimension::

    sweep:
      scheme: all                         # every fixed-step scheme
      dt: {halving: 0.01, count: 6}       # 0.01, 0.005, ..., 0.0003125
      inertia_ratio: [0.1, 0.5, 1.5, 2.0]
      zip:
        spin_tilt:                        # dimension name
          spin: [1.0, 2.0, 4.0]
          tilt: [5.0, 10.0, 20.0]

An axis is a short name (`SHORT_NAMES`) or a dotted path into the study: ``scene.body.mass``,
``scene.initial.angular_velocity.body.2`` (list entries by index), ``run.options.alpha``.
Values: a non-empty list, ``{linspace: [start, stop, count]}``, ``{logspace: [start, stop,
count]}`` (the end points themselves, not exponents) or ``{halving: start, count: n}``.

A case is the study's scene and run with one value of every axis written in; its scene is
built and validated like any scene, so a bad value fails with the axis and value named.
"""

import collections
import copy
import hashlib
import itertools
import json
import math
from dataclasses import dataclass

import numpy as np

from rbstudy._jit import SOURCE_DIGEST
from rbstudy.errors import ConfigError, RbstudyError
from rbstudy.scenes import Scene, scene_from_mapping
from rbstudy.schemes import SCHEMES, get_scheme
from rbstudy.simulate import steps_per
from rbstudy.variables import VARIABLES, coordinate_units

__all__ = ["Axis", "Dimension", "Case", "Batch", "SHORT_NAMES", "RESERVED_NAMES", "parse_sweep",
           "expand", "plan_batches", "canonical_id", "scene_key", "fail", "ALL_SCHEMES",
           "SCHEMA_VERSION", "ID_LENGTH"]

# Bumped whenever what a part file holds changes, so that old parts are never reused.
SCHEMA_VERSION = 2
# Hex digits of a batch id's hash: 64 bits, no collision among any realistic set of batches.
ID_LENGTH = 16

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
# Names the dataset already uses: a zipped dimension may not take them.
RESERVED_NAMES = frozenset(("time", "node", "axis", "component", "case", "scheme", "dt")) | \
    frozenset(VARIABLES)
# Batches group cases by scheme and dt, and the convergence fit runs along dt: both must be
# dimensions of their own.
_NOT_ZIPPABLE = ("scheme", "dt")


@dataclass(frozen=True)
class Axis:
    """One swept quantity: ``target`` (short name or dotted path), its values, its name in the
    dataset (``coordinate``) and the units of its values."""

    target: str
    values: tuple
    coordinate: str
    units: str | None


@dataclass(frozen=True)
class Dimension:
    """A dimension of the study: one axis (product) or several of equal length (zip)."""

    name: str
    axes: tuple

    @property
    def size(self):
        return len(self.axes[0].values)


@dataclass(frozen=True)
class Case:
    """One grid point of a study.

    index : position along each dimension. scene : the validated scene. spec : the case's
    study mapping (``scene``, ``run``) with every swept value written in: its identity.
    """

    index: tuple
    scene: Scene
    spec: dict
    scheme: str
    options: dict
    dt: float


def fail(path, key, message):
    """Raise the one-line `ConfigError` ``<file>: <key path>: <message>``."""
    raise ConfigError(f"{path}: {key}: {message}")



def _number(path, key, value):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        fail(path, key, f"expected a finite number, got {value!r}")
    return float(value)


def _count(path, key, value):
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        fail(path, key, f"expected a whole number >= 1, got {value!r}")
    return value


def _scalar_values(path, key, values):
    """``values`` if each is a number or a string and none repeats, else a `ConfigError`."""
    for i, value in enumerate(values):
        if isinstance(value, bool) or not isinstance(value, (int, float, str)):
            fail(path, f"{key}[{i}]", f"sweep values must be numbers or names, got {value!r}; "
                                       "sweep a vector one entry at a time (path.0, path.1...)")
    counts = collections.Counter(float(v) if not isinstance(v, str) else v for v in values)
    repeated = sorted(str(v) for v, n in counts.items() if n > 1)
    if repeated:
        fail(path, key, f"{', '.join(repeated)} given twice; each value once")
    return tuple(values)


def _values(path, key, spec):
    """The tuple of values of one axis from its YAML spec."""
    if isinstance(spec, list):
        if not spec:
            fail(path, key, "empty sweep: give at least one value")
        return _scalar_values(path, key, spec)
    if isinstance(spec, dict) and len(spec) == 1 and next(iter(spec)) in ("linspace", "logspace"):
        form, triple = next(iter(spec.items()))
        if not isinstance(triple, list) or len(triple) != 3:
            fail(path, f"{key}.{form}", f"expected [start, stop, count], got {triple!r}")
        start = _number(path, f"{key}.{form}[0]", triple[0])
        stop = _number(path, f"{key}.{form}[1]", triple[1])
        count = _count(path, f"{key}.{form}[2]", triple[2])
        if form == "linspace":
            return tuple(float(v) for v in np.linspace(start, stop, count))
        if start <= 0 or stop <= 0:
            fail(path, f"{key}.logspace", f"end points must be > 0, got {triple!r}")
        return tuple(float(v) for v in np.geomspace(start, stop, count))
    if isinstance(spec, dict) and set(spec) == {"halving", "count"}:
        start = _number(path, f"{key}.halving", spec["halving"])
        count = _count(path, f"{key}.count", spec["count"])
        return tuple(start / 2 ** i for i in range(count))
    if spec == ALL_SCHEMES and key.endswith("scheme"):
        return tuple(name for name, scheme in SCHEMES.items() if not scheme.adaptive)
    fail(path, key, f"expected a list of values, {{linspace: [start, stop, count]}}, "
                     f"{{logspace: [start, stop, count]}} or {{halving: start, count: n}}, "
                     f"got {spec!r}")


def _coordinate(target):
    """The dataset name of an axis: short names as they are, ``run.options.alpha`` -> ``alpha``,
    ``scene.body.mass`` -> ``body_mass``."""
    if target in SHORT_NAMES:
        return target
    parts = target.split(".")
    if parts[:2] == ["run", "options"]:
        return "_".join(parts[2:])
    return "_".join(parts[1:])


def _axis(path, key, target, spec):
    if target in ("run.scheme", "run.dt"):
        target = target[4:]
    if target not in SHORT_NAMES:
        head = target.split(".")[0]
        if head not in ("scene", "run") or target.count(".") < 1 or (
                head == "run" and not target.startswith("run.options.")):
            fail(path, key, f"unknown sweep axis {target!r}; use a short name "
                             f"({', '.join(SHORT_NAMES)}) or a dotted path such as "
                             "scene.body.mass or run.options.alpha")
        if target in _NOT_SWEEPABLE:
            fail(path, key, f"{target} cannot be swept: {_NOT_SWEEPABLE[target]}")
    values = _values(path, key, spec)
    return Axis(target=target, values=values, coordinate=_coordinate(target),
                units=coordinate_units(target))


def parse_sweep(path, spec):
    """The dimensions of a ``sweep:`` mapping (empty for a one-case study)."""
    if spec is None:
        return ()
    if not isinstance(spec, dict) or not spec:
        fail(path, "sweep", f"expected a mapping of axis -> values, got {spec!r}")
    dimensions = []
    for name, value in spec.items():
        if name != "zip":
            axis = _axis(path, f"sweep.{name}", name, value)
            dimensions.append(Dimension(axis.coordinate, (axis,)))
            continue
        if not isinstance(value, dict) or not value:
            fail(path, "sweep.zip", "expected a mapping of dimension name -> {axis: values}")
        for dim, group in value.items():
            key = f"sweep.zip.{dim}"
            if not isinstance(dim, str) or not dim.isidentifier():
                fail(path, key, "a dimension name needs letters, digits and '_' only")
            if dim in RESERVED_NAMES:
                fail(path, key, f"{dim!r} is a name the dataset already uses; choose another")
            if not isinstance(group, dict) or not group:
                fail(path, key, f"expected a mapping of axis -> values, got {group!r}")
            axes = tuple(_axis(path, f"{key}.{target}", target, values)
                         for target, values in group.items())
            for axis in axes:
                if axis.target in _NOT_ZIPPABLE:
                    fail(path, f"{key}.{axis.target}", f"{axis.target} cannot be zipped; sweep "
                                                        "it as an axis of its own")
            sizes = {axis.target: len(axis.values) for axis in axes}
            if len(set(sizes.values())) != 1:
                fail(path, key, f"zipped axes need equal lengths, got {sizes}")
            dimensions.append(Dimension(dim, axes))
    names = [d.name for d in dimensions] + [a.coordinate for d in dimensions for a in d.axes
                                             if a.coordinate != d.name]
    targets = [a.target for d in dimensions for a in d.axes]
    for seen in (names, targets):
        repeated = sorted({n for n in seen if seen.count(n) > 1})
        if repeated:
            fail(path, "sweep", f"{', '.join(repeated)} swept twice; sweep each quantity once")
    return tuple(dimensions)


def _set_path(spec, dotted, value):
    """Write ``value`` at a dotted path (list entries by index) into nested ``spec``."""
    *parents, leaf = dotted.split(".")
    node = spec
    for part in parents:
        if isinstance(node, list):
            node = node[_list_index(dotted, node, part)]
        else:
            node = node.setdefault(part, {})
    if isinstance(node, list):
        node[_list_index(dotted, node, leaf)] = value
    elif isinstance(node, dict):
        node[leaf] = value
    else:
        raise RbstudyError(f"{dotted}: {'.'.join(parents)} holds {node!r}, not a mapping or list")


def _list_index(dotted, node, part):
    if not part.isdigit() or int(part) >= len(node):
        raise RbstudyError(f"{dotted}: {part!r} is not an entry of a list of {len(node)}; "
                           f"use 0..{len(node) - 1}")
    return int(part)


def _body_omega(spec, name):
    omega = spec["scene"].get("initial", {}).get("angular_velocity", {})
    if not isinstance(omega, dict) or not any(key in omega for key in ("body", "space")):
        raise RbstudyError(f"{name} needs scene.initial.angular_velocity.body (or .space)")
    frame = "body" if "body" in omega else "space"
    if name == "tilt" and frame != "body":
        raise RbstudyError("tilt needs scene.initial.angular_velocity.body")
    return omega, frame


def _apply_short(spec, name, value):
    """Write a short-name value into the case mapping ``spec`` (``scene``, ``run``)."""
    if name in ("scheme", "dt"):
        spec["run"][name] = value
        return
    number = float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else None
    if number is None:
        raise RbstudyError(f"expected a number, got {value!r}")
    if name == "inertia_ratio":
        inertia = spec["scene"].get("body", {}).get("inertia")
        if not (isinstance(inertia, list) and len(inertia) == 3 and inertia[0] == inertia[1]
                and not isinstance(inertia[0], list)):
            raise RbstudyError("inertia_ratio needs scene.body.inertia = [I1, I1, I3], a body "
                               f"symmetric about axis 3, got {inertia!r}")
        spec["scene"]["body"]["inertia"] = [inertia[0], inertia[0], number * inertia[0]]
        return
    omega, frame = _body_omega(spec, name)
    vector = np.asarray(omega[frame], dtype=float)
    size = float(np.linalg.norm(vector))
    if name == "spin":
        if size == 0.0:
            raise RbstudyError("spin keeps the direction of the initial w, which is zero")
        omega[frame] = [float(v) for v in vector * (number / size)]
        return
    azimuth = math.atan2(vector[1], vector[0])
    tilt = math.radians(number)
    omega[frame] = [size * math.sin(tilt) * math.cos(azimuth),
                    size * math.sin(tilt) * math.sin(azimuth), size * math.cos(tilt)]


def _case_spec(base, dimensions, index):
    spec = copy.deepcopy(base)
    chosen = {axis.target: (axis, axis.values[i]) for dim, i in zip(dimensions, index, strict=True)
              for axis in dim.axes}
    for target, (_, value) in chosen.items():
        if target not in SHORT_NAMES:
            _set_path(spec, target, value)
    for name in _SHORT_ORDER:
        if name in chosen:
            _apply_short(spec, name, chosen[name][1])
    return spec


def _where(dimensions, index):
    """``sweep.dt[2] = 0.0025, sweep.scheme[0] = 'euler'``: names a case in an error."""
    return ", ".join(f"{axis.coordinate}[{i}] = {axis.values[i]!r}"
                     for dim, i in zip(dimensions, index, strict=True)
                     for axis in dim.axes)


def expand(path, base, dimensions, output_interval):
    """Every case of the grid, in C order of ``dimensions``, each scene built and checked.

    ``base`` is the study mapping (``scene``, ``run``); the first bad case raises a
    `ConfigError` naming the file, the swept values and the fix. Scheme options apply to the
    schemes that have them (``alpha`` to hht in a sweep over every scheme); an option that no
    scheme of the study has is an error.
    """
    cases = []
    scenes = {}
    used, ignored = set(), set()
    for index in itertools.product(*(range(d.size) for d in dimensions)):
        where = f"sweep ({_where(dimensions, index)})" if dimensions else "run"
        try:
            spec = _case_spec(base, dimensions, index)
        except RbstudyError as error:
            fail(path, where, str(error))
        run = spec["run"]
        try:
            scheme = get_scheme(run.get("scheme"))
            given = run.get("options") or {}
            known = {option.name for option in scheme.options}
            options = {name: value for name, value in given.items() if name in known}
            used.update(options)
            ignored.update(set(given) - known)
            scheme.option_row(options)
        except RbstudyError as error:
            fail(path, where, str(error))
        run["options"] = options
        dt = run.get("dt")
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not dt > 0:
            fail(path, f"{where}: run.dt" if dimensions else "run.dt",
                  f"must be a number > 0 (s), got {dt!r}")
        try:
            steps_per(output_interval, float(dt), "output interval")
        except RbstudyError as error:
            fail(path, where if dimensions else "run.dt", str(error))
        key = scene_key(spec["scene"])
        try:
            # Cases that differ only in scheme or dt share one scene object.
            scene = scenes.get(key) or scenes.setdefault(
                key, scene_from_mapping(spec["scene"], source=path))
        except RbstudyError as error:
            if not dimensions:
                raise ConfigError(str(error)) from None
            fail(path, where, str(error).removeprefix(f"{path}: "))
        cases.append(Case(index=index, scene=scene, spec=spec, scheme=scheme.name,
                          options=options, dt=float(dt)))
    unknown = sorted(ignored - used)
    if unknown:
        schemes = sorted({case.scheme for case in cases})
        fail(path, "run.options", f"{', '.join(unknown)} is an option of none of the study's "
                                   f"schemes ({', '.join(schemes)}); see `rbstudy schemes`")
    return tuple(cases)


def _normalised(value):
    """JSON-ready copy with every number a float, so that 1 and 1.0 hash alike."""
    if isinstance(value, dict):
        return {str(k): _normalised(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_normalised(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    return float(value)


def scene_key(scene_spec):
    """The identity of a resolved scene mapping (cases with equal keys share a scene)."""
    return json.dumps(_normalised(scene_spec), sort_keys=True)


def canonical_id(payload):
    """A short stable hash of ``payload``: canonical JSON (sorted keys, numbers as floats) plus
    `SCHEMA_VERSION`."""
    text = json.dumps({"schema": SCHEMA_VERSION, "payload": _normalised(payload)},
                      sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:ID_LENGTH]


@dataclass(frozen=True)
class Batch:
    """Cases of one scheme and time step, run as one dask task and stored as one part.

    id : ``<scheme>_dt<dt>_<hash>``, the hash of the cases' specs, the output grid and the
    stored variables (`canonical_id`): the same config gives the same ids, a changed one new
    ids. cases : positions in the study's case list.
    """

    id: str
    scheme: str
    dt: float
    cases: tuple


def plan_batches(cases, dimensions, output_interval, variables, max_cases):
    """Group ``cases`` by (scheme, dt), in case order, into batches of at most ``max_cases``.

    A batch's id hashes what its part holds and where it goes: the cases' resolved specs and
    their positions, the grid (every dimension's axes and values), the output grid and the
    stored variables, and the source digest of rbstudy (a fixed bug never reuses old numbers).
    Reordering or extending an axis therefore gives new ids, never a part in the wrong cells.
    """
    grid = [[d.name, [[a.target, list(a.values)] for a in d.axes]] for d in dimensions]
    groups = {}
    for position, case in enumerate(cases):
        groups.setdefault((case.scheme, case.dt), []).append(position)
    batches = []
    for (scheme, dt), members in groups.items():
        for start in range(0, len(members), max_cases):
            chunk = tuple(members[start:start + max_cases])
            digest = canonical_id({"cases": [cases[i].spec for i in chunk],
                                   "positions": list(chunk), "grid": grid,
                                   "output_interval": output_interval,
                                   "variables": list(variables), "source": SOURCE_DIGEST})
            batches.append(Batch(f"{scheme}_dt{dt:g}_{digest}", scheme, dt, chunk))
    return tuple(batches)
