"""Lines a figure draws on top of each other, found and named, so that no line hides unnamed.

Two tests, one for the data and one for the eye:

- **Coincident** (`coincident`): two lines whose values agree to `COINCIDENT_DIGITS`
  significant digits at every point (`rbstudy.analysis.summary.agree`, the findings' test),
  gaps at the same points. Every figure type draws them in turn, differing in marker and
  dash, and names them together (``rk4 = rkmk4 to 3 digits``, `together`): in the legend
  when they coincide in every case (`coinciding_lines`, which the report's caption names
  too), over a panel where they coincide there only (`panel_overlaps`).
- **Near** (`near_lines`): two lines that differ in the data but not on the page, every
  drawn point of one within `NEAR_POINTS` of the other's, gaps at the same points: euler
  and leapfrog's worst orientation errors over stiff_inertia's 17 inertia ratios, 0.3-1.4%
  apart, drew one line. Named over the panel with how far apart they are at most
  (``euler ≈ leapfrog (within 1.4%)``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, cast

import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from rbstudy.analysis.summary import (
    COINCIDENT_DIGITS,
    ERROR_MEASURES,
    agree,
    error_measure,
    per_scheme,
    schemes_of,
)

__all__ = ["NEAR_POINTS", "coincident", "together", "coinciding_lines", "panel_overlaps", "near_lines"]

# How close two drawn points are to be one to the eye (typographic points, 1/72 inch): the
# width of a figure's solid line (2 pt), under which one line covers the other.
NEAR_POINTS = 2.0


def together(
    names: Sequence[str], rows: Sequence[Any] | None = None, floor: float = 0.0, floor_name: str = "round-off"
) -> str:
    """The name of lines drawn on top of each other (`coincident` of their ``rows`` of
    values with the round-off ``floor``): ``euler = leapfrog to 3 digits``, ``... to 3
    digits above round-off (1e-13)`` where they agree only once values at the floor count as
    one, ``... (at round-off: at most 1e-12)`` where every value is there, ``... (exactly 0
    throughout)`` where every value is 0; or a line's own name. ``floor_name`` names the
    floor (``the sampling floor`` of a flip interval)."""
    joined = " = ".join(names)
    if len(names) == 1 or rows is None:
        return joined if len(names) == 1 else f"{joined} to {COINCIDENT_DIGITS} digits"
    finite = np.concatenate([np.asarray(row)[np.isfinite(row)] for row in rows])
    if finite.size and np.all(finite == 0.0):
        return f"{joined} (exactly 0 throughout)"
    if floor > 0:
        if finite.size and np.all(np.abs(finite) <= floor):
            return f"{joined} (at {floor_name}: at most {floor:g})"
        if not all(agree(rows[0], row) for row in rows[1:]):
            return f"{joined} to {COINCIDENT_DIGITS} digits above {floor_name} ({floor:g})"
    return f"{joined} to {COINCIDENT_DIGITS} digits"


def coinciding_lines(ds: xr.Dataset, key: str) -> list[tuple[str, str]]:
    """The (first, second) schemes whose lines the convergence figure of measure ``key``
    draws on top of each other and names together (`coincident` over every case, the
    measure's round-off floor aside): the figure's caption names the same pairs."""
    errors = error_measure(ds, key)
    if errors is None or "scheme" not in errors.dims:
        return []
    names = list(schemes_of(ds))
    groups = coincident(
        [per_scheme(errors, name).values.ravel() for name in names], ERROR_MEASURES[key].floor
    )
    return [(names[group[0]], names[other]) for group in groups for other in group[1:]]


def coincident(errors: Sequence[Any], floor: float = 0.0) -> list[list[int]]:
    """Groups of line indices (first line first) whose ``errors`` (lines x points) agree to
    `COINCIDENT_DIGITS` significant digits at every point (`agree`, the findings' test),
    gaps at the same points, points where both lie at or below the measure's round-off
    ``floor`` counting as agreeing (a figure cannot tell them apart: rk4 and rkmk4 differed
    by 2% at one precession error of 2.6e-14 and were drawn as one line, unnamed); each
    line is in exactly one group, alone when it has no point to agree on (failed at every
    dt)."""
    errors = [np.where(np.abs(e) <= floor, 0.0, e) if floor > 0 else e for e in errors]
    return _grouped(len(errors), lambda first, other: agree(errors[other], errors[first]), errors)


def _grouped(count, same, rows):
    """Groups of ``count`` line indices, each line with the later ones ``same(first,
    other)`` as it, unless it has no finite value in ``rows`` (nothing drawn to share)."""
    groups, placed = [], set()
    for first in range(count):
        if first in placed:
            continue
        shown = np.isfinite(rows[first]).any()
        group = [first] + [
            other for other in range(first + 1, count) if shown and other not in placed and same(first, other)
        ]
        placed.update(group)
        groups.append(group)
    return groups


def panel_overlaps(
    names: Sequence[str],
    values: Sequence[Any],
    groups: list[list[int]],
    floor: float = 0.0,
    ax: Axes | None = None,
    curves: Sequence[tuple[Any, Any]] | None = None,
) -> list[str]:
    """The lines a panel draws on top of each other that its figure's legend does not name
    together: ``values`` (lines x points) as the panel draws them, ``groups`` the figure's
    (`coincident` over every case, named in the legend). The same test, `coincident`,
    on this panel's points; each legend group is named by its first line, so that no pair
    the legend names is named again: ``no_squish = splitting to 3 digits`` over abaqus_top's
    energy errors at I3/I1 = 0.1, 0.5 and 1.5, where the legend cannot name them (they part
    at 2). Given the panel ``ax`` and each line's ``curves`` ((x, y) as drawn, its limits
    set), the lines left apart that the eye cannot part are named too (`near_lines`)."""
    first_of = {k: group[0] for group in groups for k in group}
    notes, shown = [], []
    for group in coincident(values, floor):
        firsts = list(dict.fromkeys(first_of[k] for k in group))
        shown.append(firsts[0])
        if len(firsts) > 1:
            notes.append(together([names[k] for k in firsts], [values[k] for k in firsts], floor))
    if ax is not None:
        assert curves is not None, "a panel's curves come with its axes"
        notes += near_lines(ax, [names[k] for k in shown], [curves[k] for k in shown])
    return notes


def near_lines(ax: Axes, names: Sequence[str], curves: Sequence[tuple[Any, Any]]) -> list[str]:
    """``a ≈ b (within 1.4%)`` for each group of the lines ``curves`` ((x, y) of each, as
    drawn on ``ax``, whose limits are set: exact zeros at the floor they are drawn on,
    failures NaN) whose every point lies within `NEAR_POINTS` of the first's, gaps at the
    same points; the share is their largest relative difference in x or y."""
    ax.get_xlim(), ax.get_ylim()  # the limits autoscaled now: the transform reads them as they stand
    box = ax.get_position()
    figure = cast(Figure, ax.figure)  # the figures draw no subfigures
    size = np.array([box.width * figure.get_figwidth(), box.height * figure.get_figheight()]) * 72
    to_axes = ax.transScale + ax.transLimits  # data -> the panel's unit square, log axes too
    placed = []
    for x, y in curves:
        points = np.column_stack(np.broadcast_arrays(np.asarray(x, float), np.asarray(y, float)))
        drawn = np.isfinite(points).all(axis=1) & (points > 0).all(axis=1)
        at = np.full(points.shape, np.nan)
        if drawn.any():
            at[drawn] = to_axes.transform(points[drawn]) * size
        placed.append((points, at))

    def near(first, other):
        (_, a), (_, b) = placed[first], placed[other]
        same_gaps = np.array_equal(np.isnan(a[:, 0]), np.isnan(b[:, 0]))
        return same_gaps and np.nanmax(np.hypot(*(a - b).T)) <= NEAR_POINTS

    notes = []
    for group in _grouped(len(curves), near, [at[:, 0] for _, at in placed]):
        if len(group) > 1:
            values = np.array([placed[k][0] for k in group])
            with np.errstate(invalid="ignore", divide="ignore"):
                apart = np.nanmax(np.abs(values - values[0]) / np.abs(values).max(axis=0))
            notes.append(f"{' ≈ '.join(names[k] for k in group)} (within {apart:.1%})")
    return notes
