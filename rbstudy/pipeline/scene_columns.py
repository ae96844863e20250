"""The distinct scenes of a sweep: its scene axes written into the study's scene as columns.

The scene axes (short names that change the body or its spin, ``scene.`` paths) are
written in as columns, one entry per distinct scene, and all scenes are read and checked at
once (`rbstudy.inputs.scenes.scene_table`), so that validating a study costs microseconds
per case. A bad value fails with the row of the first scene it spoils.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from rbstudy.errors import InputError
from rbstudy.inputs.reader import Reader
from rbstudy.inputs.scenes import scene_table
from rbstudy.physics.analytic import symmetry_axes
from rbstudy.physics.scenes import SceneTable
from rbstudy.pipeline.axes import SHORT_NAMES, Dimension, touches_scene

__all__ = ["set_path", "distinct_scenes"]

# Applied after dotted paths, in this order (spin and tilt commute: one sets the length of w,
# the other its direction).
_SHORT_ORDER = ("scheme", "dt", "inertia_ratio", "tilt", "spin")


def _check_replaced(dotted: str, old: Any) -> None:
    """Refuse a value of the study that a sweep of ``dotted`` replaces but that no sweep
    value could stand for (a list, a number past a float): replaced, it would pass unread."""
    try:
        readable = isinstance(old, str | bool) or (isinstance(old, int | float) and math.isfinite(float(old)))
    except OverflowError:
        readable = False
    if not readable:
        shown = repr(old) if len(repr(old)) <= 40 else repr(old)[:37] + "..."
        raise InputError(
            f"holds {shown}, which the sweep of it replaces but no sweep value stands for",
            "give a number, a name or true/false there",
            key=dotted,
        )


def set_path(spec: Any, dotted: str, value: Any) -> None:
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
        index = _list_index(dotted, node, leaf)
        _check_replaced(dotted, node[index])
        node[index] = value
    elif isinstance(node, dict):
        if leaf in node:
            _check_replaced(dotted, node[leaf])
        node[leaf] = value
    else:
        raise InputError(
            f"{'.'.join(parents)} holds {node!r}, not a mapping or list",
            "sweep a path that exists in the study",
            key=dotted,
        )


def _list_index(dotted: str, node: list[Any], part: str) -> int:
    if not part.isdigit() or int(part) >= len(node):
        raise InputError(
            f"{part!r} is not an entry of a list of {len(node)}", f"use 0..{len(node) - 1}", key=dotted
        )
    return int(part)


def _column(values: Sequence[Any]) -> np.ndarray:
    """Axis values as a column: flags when all are true or false, objects when names are
    among them, else floats."""
    if all(isinstance(v, bool) for v in values):
        return np.array(values, dtype=bool)
    if any(isinstance(v, (str, bool)) for v in values):
        return np.array(values, dtype=object)
    return np.array(values, dtype=float)


def _fail_at(
    bad: np.ndarray, message: Callable[[int], str], fix: str | None = None, key: str | None = None
) -> None:
    """Raise an `InputError` at the first row where ``bad`` (n,) holds."""
    if bad.any():
        row = int(np.argmax(bad))
        raise InputError(message(row), fix, key=key, row=row)


def _entry(value: Any, row: int) -> Any:
    """The value of a leaf (a number, or a column) in scene ``row``, as a Python value."""
    if not isinstance(value, np.ndarray):
        return value
    entry = value[row]
    return entry.item() if isinstance(entry, np.generic) else entry


def _as_floats(value: Any, size: int) -> np.ndarray:
    """A leaf as (size,) floats, NaN where it is not a number."""
    if isinstance(value, np.ndarray) and value.dtype.kind == "f":
        return value
    entries = value.tolist() if isinstance(value, np.ndarray) else [value] * size
    return np.array([_float_or_nan(entry) for entry in entries])


def _float_or_nan(value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    try:
        return float(value)
    except OverflowError:  # an integer beyond any float
        return math.nan


def _vector_rows(values: Any, size: int, key: str) -> np.ndarray:
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


def _body_omega(scene: dict[str, Any], name: str, size: int) -> tuple[dict[str, Any], str, np.ndarray]:
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


def _inside(mapping: Any, *keys: str) -> Any:
    """The value at ``keys`` in nested mappings, None where one is missing or not a mapping."""
    for key in keys:
        mapping = mapping.get(key) if isinstance(mapping, dict) else None
    return mapping


def _short_numbers(name: str, column: np.ndarray) -> np.ndarray:
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


def _apply_short(scene: dict[str, Any], name: str, column: np.ndarray) -> None:
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


def distinct_scenes(reader: Reader, base: Mapping[str, Any], dimensions: Sequence[Dimension]) -> SceneTable:
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
            set_path(scene, target, column)
    for name in _SHORT_ORDER:
        if name in chosen:
            _apply_short(scene["scene"], name, chosen[name])
    return scene_table(scene["scene"], source=reader.source, size=size)
