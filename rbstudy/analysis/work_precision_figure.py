"""The work-precision figure: cost per case against the final orientation error, a line per
scheme over dt, with the study's accuracy bound and the findings' recommended point.

The cost is the one the findings rank by (`rbstudy.analysis.findings.case_seconds`: steps
at the scheme's calibrated seconds a step, or an older archive's run time), so that the
star lies where the words put it.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

# `figure_frame.save` is looked up when a figure is written, so that a test may keep the
# figures instead (tests/test_figures.py's drawn_figures)
from rbstudy.analysis import figure_frame
from rbstudy.analysis.figure_frame import FORMATS, LEGEND_WIDTH, RC, Figures, figure_legend, grid
from rbstudy.analysis.figure_lines import figure_layout, group_styles, line_styles, lines_of, missing_text
from rbstudy.analysis.figure_marks import (
    BOUND_STYLE,
    RECOMMENDED_STYLE,
    Band,
    RecommendedPoint,
    band,
    bound_label,
    recommended_point,
)
from rbstudy.analysis.figure_text import aside, overlap_title, panel_title, title
from rbstudy.analysis.findings import calibrated, case_seconds
from rbstudy.analysis.overlaps import coincident, panel_overlaps, together
from rbstudy.analysis.summary import error_measure, schemes_of

__all__ = ["work_precision"]


class _CostLine(NamedTuple):
    """A line of a work-precision panel: its `rbstudy.analysis.figure_lines.Line` label and
    style key, and per dt its worst ``errors`` and dearest ``times`` over the reduced axes."""

    label: str
    key: str | int
    errors: np.ndarray
    times: np.ndarray


@dataclass(frozen=True)
class _CostPanels:
    """What a work-precision figure shows: per panel, the values of the other axes it shows
    (``picks``), the `Band` of its errors over the ``reduced`` axes (``bands``) and its
    lines (``lines``); ``line_dim`` and ``facet`` as `figure_layout` gives them, and
    ``behind`` the cases behind each point."""

    line_dim: str | None
    facet: str | None
    reduced: list[str]
    picks: list[dict[str, Any]]
    bands: list[Band]
    lines: list[list[_CostLine]]
    behind: int


def _cost_panels(ds: xr.Dataset, measure: xr.DataArray) -> _CostPanels:
    """The `_CostPanels` of the final orientation errors ``measure``: a line's points are
    the worst error over the reduced axes and the dearest cost, of the cases that finished
    (`band`)."""
    line_dim, facet, reduced = figure_layout(ds)
    values = list(ds[facet].values) if facet else [None]
    picks = [{facet: value} if facet else {} for value in values]
    bands = [band(measure.sel(pick), reduced) for pick in picks]
    cost = case_seconds(ds)
    lines = [
        [
            _CostLine(line.label, line.key, line.data.values, times.data.values)
            for line, times in zip(
                lines_of(errors_band.worst, line_dim),
                lines_of(band(cost.sel(pick), reduced).worst, line_dim),
                strict=True,
            )
        ]
        for pick, errors_band in zip(picks, bands, strict=True)
    ]
    behind = int(np.prod([ds.sizes[d] for d in reduced]))  # cases behind each point
    return _CostPanels(line_dim, facet, reduced, picks, bands, lines, behind)


def _mark_answer(
    ax: Axes,
    ds: xr.Dataset,
    panels: _CostPanels,
    k: int,
    point: RecommendedPoint,
    extras: dict[str, tuple[Line2D, str]],
) -> None:
    """The star of the recommended ``point`` on the line it lies on in the panel ``k``: its
    scheme's, or in a one-scheme study the line of each value of the answer's cases."""
    pick, line_dim = panels.picks[k], panels.line_dim
    for j, cost_line in enumerate(panels.lines[k]):
        at = pick if line_dim in (None, "scheme") else {**pick, line_dim: ds[line_dim].values[j]}
        if (line_dim == "scheme" and cost_line.label != point.scheme) or not point.covers(at):
            continue
        step = int(np.flatnonzero(ds["dt"].values == point.dt)[0])
        (star,) = ax.plot(cost_line.errors[step], cost_line.times[step], **RECOMMENDED_STYLE)
        extras.setdefault("point", (star, point.label))


def _draw_panel(
    ds: xr.Dataset,
    fig: Figure,
    ax: Axes,
    panels: _CostPanels,
    k: int,
    groups: list[list[int]],
    drawn: dict[int, dict[str, Any]],
    point: RecommendedPoint | None,
    handles: dict[int, Line2D],
    extras: dict[str, tuple[Line2D, str]],
) -> None:
    """Draw the panel ``k`` of ``panels`` on ``ax``, its lines in their ``drawn`` styles, the
    accuracy bound and the recommended ``point`` (kept for the legend: the first drawing of
    each line in ``handles``, the bound's and the point's in ``extras``)."""
    lines = panels.lines[k]
    for j, cost_line in enumerate(lines):
        shown = cost_line.errors > 0  # an exact zero has no place on a log axis: said in the title
        (line,) = ax.loglog(np.where(shown, cost_line.errors, np.nan), cost_line.times, **drawn[j])
        handles.setdefault(j, line)
    bound = ds.attrs.get("accuracy_bound")
    if bound is not None:
        extras.setdefault("bound", (ax.axvline(bound, **BOUND_STYLE), bound_label(bound)))
    if point is not None:
        _mark_answer(ax, ds, panels, k, point, extras)
    ax.set_xlabel("final orientation error (rad)")
    ax.set_ylabel("cost per case (core-seconds)")
    here = panel_overlaps(
        [line.label for line in lines],
        [np.r_[line.errors, line.times] for line in lines],
        groups,
        ax=ax,
        curves=[(line.errors, line.times) for line in lines],  # zeros not drawn
    )
    value = panels.picks[k][panels.facet] if panels.facet else None
    text = panel_title(panels.facet, value, panels.reduced, "the worst error and cost")
    ax.set_title(overlap_title(ax, fig, text, here))
    ax.grid(True, which="major", alpha=0.3)


def _what(ds: xr.Dataset, measure: xr.DataArray) -> str:
    """What the figure shows, under the study's title: which cost, and that exact zeros are
    left out where there are some."""
    zeros = " (exact zeros, which a log axis cannot show, left out)" if (measure == 0).any() else ""
    return (
        "work-precision: cost as the findings rank it, each case's steps at its scheme's "
        "seconds a step, calibrated once on this machine"
        if calibrated(ds)
        else "work-precision: kernel CPU time of each batch divided among its cases, compilation excluded"
    ) + f"; each point a dt{zeros}"


def work_precision(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str] = FORMATS,
    styles: Mapping[str, Sequence[str]] | None = None,
) -> Figures:
    """Cost per case against the final orientation error, a line per scheme over dt, the
    accuracy bound and the study's recommended point (`recommended_point`): the cost the
    findings rank by (`case_seconds`: steps at the scheme's calibrated seconds a step, or an
    older archive's run time), so that the star lies where the words put it;
    ``styles``: the schemes' registered styles
    (`rbstudy.analysis.figure_lines.line_styles`)."""
    figures = Figures()
    schemes = line_styles(schemes_of(ds), styles)
    measure = error_measure(ds, "orientation")
    if measure is None or "dt" not in ds.dims:
        return figures
    if not (measure > 0).any():
        figures.absent["work_precision"] = "no case has a finite, non-zero orientation error"
        return figures
    panels = _cost_panels(ds, measure)
    first = panels.lines[0]
    # lines drawn on top of each other (error and time alike at every point) named together
    groups = coincident(
        [np.concatenate([np.r_[p[j].errors, p[j].times] for p in panels.lines]) for j in range(len(first))]
    )
    drawn = group_styles(groups, [line.key for line in first], schemes)
    point = recommended_point(ds)
    with plt.rc_context(RC):
        reserved = LEGEND_WIDTH / 2
        fig, axes = grid(len(panels.picks), width=5.0, legend_width=reserved)
        handles: dict[int, Line2D] = {}
        extras: dict[str, tuple[Line2D, str]] = {}
        for k, ax in enumerate(axes):
            _draw_panel(ds, fig, ax, panels, k, groups, drawn, point, handles, extras)
        entries = [
            (
                [handles[j] for j in group],
                together([first[j].label for j in group])
                + aside(missing_text(panels.bands, panels.line_dim, group[0], panels.behind), " ({})"),
            )
            for group in (groups if panels.line_dim else [])
        ]
        figure_legend(fig, entries + [([h], text) for h, text in extras.values()], reserved)
        title(fig, ds, _what(ds, measure))
        figures.written.append(figure_frame.save(fig, folder, ds, "work_precision", formats))
    return figures
