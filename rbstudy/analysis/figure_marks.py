"""Marks the figures of `rbstudy.analysis.plots` share: the band a line stands for when a
swept axis is too long for panels, exact zeros on their floor line with their own mark and
legend entry, the accuracy bound and the recommended point of the work-precision figure, and
text labels moved clear of the data they annotate.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.text import Annotation

from rbstudy.analysis.findings import findings

__all__ = [
    "Band",
    "EXACT_ZERO_LABEL",
    "EXACT_ZERO_GID",
    "ZERO_LABEL",
    "ZERO_MARK_EVERY",
    "band",
    "zero_floor",
    "on_floor",
    "mark_floor",
    "zero_marks",
    "plot_with_zeros",
    "zero_entry",
    "GuideLabel",
    "clear_labels",
    "BOUND_STYLE",
    "RECOMMENDED_STYLE",
    "bound_label",
    "RecommendedPoint",
    "recommended_point",
]

# An exact zero, which a log axis cannot show, is drawn on the floor line in its line's
# colour with this mark (no scheme wears it), and named once in the legend: a gap in a line
# is a failed case, never a zero.
EXACT_ZERO_LABEL = "exact zero (on the dotted floor)"
EXACT_ZERO_MARKER = "$0$"
EXACT_ZERO_GID = "exact_zero"
# The label of the floor line on which exact zeros are drawn.
ZERO_LABEL = "0 (exact)"
# A dense time series marks every this many of its exact zeros (each point would be a smear).
ZERO_MARK_EVERY = 8


class _Place(NamedTuple):
    """Where a label sits around its anchor: offset ``dx``, ``dy`` in points, and its
    horizontal and vertical alignment ``ha``, ``va``."""

    dx: int
    dy: int
    ha: str
    va: str


# Where a label may sit around its anchor, tried in turn: above, below, then beside, then
# farther off.
_PLACES = [
    _Place(0, 2, "center", "bottom"),
    _Place(0, -2, "center", "top"),
    _Place(4, 0, "left", "center"),
    _Place(-4, 0, "right", "center"),
    _Place(0, 10, "center", "bottom"),
    _Place(0, -10, "center", "top"),
    _Place(12, 6, "left", "bottom"),
    _Place(-12, -6, "right", "top"),
]
# Points sampled along each segment of a line when testing it against a label's box.
_SAMPLES = 64


class Band(NamedTuple):
    """A line's values over the reduced dims (`band`): the largest (``worst``) and smallest
    (``best``) over the cases that gave a value, and how many gave none (``missing``)."""

    worst: xr.DataArray
    best: xr.DataArray
    missing: xr.DataArray


def band(da: xr.DataArray, reduced: list[str]) -> Band:
    """A line's values over the ``reduced`` dims as a `Band` (worst, best, missing): the largest and
    smallest over the cases that gave a value (a case that failed at some values of them
    still shows where it did not: the worst case with NaN kept hid six schemes of nine in
    the stiff_inertia study), and how many of those cases gave none (failed, or without a
    reference). NaN where no case gave a value."""
    if not reduced:
        return Band(da, da, da.isnull().astype(int))
    return Band(da.max(reduced, skipna=True), da.min(reduced, skipna=True), da.isnull().sum(reduced))


def zero_floor(values: Any) -> float | None:
    """The y of the floor line on which exact zeros of ``values`` (array-like) are drawn:
    half a decade below the decade under the smallest positive value (between tick labels,
    so that no label reads as the value of a zero), or None when no value is zero."""
    values = np.asarray(values, dtype=float)
    if not np.any(values == 0.0):
        return None
    positive = values[values > 0]
    decade = np.floor(np.log10(positive.min())) - 1 if positive.size else -16.0
    return 10.0 ** (decade - 0.5)


def on_floor(y: Any, floor: float | None) -> np.ndarray:
    """``y`` as `plot_with_zeros` draws it: its exact zeros on the ``floor`` line (None: it
    has no zero)."""
    y = np.asarray(y, dtype=float)
    return y if floor is None else np.where(y == 0.0, floor, y)


def mark_floor(ax: Axes, floor: float | None) -> None:
    """Draw and label the floor line (after the data, so that the limits know the data)."""
    if floor is None:
        return
    ax.axhline(floor, color="0.5", linewidth=0.8, linestyle=":", zorder=1)
    ax.annotate(
        ZERO_LABEL,
        (0.01, floor),
        xycoords=("axes fraction", "data"),
        xytext=(0, 3),
        textcoords="offset points",
        fontsize=7,
        color="0.3",
    )
    ax.set_ylim(bottom=floor / 2.0, top=max(ax.get_ylim()[1], floor * 10.0))


def zero_marks(
    ax: Axes, x: Any, zeros: np.ndarray, floor: float | None, style: dict[str, Any], every: int = 1
) -> None:
    """The points of ``x`` where ``zeros`` (booleans), on the ``floor`` line, in the line's
    colour with the exact-zero mark (every ``every``-th of them for a dense time series)."""
    if floor is None or not np.any(zeros):
        return
    (marks,) = ax.plot(
        np.asarray(x)[zeros][::every],
        np.full(int(np.sum(zeros)), floor)[::every],
        linestyle="none",
        marker=EXACT_ZERO_MARKER,
        markersize=style["markersize"] + 3,
        color=style["color"],
        zorder=style["zorder"] + 1,
    )
    marks.set_gid(EXACT_ZERO_GID)


def plot_with_zeros(
    ax: Axes,
    x: Any,
    y: Any,
    floor: float | None,
    label: str | None,
    style: dict[str, Any],
    markers: bool = True,
) -> Line2D:
    """A line with its exact zeros on the floor line, the line running down to them, each
    with the exact-zero mark (`zero_marks`) instead of the line's own (for a dense time
    series, ``markers`` off, no marks of its own, the zeros marked every `ZERO_MARK_EVERY`):
    only a failed case (NaN) is a gap."""
    y = np.asarray(y, dtype=float)
    zero = y == 0.0
    drawn = np.where(y > 0, y, np.where(zero, np.nan if floor is None else floor, np.nan))
    line_style = style if markers else {**style, "marker": ""}
    if markers and zero.any():  # the line's marks on its non-zero points only
        every = style.get("markevery") or (0, 1)
        line_style = {**style, "markevery": [k for k in range(every[0], y.size, every[1]) if not zero[k]]}
    (line,) = ax.plot(x, drawn, label=label, **line_style)
    zero_marks(ax, x, zero, floor, style, every=1 if markers else ZERO_MARK_EVERY)
    return line


def zero_entry(fig: Figure) -> list[tuple[list[Any], str]]:
    """The legend entry of the exact-zero mark, a list of one (handles, label), when some
    panel of ``fig`` shows one; else empty."""
    shown = any(line.get_gid() == EXACT_ZERO_GID for ax in fig.axes for line in ax.get_lines())
    if not shown:
        return []
    handle = Line2D([], [], linestyle="none", marker=EXACT_ZERO_MARKER, markersize=9, color="0.3")
    return [([handle], EXACT_ZERO_LABEL)]


class GuideLabel(NamedTuple):
    """A label to place clear of the data (`clear_labels`): the annotation ``text``, the
    ``line`` it names, and ``anchors``, data points along it (the first preferred)."""

    text: Annotation
    line: Line2D
    anchors: list[tuple[float, float]]


def _obstacles(ax, own):
    """Display points of the data of ``ax`` a label must keep off: points sampled along each
    drawn segment of every line but ``own`` (the label's own guide), and the markers."""
    points = []
    for line in ax.get_lines():
        if line is own or not line.get_visible():
            continue
        data = np.column_stack([line.get_xdata(), line.get_ydata()]).astype(float)
        xy = line.get_transform().transform(data)
        finite = np.isfinite(xy).all(axis=1)
        if line.get_linestyle() not in ("None", "none", "", " "):
            joined = finite[:-1] & finite[1:]
            start, end = xy[:-1][joined], xy[1:][joined]
            steps = np.linspace(0.0, 1.0, _SAMPLES)[None, :, None]
            points.append((start[:, None, :] + steps * (end - start)[:, None, :]).reshape(-1, 2))
        if line.get_marker() not in ("None", "none", "", " ", None):
            points.append(xy[finite])
    return np.concatenate(points) if points else np.zeros((0, 2))


def _hits(box, obstacles, margin):
    inside = (
        (obstacles[:, 0] > box.x0 - margin)
        & (obstacles[:, 0] < box.x1 + margin)
        & (obstacles[:, 1] > box.y0 - margin)
        & (obstacles[:, 1] < box.y1 + margin)
    )
    return int(inside.sum())


def _place(text, anchor, place):
    text.xy = anchor
    text.xyann = (place.dx, place.dy)
    text.set_horizontalalignment(place.ha)
    text.set_verticalalignment(place.va)


def _clearest(text, anchors, frame, obstacles, renderer, margin):
    """The (anchor, place) of ``text``: the first of its ``anchors`` and of `_PLACES`
    around it where its box, widened by ``margin``, holds none of the ``obstacles`` and lies
    inside the panel's ``frame``; where none is clear, the one that touches the fewest."""
    best = None
    for anchor in anchors:
        for place in _PLACES:
            _place(text, anchor, place)
            box = text.get_window_extent(renderer)
            outside = box.x0 < frame.x0 or box.x1 > frame.x1 or box.y0 < frame.y0 or box.y1 > frame.y1
            score = (outside, _hits(box, obstacles, margin))
            if score == (False, 0):
                return anchor, place
            if best is None or score < best[0]:
                best = (score, anchor, place)
    assert best is not None, "a label has an anchor"
    return best[1], best[2]


def clear_labels(fig: Figure, labels: list[GuideLabel]) -> None:
    """Move each of ``labels`` (`GuideLabel`) to the first of its anchors and of `_PLACES`
    around it where its box, widened by a marker's radius, holds no point of any other line
    (data, floors, other guides) and lies inside its panel; where none is clear, to the
    place that touches the fewest. The figure is laid out first: the boxes are measured
    where they will be drawn."""
    if not labels:
        return
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]  # the Agg canvas's (files only)
    margin = 6.0 * fig.dpi / 72.0  # half the largest marker of a line (a fitted point's circle)
    for label in labels:
        ax = label.text.axes
        assert ax is not None, "a guide's label is drawn on its panel"
        frame = ax.get_window_extent(renderer)
        anchor, place = _clearest(
            label.text, label.anchors, frame, _obstacles(ax, label.line), renderer, margin
        )
        _place(label.text, anchor, place)


# The accuracy bound on the work-precision figure, and the recommended point on it.
BOUND_STYLE: dict[str, Any] = dict(color="0.15", linestyle="-.", linewidth=1.0, zorder=1)
RECOMMENDED_STYLE: dict[str, Any] = dict(
    linestyle="none",
    marker="*",
    markersize=16,
    markerfacecolor="gold",
    markeredgecolor="k",
    markeredgewidth=0.8,
    zorder=10,
)


def bound_label(bound: float) -> str:
    """The legend entry of the accuracy bound's line on the final-error axis."""
    return f"accuracy bound {bound:g} rad (judged on the error at every sample)"


@dataclass(frozen=True)
class RecommendedPoint:
    """The study's answer as the findings give it (its first recommendation): ``scheme`` at
    ``dt``, over the ``cases`` (coordinate -> value mappings; an axis not named: every
    value), and the legend's ``label``."""

    scheme: str
    dt: float
    cases: Sequence[Mapping[str, Any]]
    label: str

    def covers(self, pick: Mapping[str, Any]) -> bool:
        """Whether a panel of the other axes' values ``pick`` shows a case of the answer."""
        return any(all(case.get(d, v) == v for d, v in pick.items()) for case in self.cases)


def recommended_point(ds: xr.Dataset) -> RecommendedPoint | None:
    """The `RecommendedPoint` of ``ds``: the first recommendation of
    `rbstudy.analysis.findings.findings` (the study-wide pick where there is one), or None."""
    found = next((f for f in findings(ds) if f.kind == "recommendation"), None)
    if found is None:
        return None
    first = found.cases[0]
    scheme, dt = str(first["scheme"]), float(first["dt"])
    where = "" if len(found.cases) == 1 and set(first) <= {"scheme", "dt"} else " (where the findings say)"
    return RecommendedPoint(scheme, dt, found.cases, _answer_label(scheme, dt, found) + where)


def _answer_label(scheme, dt, found):
    """``recommended: rk4 at dt = 0.01 s``; the candidates of equal cost the finding names
    with it (``numbers["equal_cost"]``) named too, as the finding does: the star marks the
    one that represents them."""
    tied = found.numbers.get("equal_cost", [])
    if not tied:
        return f"recommended: {scheme} at dt = {dt:g} s"
    if all(other["dt_s"] == dt for other in tied):
        names = [scheme, *(other["scheme"] for other in tied)]
        return f"recommended: {', '.join(names[:-1])} or {names[-1]}, equal cost, at dt = {dt:g} s"
    others = ", ".join(f"{other['scheme']} at dt = {other['dt_s']:g} s" for other in tied)
    return f"recommended: {scheme} at dt = {dt:g} s (equal cost: {others})"
