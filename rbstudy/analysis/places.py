"""Where a study's findings hold: the values of the swept axes other than scheme and ``dt``,
each case's labels along them, and a list of cases told in words without losing a value
(``inertia_ratio 0.0001 to 10000, 17 values, every value swept``).

The findings (`rbstudy.analysis.findings`) and the recommendation
(`rbstudy.analysis.recommend`) read their cases through `CaseLabels`, whose labels are made
only when read: a finding names a few of a million cases.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping, Sequence
from typing import Any

import numpy as np
import xarray as xr

__all__ = [
    "SWEPT_BY_SUMMARY",
    "SHOWN_VALUES",
    "significant",
    "plain",
    "other_dims",
    "label_values",
    "value_texts",
    "axis_text",
    "runs_text",
    "CaseLabels",
    "Members",
    "cases_of",
]

# The axes the per-scheme table sweeps itself: every other swept axis is a question of the study.
SWEPT_BY_SUMMARY = ("scheme", "dt")
# A list of values is named whole up to this many; a longer one as a range that loses none
# ("0.0001 to 10000, 17 values, every value swept", "all 17 values but 3.16": `axis_text`).
# A zipped axis is named by its coordinates joined ("spin/tilt 1/0") up to this many, and by
# its own name and position beyond ("body 1").
MAX_JOINED = 2
SHOWN_VALUES = 6


def significant(value: float, digits: int = 3) -> str:
    """A number with ``digits`` significant digits, as text."""
    return f"{value:.{digits}g}"


def plain(value: Any) -> Any:
    """A coordinate value as a JSON-friendly Python scalar."""
    value = value.item() if isinstance(value, np.generic) else value
    return str(value) if isinstance(value, bytes | np.str_) else value


def other_dims(ds: xr.Dataset) -> list[str]:
    """The swept axes of ``ds`` other than scheme and ``dt`` (`SWEPT_BY_SUMMARY`), in its order."""
    return [str(d) for d in ds["status"].dims if d not in SWEPT_BY_SUMMARY]


def label_values(ds: xr.Dataset, dim: str) -> dict[str, list[Any]]:
    """The labels of every position along ``dim``, name -> list of plain values: every
    coordinate that runs along ``dim`` alone (a zipped axis has several), else the
    position. Read once per axis: reading them per case took seconds a thousand cases."""
    names = [str(name) for name, coord in ds.coords.items() if coord.dims == (dim,)]
    if not names:
        return {dim: list(range(ds.sizes[dim]))}
    return {name: [plain(value) for value in ds[name].values] for name in names}


class _Place(dict[str, Any]):
    """The coordinates of one value of the other swept axes (name -> value), as `cases_of`
    yields them, which also know where they lie: ``positions`` (dim -> index) along
    ``axes`` (dim -> `label_values` of that dim, every value swept), so that a list of them
    can be told without losing a value (`_where`). Elsewhere it is the plain mapping."""

    positions: dict[str, int] = {}
    axes: dict[str, dict[str, list[Any]]] = {}


def _where(labels: Sequence[_Place]) -> str:
    """Where a finding holds, every value of it (`_held`): ``inertia_ratio 0.5, 1.5, 2`` or
    ``inertia_ratio 0.0001 to 10000, 17 values, every value swept``, for the ``labels`` (a
    list of `cases_of`' `_Place` mappings); a zipped axis's coordinates together
    (``spin/tilt 1/0, 2/0.5``), its index left out. Where the values held are not every
    combination of the axes' values held, it is told per value of the later axes
    (``alpha 0, -0.05 at inertia_ratio 1; alpha 0 at inertia_ratio 2``)."""
    axes = labels[0].axes if isinstance(labels[0], _Place) else {}
    if not axes:  # plain mappings: every value named
        return "; ".join(
            f"{name} " + ", ".join(dict.fromkeys(_text(label[name]) for label in labels))
            for name in labels[0]
        )
    return _held([tuple(label.positions[dim] for dim in axes) for label in labels], list(axes.items()))


def _held(positions: list[tuple[int, ...]], axes: list[tuple[str, dict[str, list[Any]]]]) -> str:
    """`_where`'s text of the held ``positions`` (tuples of indices along ``axes``, a list of
    (dim, `label_values` of it)): per axis when they are every combination of the axes'
    values they hold, else the first axis's values per combination of the others."""
    first = sorted({p[0] for p in positions})
    if len(axes) == 1:
        return axis_text(*axes[0], first)
    rests: dict[tuple[int, ...], set[int]] = {}
    for p in positions:
        rests.setdefault(p[1:], set()).add(p[0])
    groups: dict[tuple[int, ...], list[tuple[int, ...]]] = {}
    for rest, held in rests.items():
        groups.setdefault(tuple(sorted(held)), []).append(rest)
    if len(groups) == 1 and len(positions) == len(first) * len(rests):  # every combination
        return "; ".join([axis_text(*axes[0], first), _held(list(rests), axes[1:])])
    return "; ".join(
        f"{axis_text(*axes[0], list(held))} at {_held(rest, axes[1:])}" for held, rest in groups.items()
    )


def _axis_names(dim: str, axis: Mapping[str, list[Any]]) -> list[str]:
    """The coordinates that name the values along ``dim`` (`label_values` ``axis``): a zipped
    axis's own, its index (the dimension's name) left out; a zip of more than `MAX_JOINED`
    coordinates is named by the dimension alone, its values by their positions (``body 1``):
    five coordinates joined ran past a line."""
    names = [name for name in axis if name != dim] or [dim]
    return names if len(names) <= MAX_JOINED else [dim]


def value_texts(dim: str, axis: Mapping[str, list[Any]]) -> list[str]:
    """Every value along ``dim`` as text, a zipped axis's coordinates joined by "/" (its
    positions where `_axis_names` names it by the dimension)."""
    names = _axis_names(dim, axis)
    count = len(next(iter(axis.values())))
    columns = [axis.get(name, range(count)) for name in names]
    return ["/".join(_text(column[k]) for column in columns) for k in range(count)]


def axis_text(dim: str, axis: Mapping[str, list[Any]], held: Sequence[int]) -> str:
    """The values at positions ``held`` (sorted) along ``dim`` (`label_values` ``axis``),
    none lost: each named when at most `SHOWN_VALUES`; ``0.0001 to 10000, 17 values, every
    value swept``; ``all 17 values but 3.16``; or runs of neighbouring swept values, ``0.0001
    to 0.1, 1 (8 of the 17 values: every swept value of each range)``."""
    values = value_texts(dim, axis)
    name = "/".join(_axis_names(dim, axis))
    count = len(values)
    if len(held) <= SHOWN_VALUES:
        return f"{name} " + ", ".join(values[k] for k in held)
    if len(held) == count:
        return f"{name} {values[0]} to {values[-1]}, {count} values, every value swept"
    left = sorted(set(range(count)) - set(held))
    if len(left) <= SHOWN_VALUES:
        return f"{name} all {count} values but " + ", ".join(values[k] for k in left)
    counted = f"{len(held)} of the {count} values"
    return f"{name} {runs_text(values, held)} ({counted}: every swept value of each range)"


def runs_text(values: Sequence[str], held: Sequence[int]) -> str:
    """The ``values`` at positions ``held`` as runs of neighbours: ``a to b`` for three or
    more, ``a and b`` for two."""
    runs: list[list[int]] = []
    for k in held:
        if runs and k == runs[-1][-1] + 1:
            runs[-1].append(k)
        else:
            runs.append([k])
    return ", ".join(
        f"{values[run[0]]} to {values[run[-1]]}" if len(run) >= 3 else " and ".join(values[k] for k in run)
        for run in runs
    )


def _text(value: Any) -> str:
    """A coordinate value as text: 3 significant digits, 3160 and 10000 rather than 3.16e+03
    and 1e+04."""
    if not isinstance(value, float):
        return str(value)
    return f"{float(significant(value)):.0f}" if 1e3 <= abs(value) < 1e6 else significant(value)


class CaseLabels(Sequence[_Place]):
    """The `_Place` of each value of the other swept axes, in C order (as `cases_of` yields
    them), each made when it is read: a finding names a few of a million cases, whose
    mappings, made all at once, are slow to make and large to hold."""

    def __init__(self, ds: xr.Dataset) -> None:
        self.dims = other_dims(ds)
        self.shape = tuple(ds.sizes[d] for d in self.dims)
        self._labels_of = [label_values(ds, dim) for dim in self.dims]
        self.axes = dict(zip(self.dims, self._labels_of, strict=True))

    def __len__(self) -> int:
        return math.prod(self.shape)

    def __getitem__(self, k: int) -> _Place:  # type: ignore[override]  # no slices: read a case at a time
        if not -len(self) <= k < len(self):
            raise IndexError(k)
        return self.at(tuple(int(i) for i in np.unravel_index(k % len(self), self.shape)))

    def at(self, index: tuple[int, ...]) -> _Place:
        """The `_Place` at ``index`` (a position along each of the other swept axes)."""
        labels = _Place()
        for values, k in zip(self._labels_of, index, strict=True):
            labels.update({name: column[k] for name, column in values.items()})
        labels.positions = dict(zip(self.dims, index, strict=True))
        labels.axes = self.axes
        return labels

    def where(self, members: Sequence[int] | np.ndarray) -> str:
        """`_where` of the cases ``members`` (their indices, ascending), from their positions
        alone."""
        if not self.dims:
            return _where([self[k] for k in members])
        positions = np.column_stack(np.unravel_index(members, self.shape)).tolist()
        return _held(list(map(tuple, positions)), list(self.axes.items()))


class Members(Sequence[Mapping[str, Any]]):
    """A finding's cases (`Finding.cases`): those of ``members`` (indices) among ``labels``
    (`CaseLabels`), each mapping made when it is read, the ``fixed`` names (a scheme and a
    step) before its labels."""

    def __init__(
        self, labels: CaseLabels, members: Sequence[int] | np.ndarray, fixed: Mapping[str, Any] | None = None
    ) -> None:
        self._labels, self._members, self._fixed = labels, members, fixed

    def __len__(self) -> int:
        return len(self._members)

    def __getitem__(self, k: int | slice) -> Any:
        if isinstance(k, slice):
            return tuple(self[i] for i in range(*k.indices(len(self))))
        labels = self._labels[int(self._members[k])]
        return labels if self._fixed is None else {**self._fixed, **labels}

    def __eq__(self, other: object) -> bool:  # as the tuple of cases it stands for
        return isinstance(other, tuple | Members) and tuple(self) == tuple(other)

    def __repr__(self) -> str:
        return f"Members({len(self)} cases)"


def cases_of(ds: xr.Dataset) -> Iterator[tuple[_Place, dict[str, int]]]:
    """The cases of every value of the other swept axes, in C order: (labels, isel indexer)
    pairs, the labels a `_Place`."""
    labels = CaseLabels(ds)
    for index in np.ndindex(*labels.shape):
        place = labels.at(index)
        yield place, dict(place.positions)
