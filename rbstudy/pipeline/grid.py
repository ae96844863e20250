"""The sweep grid: a study's dimensions -> one `Case` per grid point.

The dimensions come from the ``sweep:`` block (`rbstudy.pipeline.axes`). A case is the
study's scene and run with one value of every axis written in. The scene axes give the
distinct scenes, one `SceneTable` (`rbstudy.pipeline.scene_columns`); the run axes (scheme,
dt, ``run.options.``) give the few distinct runs. A case is a pair of rows, built into a
`Case` only when asked for, so that a study of 1e5 cases holds no 1e5 Python objects. A bad
scene or run fails naming the swept values of its case; every failure goes through the
study's `rbstudy.inputs.reader.Reader`.
"""

from __future__ import annotations

import collections.abc
import itertools
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rbstudy.errors import InputError, did_you_mean
from rbstudy.inputs.reader import Reader
from rbstudy.physics.scenes import Scene, SceneTable
from rbstudy.physics.time_grid import steps_per
from rbstudy.pipeline.axes import Dimension, touches_scene
from rbstudy.pipeline.scene_columns import distinct_scenes, set_path
from rbstudy.schemes import SCHEMES, Scheme, get_scheme

__all__ = ["Case", "Cases", "Run", "expand", "option_notes", "read_dt"]


# --- the distinct runs: scheme, options and dt -----------------------------------------------


@dataclass(frozen=True)
class Run:
    """How a case is integrated: a scheme, the options it has, a time step (s)."""

    scheme: str
    options: dict[str, Any]
    dt: float


def read_dt(reader: Reader, value: Any, output_interval: float | None = None) -> float:
    """The time step ``value`` of ``run.dt`` (as written, or swept) in s: a positive number
    that divides ``output_interval`` (s; None when the step itself is the output interval);
    else a `ConfigError` at ``run.dt``."""
    dt = float(reader.number(value, "run.dt", positive=True))  # one value, never a column
    if output_interval is not None:
        try:
            steps_per(output_interval, dt, "dt", "output interval")
        except InputError as error:
            raise reader.locate(error, "run.dt") from None
    return dt


def _run(
    reader: Reader,
    base: Mapping[str, Any],
    dimensions: Sequence[Dimension],
    index: Sequence[int],
    output_interval: float,
) -> Run:
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
                set_path(spec, axis.target, axis.values[i])
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

    index: tuple[int, ...]
    scene: Scene
    scheme: str
    options: dict[str, Any]
    dt: float


@dataclass(frozen=True, eq=False)
class Cases(collections.abc.Sequence):
    """Every case of a study, in C order of its dimensions, each built when asked for.

    A case is a distinct scene and a distinct run: ``scenes`` (a `SceneTable`) and ``runs``
    (`Run`s) hold them, ``scene_rows`` and ``run_rows`` (cases,) say which each case has, so
    that a study of 1e5 cases holds no 1e5 Python objects.
    """

    shape: tuple[int, ...]
    scenes: SceneTable
    runs: tuple[Run, ...]
    scene_rows: np.ndarray
    run_rows: np.ndarray

    def __len__(self) -> int:
        return len(self.scene_rows)

    def __getitem__(self, number: int) -> Case:  # type: ignore[override]  # cases are numbered, never sliced
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

    def __iter__(self) -> Iterator[Case]:
        return (self[number] for number in range(len(self)))


def _where(dimensions: Sequence[Dimension], index: Sequence[int]) -> str:
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


def _rows_of(dimensions: Sequence[Dimension], chosen: Sequence[int], shape: tuple[int, ...]) -> np.ndarray:
    """For each case of the grid ``shape``, its row in the product of the ``chosen``
    dimensions (positions among ``dimensions``)."""
    size = math.prod(shape)
    if not chosen:
        return np.zeros(size, dtype=np.int64)
    index = np.unravel_index(np.arange(size), shape)
    return np.ravel_multi_index([index[k] for k in chosen], [shape[k] for k in chosen])


def _given_options(base: Mapping[str, Any], dimensions: Iterable[Dimension]) -> dict[str, str]:
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


def _takers(option: str, schemes: Iterable[Scheme]) -> list[str]:
    """The names of the `Scheme`s of ``schemes`` that take the option named ``option``."""
    return [scheme.name for scheme in schemes if any(o.name == option for o in scheme.options)]


def option_notes(
    base: Mapping[str, Any], dimensions: Iterable[Dimension], runs: Iterable[Run]
) -> tuple[str, ...]:
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


def expand(
    reader: Reader, base: Mapping[str, Any], dimensions: Sequence[Dimension], output_interval: float
) -> Cases:
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
        scenes = distinct_scenes(reader, base, scene_dimensions)
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
