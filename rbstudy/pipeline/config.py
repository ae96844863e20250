"""Study configs: YAML -> a validated, frozen `StudyConfig`, or a one-line `ConfigError`.

A study holds a name, a title, a scene (`rbstudy.inputs.scenes`), the output spec, the run
(scheme, scheme options, dt) and a sweep (`rbstudy.pipeline.axes`). Loading expands the sweep
(`rbstudy.pipeline.grid`), builds every case's scene and plans the batches
(`rbstudy.pipeline.batches`), so every error surfaces before any work starts, through one
`rbstudy.inputs.reader.Reader` naming the file, the key path, the value and the fix.
docs/config.md documents every key.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import yaml

from rbstudy.archive.layout import FORMATS
from rbstudy.archive.variables import (
    BOOKKEEPING,
    COST_MODEL,
    DEPRECATED,
    SCHEME_COORDINATES,
    UNCERTAINTIES,
    VARIABLES,
    scene_features,
    selected,
)
from rbstudy.errors import ConfigError, InputError
from rbstudy.inputs.reader import FOLDER_NAME_RULE, MAX_TITLE_CHARACTERS, Reader
from rbstudy.inputs.yaml_file import read_yaml_file
from rbstudy.numerics.state import N_STATE, row_width
from rbstudy.physics.scenes import SceneTable
from rbstudy.physics.time_grid import output_count
from rbstudy.pipeline.axes import MAX_CASES, Dimension, label_options, parse_sweep, touches_scene
from rbstudy.pipeline.batch_data import ACCURACY_BOUND
from rbstudy.pipeline.batches import Batch, plan_batches
from rbstudy.pipeline.grid import Cases, expand, option_notes, read_dt
from rbstudy.pipeline.overrides import Overridden, apply_overrides
from rbstudy.schemes import composition_reach, get_scheme

__all__ = [
    "StudyConfig",
    "OrderDimension",
    "load_study",
    "BATCH_MAX_CASES",
    "BATCH_MAX_BYTES",
    "MAX_CASES",
    "resolved_config",
]

_TOP_KEYS = ("name", "title", "scene", "output", "run", "sweep")
# The keys a study cannot do without, and how to add each (docs/config.md).
_REQUIRED_KEYS = {
    "name": f"add name: <{FOLDER_NAME_RULE}> (it names the results folder)",
    "scene": "add scene: with its body and initial state (docs/config.md)",
    "run": "add run: with scheme and dt, or sweep them (docs/config.md)",
}

# A batch holds at most this many cases, and at most this many bytes of sampled states: enough
# bodies to amortise a task's and its part file's fixed cost (a part's writing time goes mostly to
# a fixed cost: creating its variables and its fsyncs), few enough that
# several batches run at once and a kill loses little work.
BATCH_MAX_CASES = 4096
BATCH_MAX_BYTES = 256 * 2**20


@dataclass(frozen=True)
class StudyConfig:
    """A validated study.

    text : the config file's text (its SHA-256 names the study folder's owner,
    `rbstudy.archive.owner.folder_claim`). overrides : the ``--set KEY=VALUE`` texts applied to
    it (`rbstudy.pipeline.overrides`). archived_text : the config text the archive stores: the
    file's, or with the overrides applied. base : the ``scene`` and ``run`` mappings as
    written. dimensions : the swept `rbstudy.pipeline.axes.Dimension`s (empty for one case).
    cases : every case, in C order of the dimensions (`rbstudy.pipeline.grid.Cases`: its
    distinct scenes and runs). variables : the stored variable names. batches : the
    `rbstudy.pipeline.batches.Batch`es. schemes : what the archive records of each scheme,
    name -> {coordinate: value} (`rbstudy.archive.variables.SCHEME_COORDINATES`; the
    nominal order a tuple along `order_dimension` where a composition is swept). n_times :
    output samples per case. output_format : the archive's format, a key of
    `rbstudy.archive.layout.FORMATS` (``output.format``, or ``sweep --format``).
    """

    path: str
    text: str
    overrides: tuple[str, ...]
    archived_text: str
    name: str
    title: str
    base: dict
    output_interval: float
    accuracy_bound: float
    duration: float
    dimensions: tuple[Dimension, ...]
    cases: Cases
    variables: tuple[str, ...]
    batches: tuple[Batch, ...]
    schemes: dict[str, dict]
    output_format: str = "netcdf"

    @property
    def order_dimension(self) -> OrderDimension | None:
        """The `OrderDimension` of a swept option that sets the nominal order (a
        composition), or None."""
        return order_dimension(self.dimensions, self.schemes)

    @property
    def scene_dims(self) -> tuple[str, ...]:
        """Names of the dimensions along which the scene changes: those of the variables of
        the scene alone (`rbstudy.archive.variables.PER_SCENE`)."""
        return tuple(d.name for d in self.dimensions if any(map(touches_scene, d.axes)))

    @property
    def n_times(self) -> int:
        return output_count(self.duration, self.output_interval)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(d.size for d in self.dimensions)

    @property
    def node_names(self) -> tuple[str, ...]:
        return self.cases.scenes.node_names

    def bytes_per_case(self) -> int:
        """Bytes one case occupies in the archive."""
        sizes = {"time": self.n_times, "axis": 3, "component": 4, "node": len(self.node_names)}
        return sum(
            np.dtype(VARIABLES[name].dtype).itemsize * math.prod(sizes[d] for d in VARIABLES[name].dims)
            for name in self.variables
        )

    def working_bytes_per_case(self) -> int:
        """Bytes a case holds while its batch runs: sampled states, outputs, and its
        parameter row (long with long load tables)."""
        knots = self.cases.scenes.loads["knots"].shape[-1]
        return self.bytes_per_case() + np.dtype("f8").itemsize * (
            N_STATE * self.n_times + int(row_width(knots))
        )

    @property
    def notes(self) -> tuple[str, ...]:
        """What a user should know of how the study runs, one line each: a scheme option
        that only some of its schemes take (`rbstudy.pipeline.grid.option_notes`)."""
        return option_notes(self.base, self.dimensions, self.cases.runs)

    @property
    def warnings(self) -> tuple[str, ...]:
        """What reading the study noticed but accepted, one line each: its scenes' (a
        regularised body), knots of load tables inside the steps of a high-order scheme, and
        an accuracy bound below the float64 floor of some scene (`_floor_warnings`)."""
        return (
            self.cases.scenes.warnings
            + _knot_warnings(self.cases, self.duration)
            + _floor_warnings(self.cases.scenes, self.duration, self.accuracy_bound)
        )


# The scenes whose float64 floor `_floor_warnings` computes at most, the fastest spinning
# first (the floor grows with the angle turned): a million scenes' closed forms, seven times
# each, would take longer than reading the study.
FLOOR_SCENES = 4096


def _floor_warnings(scenes: SceneTable, duration: float, bound: float) -> tuple[str, ...]:
    """A warning when the accuracy ``bound`` (rad) lies below the float64 floor of some scene
    with a closed-form reference (`rbstudy.physics.references.table_floors`): no scheme can be
    shown to meet it there, as rounding the initial state moves the exact motion as far."""
    from rbstudy.physics.references import table_floors  # the closed forms' kernels: here only

    rows = np.argsort(-np.linalg.norm(scenes.omega_body, axis=-1), kind="stable")[:FLOOR_SCENES]
    floors = table_floors(scenes, rows, duration)
    above = np.isfinite(floors) & (floors > bound)
    if not above.any():
        return ()
    return (
        f"output.accuracy_bound: {bound:g} rad lies below the float64 floor of {int(above.sum())} of "
        f"{rows.size} scenes (up to {np.nanmax(floors):.1e} rad at t = {duration:g} s: one ulp of the "
        "initial state, carried by the exact motion): no scheme can be shown to meet it there; "
        "raise the bound or shorten the run",
    )


def _knot_warnings(cases: Cases, duration: float) -> tuple[str, ...]:
    """A warning when a knot of the loads tabulated in time falls inside a step of a fixed-step
    scheme of order above 2: the kink of the load there costs that scheme its order (rk4
    converges at order 2 only, measured), while knots on multiples of dt keep it. A
    composition whose stages reach outside the step (the triple jump) crosses every knot and
    the tables' ends, wherever they are."""
    tabulated = np.asarray(cases.scenes.loads["knots"])[0]
    knots = tabulated[(tabulated > 0.0) & (tabulated < duration)]
    for run in cases.runs:
        scheme = get_scheme(run.scheme)
        order = scheme.nominal_order(run.options)
        if order <= 2 or scheme.adaptive:
            continue
        composed = any(option.sets_order and option.name in run.options for option in scheme.options)
        earliest, latest = composition_reach(order) if composed else (0.0, 1.0)
        if tabulated.size and (earliest < 0.0 or latest > 1.0):
            return (
                f"scene.loads: {run.scheme} with composition {order} takes the loads up to "
                f"{max(-earliest, latest - 1.0):.2f} dt outside each step, across the "
                "knots and ends of the load tables: it converges at order 2 only under "
                "loads tabulated in time; use composition 6 or 8, whose stages stay "
                "inside the step",
            )
        steps = knots / run.dt
        inside = knots[np.abs(steps - np.round(steps)) > 1e-9 * np.maximum(steps, 1.0)]
        if inside.size:
            more = f" (and {inside.size - 1} more)" if inside.size > 1 else ""
            return (
                f"scene.loads: the load tables' knot at t = {inside[0]:g} s{more} "
                f"falls inside a step of dt = {run.dt:g} s: "
                f"{run.scheme} (order {order}) converges at order 2 only across it; "
                "put the knots on multiples of dt",
            )
    return ()


def _variables(reader: Reader, requested: Any, scenes: SceneTable) -> tuple[str, ...]:
    """The variables every scene of ``scenes`` defines, narrowed to ``output.variables`` when
    given (the per-case bookkeeping of `rbstudy.archive.variables.BOOKKEEPING`, the
    `COST_MODEL` and the reference's `UNCERTAINTIES` are always kept,
    and a deprecated name brings its new name along)."""
    available = selected(scene_features(scenes))
    if requested is None:
        return tuple(available)
    if not isinstance(requested, list) or not requested:
        reader.fail("output.variables", f"expected a non-empty list of names, got {requested!r}")
    for i, name in enumerate(requested):
        if not isinstance(name, str) or name not in VARIABLES:
            reader.fail(
                f"output.variables[{i}]", f"unknown variable {name!r}", f"valid: {', '.join(VARIABLES)}"
            )
        if name not in available:
            needs = ", ".join(sorted(VARIABLES[name].needs))
            reader.fail(
                f"output.variables[{i}]",
                f"{name} needs {needs}, which not every case of this study has",
                "remove it",
            )
    wanted = set(requested) | {DEPRECATED[name] for name in requested if name in DEPRECATED}
    kept = set(wanted) | set(BOOKKEEPING) | set(COST_MODEL) | set(UNCERTAINTIES)
    return tuple(name for name in available if name in kept)


class OrderDimension(NamedTuple):
    """A swept option that sets a scheme's nominal order (``run.options.composition``): the
    name of its dimension, the option's name and its values along the dimension."""

    dimension: str
    option: str
    values: tuple


def order_dimension(dimensions: Iterable[Dimension], schemes: Iterable[str]) -> OrderDimension | None:
    """The `OrderDimension` of a swept option that sets the nominal order of one of
    ``schemes`` (the study's), or None."""
    setting = {option.name for name in schemes for option in get_scheme(name).options if option.sets_order}
    for dim in dimensions:
        for axis in dim.axes:
            option = axis.target.removeprefix("run.options.")
            if axis.target.startswith("run.options.") and option in setting:
                return OrderDimension(dimension=dim.name, option=option, values=axis.values)
    return None


def _scheme_claims(cases: Cases, dimensions: Sequence[Dimension]) -> dict[str, dict[str, Any]]:
    """What the archive records of each scheme of the study: name -> {coordinate: value}.
    The nominal order is that of the scheme's options (a composition sets it); where such an
    option is swept, it is the tuple of orders along that option's dimension
    (`order_dimension`)."""
    names = sorted({run.scheme for run in cases.runs})
    swept = order_dimension(dimensions, names)
    claims = {}
    for name in names:
        scheme = get_scheme(name)
        options = next(run.options for run in cases.runs if run.scheme == name)
        claims[name] = {
            coordinate: getattr(scheme, attribute)
            for coordinate, (attribute, _, _) in SCHEME_COORDINATES.items()
        }
        claims[name]["nominal_order"] = (
            scheme.nominal_order(options)
            if swept is None
            else tuple(scheme.nominal_order({**options, swept.option: value}) for value in swept.values)
        )
    return claims


def _output_interval(reader: Reader, output: dict[str, Any], dt: float | None, swept: set[str]) -> float:
    """``output.interval`` (s), else the unswept ``run.dt`` (``dt``, already read)."""
    if "interval" in output:
        return float(reader.number(output["interval"], "output.interval", positive=True))
    if "dt" not in swept and dt is not None:
        return dt
    reader.fail("output.interval", "missing", "with dt swept, give the output interval (s)")


def load_study(path: str | os.PathLike[str], overrides: Sequence[str] = ()) -> StudyConfig:
    """Read the study config at ``path``, apply the ``--set`` texts ``overrides``
    (``KEY=VALUE``, `rbstudy.pipeline.overrides`) and validate it; nothing is run or written.
    An error in what an override wrote names its key as ``--set <key>``."""
    path = str(path)
    text, data = read_yaml_file(path)
    overridden = apply_overrides(data, overrides, path)
    try:
        return _validated(path, text, overridden)
    except InputError as error:
        raise overridden.blame(error) from None


def _validated(path: str, text: str, overridden: Overridden) -> StudyConfig:
    """The `StudyConfig` of the `Overridden` mapping of the file ``path`` of text ``text``."""
    reader = Reader(path, ConfigError)
    data = reader.mapping(overridden.data, "", _TOP_KEYS)  # an empty file reads as empty: name missing
    for key, fix in _REQUIRED_KEYS.items():
        if key not in data:
            reader.fail(key, "missing", fix)
    name, title = _names(reader, data)
    run = reader.mapping(data["run"], "run", ("scheme", "options", "dt"))
    dimensions = parse_sweep(reader, data.get("sweep"))
    swept, dt = _checked_run(reader, run, dimensions)
    output = _output(reader, data.get("output"), dt, swept)
    if not isinstance(data["scene"], dict):
        reader.fail("scene", f"expected a mapping, got {data['scene']!r}")
    base = {"scene": data["scene"], "run": dict(run)}
    cases = expand(reader, base, dimensions, output.interval)
    duration = cases.scenes.duration
    try:
        output_count(duration, output.interval)
    except InputError as error:
        raise reader.locate(error, "output.interval") from None
    variables = _variables(reader, output.variables, cases.scenes)
    dimensions = label_options(dimensions, sorted({run.scheme for run in cases.runs}))
    study = StudyConfig(
        path=path,
        text=text,
        overrides=overridden.assignments,
        archived_text=overridden.text(text),
        name=name,
        title=title,
        base=base,
        output_interval=output.interval,
        accuracy_bound=output.accuracy_bound,
        duration=duration,
        dimensions=dimensions,
        cases=cases,
        variables=variables,
        batches=(),
        schemes=_scheme_claims(cases, dimensions),
        output_format=output.format,
    )
    return dataclasses.replace(study, batches=_batches(study))


def _names(reader: Reader, data: dict[str, Any]) -> tuple[str, str]:
    """The study's ``name`` (its folder's) and ``title`` (the name unless given)."""
    name = reader.folder_name(data["name"], "name")
    title = reader.line(data.get("title", name), "title")
    if "title" in data and len(title) > MAX_TITLE_CHARACTERS:  # the default, the name, is bounded
        reader.fail(
            "title",
            f"{len(title):,} characters long, at most {MAX_TITLE_CHARACTERS}: it heads every figure",
            "shorten it, and put the longer description in a comment of the config",
        )
    return name, title


def _checked_run(
    reader: Reader, run: dict[str, Any], dimensions: tuple[Dimension, ...]
) -> tuple[set[str], float | None]:
    """The targets the sweep's ``dimensions`` sweep and the ``run.dt`` written (s; None if
    not), once the study is checked to have at most `MAX_CASES` cases, and a scheme and dt
    written in ``run`` or swept."""
    count = math.prod(d.size for d in dimensions)
    if count > MAX_CASES:
        reader.fail(
            "sweep",
            f"{count:,} cases ("
            + " x ".join(str(d.size) for d in dimensions)
            + f"); at most {MAX_CASES:,} per study",
            "split it into several studies",
        )
    swept = {axis.target for d in dimensions for axis in d.axes}
    for key in ("scheme", "dt"):
        if key not in run and key not in swept:
            reader.fail(f"run.{key}", "missing", "give it here or sweep it")
    # checked even when swept: a value that is never used must still not be garbage
    dt = read_dt(reader, run["dt"]) if "dt" in run else None
    if "scheme" in run:
        try:
            get_scheme(run["scheme"])
        except InputError as error:
            raise reader.locate(error, "run.scheme") from None
    if not isinstance(run.get("options") or {}, dict):
        reader.fail("run.options", f"expected a mapping of option: value, got {run['options']!r}")
    return swept, dt


class _Output(NamedTuple):
    """The ``output:`` block read: the sampling interval (s), the variables asked for (None:
    every one), the accuracy bound and the archive's format."""

    interval: float
    variables: list | None
    accuracy_bound: float
    format: str


def _output(reader: Reader, given: Any, dt: float | None, swept: set[str]) -> _Output:
    """The ``output:`` block ``given``, read and checked; ``dt``, ``swept`` as
    `_output_interval` takes them."""
    output = reader.mapping(given, "output", ("interval", "variables", "accuracy_bound", "format"))
    output_format = output.get("format", "netcdf")
    if output_format not in FORMATS:
        reader.fail(
            "output.format",
            f"unknown archive format {output_format!r}",
            "valid: netcdf (one file, the default) or zarr (a store for cluster-scale studies)",
        )
    interval = _output_interval(reader, output, dt, swept)
    bound = output.get("accuracy_bound", ACCURACY_BOUND)
    accuracy_bound = float(reader.number(bound, "output.accuracy_bound", positive=True))
    return _Output(interval, output.get("variables"), accuracy_bound, output_format)


def _batches(study: StudyConfig) -> tuple[Batch, ...]:
    """The batches of ``study`` (`plan_batches`), each at most `BATCH_MAX_CASES` cases and
    `BATCH_MAX_BYTES` of working memory."""
    max_cases = max(1, min(BATCH_MAX_CASES, BATCH_MAX_BYTES // study.working_bytes_per_case()))
    runs = study.cases.runs
    return plan_batches(
        study.cases,
        study.base["scene"],
        study.dimensions,
        study.output_interval,
        study.variables,
        max_cases,
        verdict={"accuracy_bound": study.accuracy_bound},
        run_costs=[get_scheme(run.scheme).seconds_per_step(run.options) for run in runs],
        code_digests={name: get_scheme(name).code_digest for name in study.schemes},
    )


def resolved_config(study: StudyConfig) -> str:
    """The study as YAML with every sweep expanded into explicit values (``study.yaml``)."""
    resolved = {
        "name": study.name,
        "title": study.title,
        **study.base,
        "output": {
            "interval": study.output_interval,
            "variables": list(study.variables),
            "accuracy_bound": study.accuracy_bound,
            "format": study.output_format,
        },
        "sweep": {d.name: {axis.target: list(axis.values) for axis in d.axes} for d in study.dimensions},
        "cases": len(study.cases),
        "batches": [batch.id for batch in study.batches],
    }
    return yaml.safe_dump(resolved, sort_keys=False)
