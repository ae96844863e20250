"""The convergence figures: error against dt, log-log, one figure per error measure.

A line per scheme (`rbstudy.analysis.figure_lines.figure_layout`) with its fitted order and
the slope of its finest fitted pair in the legend (`rbstudy.analysis.convergence_legend`),
the fitted points circled, slope guides placed clear of the data
(`rbstudy.analysis.slope_guides`), the reference's uncertainty below which no order is
fitted, and exact zeros on a floor line. Drawn only when at least one line has an
asymptotic range; else left out with why.
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

# `figure_frame.save` is looked up when a figure is written, so that a test may keep the
# figures instead (tests/test_figures.py's drawn_figures)
from rbstudy.analysis import figure_frame
from rbstudy.analysis.convergence_legend import FittedLine, fit_label, fit_text, value_fits, values_label
from rbstudy.analysis.figure_frame import (
    FORMATS,
    LEGEND_WIDTH,
    RC,
    Figures,
    figure_legend,
    grid,
    log_labels,
)
from rbstudy.analysis.figure_lines import (
    LineStyle,
    draw_band,
    figure_layout,
    group_styles,
    line_styles,
    lines_of,
    missing_text,
)
from rbstudy.analysis.figure_marks import (
    ZERO_LABEL,
    Band,
    GuideLabel,
    band,
    clear_labels,
    mark_floor,
    on_floor,
    plot_with_zeros,
    zero_entry,
    zero_floor,
)
from rbstudy.analysis.figure_text import aside, overlap_title, panel_title, title, value_text
from rbstudy.analysis.overlaps import coincident, panel_overlaps, together
from rbstudy.analysis.slope_guides import guide_orders, reference_slopes
from rbstudy.analysis.summary import (
    ERROR_MEASURES,
    FLOOR_FACTOR,
    UNCERTAINTY_FACTOR,
    error_measure,
    fitted_order,
    round_off_of,
    schemes_of,
    uncertainty_of,
)
from rbstudy.numerics.state import OK
from rbstudy.physics.analytic import REFERENCE_KINDS
from rbstudy.physics.metrics import OrderFit

__all__ = ["convergence", "unreferenced"]

_NO_REFERENCE = REFERENCE_KINDS.index("none")


def unreferenced(ds: xr.Dataset) -> np.ndarray:
    """Per case: it had no reference (its DOP853 reference passed its step budget), so its
    errors against a reference are NaN without having failed."""
    if "reference" not in ds:
        return np.zeros(1, dtype=bool)
    return ds["reference"].values == _NO_REFERENCE


def _at(da: xr.DataArray, facet: str | None, value: Any) -> xr.DataArray:
    """``da`` in the panel at ``value`` of the axis ``facet`` (all of it with no facet)."""
    return da.sel({facet: value}) if facet else da


@dataclass(frozen=True)
class _Panels:
    """What a convergence figure of the measure ``key`` shows, per panel shown (at the
    ``values`` of the axis ``facet``): the worst error of each point (``worst``), its `Band`
    over the ``reduced`` axes (``bands``), `UNCERTAINTY_FACTOR` times the reference's
    uncertainty (``limits``), `FLOOR_FACTOR` times the largest float64 floor of its cases
    (``float64``, NaN where none), the lines with their orders (``fits``) and, where axes are
    reduced, the orders fitted value by value (``value_fits``); ``behind``: the cases behind
    each point; ``unreferenced``: the facet's values not shown, none of whose cases has a
    reference."""

    key: str
    dts: np.ndarray
    line_dim: str | None
    facet: str | None
    reduced: list[str]
    values: list[Any]
    unreferenced: list[Any]
    worst: list[xr.DataArray]
    limits: list[xr.DataArray]
    float64: list[float]
    bands: list[Band]
    fits: list[list[FittedLine]]
    value_fits: list[list[list[tuple[OrderFit, str | None]]]]
    behind: int


def _uncertainty_limit(uncertainty, facet, value, reduced, like):
    """`UNCERTAINTY_FACTOR` times the reference's uncertainty of a panel's points, the
    largest over the ``reduced`` dims (cases whose reference is exact do not count), like
    the panel ``like``: NaN where no case's reference is uncertain."""
    if uncertainty is None:
        return like.copy(data=np.full(like.shape, np.nan))
    picked = _at(uncertainty, facet, value)
    return UNCERTAINTY_FACTOR * (picked.max(reduced, skipna=True) if reduced else picked)


def _float64_floor(ds, key, measure, facet, value):
    """`FLOOR_FACTOR` times the largest float64 floor of a panel's cases (at ``value`` of
    ``facet``), for a measure it bounds (`ErrorMeasure.conditioned`); NaN where none."""
    if not ERROR_MEASURES[key].conditioned or "float64_floor" not in ds:
        return np.nan
    floors = _at(ds["float64_floor"].broadcast_like(measure), facet, value).values
    return FLOOR_FACTOR * float(np.nanmax(floors)) if np.isfinite(floors).any() else np.nan


def _fitted_lines(dts, key, line_dim, worst, failed, limits, floors):
    """The `FittedLine` of each line of a panel: its ``worst`` errors, whether a case
    ``failed``, its ``limits`` and the measure's ``floors``, and the order fitted through them."""
    return [
        FittedLine(
            line.label,
            line.key,
            line.data.values,
            fitted_order(dts, line.data.values, key, limit.data.values, floor.data.values),
            bool(failure.data.values.any()),
            limit.data.values,
            floor.data.values,
            ERROR_MEASURES[key].floor_kind,
        )
        for line, failure, limit, floor in zip(
            lines_of(worst, line_dim),
            lines_of(failed, line_dim),
            lines_of(limits, line_dim),
            lines_of(floors, line_dim),
            strict=True,
        )
    ]


def _panels(ds: xr.Dataset, key: str, measure: xr.DataArray) -> _Panels:
    """The `_Panels` of the convergence figure of measure ``key`` (``measure``, its values)."""
    dts = ds["dt"].values
    line_dim, facet, reduced = figure_layout(ds)
    values = list(ds[facet].values) if facet else [None]
    bands = [band(_at(measure, facet, value), reduced) for value in values]
    worst = [panel.worst for panel in bands]
    uncertainty = uncertainty_of(ds, key, measure)
    limits = [
        _uncertainty_limit(uncertainty, facet, value, reduced, panel)
        for value, panel in zip(values, worst, strict=True)
    ]
    # the round-off floor of the worst case is the largest of the panel's (`round_off_of`)
    round_off = round_off_of(ds, key, measure)
    round_offs = [band(_at(round_off, facet, value), reduced).worst for value in values]
    failures = [band(_at(ds["status"] != OK, facet, value), reduced).worst for value in values]
    # a panel whose every case finished without a reference has nothing to show
    shown = [
        k
        for k, (panel, failed) in enumerate(zip(worst, failures, strict=True))
        if np.isfinite(panel.values).any() or failed.values.any()
    ] or list(range(len(values)))
    left_out = [values[k] for k in range(len(values)) if k not in shown]
    values, bands = [values[k] for k in shown], [bands[k] for k in shown]
    worst, failures = [worst[k] for k in shown], [failures[k] for k in shown]
    limits, round_offs = [limits[k] for k in shown], [round_offs[k] for k in shown]
    float64 = [_float64_floor(ds, key, measure, facet, value) for value in values]
    return _Panels(
        key=key,
        dts=dts,
        line_dim=line_dim,
        facet=facet,
        reduced=reduced,
        values=values,
        unreferenced=left_out,
        worst=worst,
        limits=limits,
        float64=float64,
        bands=bands,
        fits=[
            _fitted_lines(dts, key, line_dim, *panel)
            for panel in zip(worst, failures, limits, round_offs, strict=True)
        ],
        # where a line stands for many cases, an order is fitted at each value of the reduced
        # axes (the table's fits), never through the worst case's envelope
        value_fits=[
            value_fits(
                dts,
                _at(measure, facet, value),
                uncertainty,
                _at(round_off, facet, value),
                facet,
                value,
                line_dim,
                reduced,
                key,
            )
            for value in values
        ],
        behind=int(np.prod([ds.sizes[d] for d in reduced])),  # cases behind each point
    )


def _has_order(panels: _Panels) -> bool:
    """Whether some line of the figure has an asymptotic range (value by value, where axes
    are reduced)."""
    if panels.reduced:
        fits = (fit for panel in panels.value_fits for line in panel for fit, _ in line)
    else:
        fits = (line.fit for panel in panels.fits for line in panel)
    return any(np.isfinite(fit.order) for fit in fits)


def _why_no_order(ds: xr.Dataset, label: str) -> str:
    """Why the figure of the measure named ``label`` is left out: no line has an order."""
    if unreferenced(ds).all():
        return f"no case has a reference to measure the {label} against (reference = none)"
    return (
        f"no line shows an asymptotic range of the {label} (every line failed, "
        "stalled, or was exact or at the round-off floor at every dt)"
    )


def _draw_panel(
    ds: xr.Dataset,
    fig: Figure,
    ax: Axes,
    panels: _Panels,
    k: int,
    groups: list[list[int]],
    drawn: dict[int, dict[str, Any]],
    handles: dict[int, Line2D],
) -> tuple[float | None, list[GuideLabel]]:
    """Draw the panel ``k`` of ``panels`` on ``ax``, its lines in their ``drawn`` styles (the
    first drawing of each kept in ``handles`` for the legend); returns its floor line (None:
    no zero) and the labels of its slope guides."""
    spec = ERROR_MEASURES[panels.key]
    dts, lines, value = panels.dts, panels.fits[k], panels.values[k]
    ax.set_xscale("log")
    ax.set_yscale("log")
    floor = zero_floor(panels.worst[k].values)
    least = lines_of(panels.bands[k].best, panels.line_dim)
    for j, (line, best) in enumerate(zip(lines, least, strict=True)):
        errors, fit, style = line.errors, line.fit, drawn[j]
        handles.setdefault(j, plot_with_zeros(ax, dts, errors, floor, None, style))
        if panels.reduced:
            draw_band(ax, dts, best.data.values, errors, floor, style)
        ax.plot(
            dts[fit.used],
            errors[fit.used],
            linestyle="none",
            marker="o",
            markersize=11,
            markerfacecolor="none",
            markeredgewidth=0.8,
            color=style["color"],
            zorder=1,
        )
    labels = reference_slopes(
        ax, dts, np.array([line.errors for line in lines]), guide_orders(ds, panels.facet, value)
    )
    _mark_uncertainty(ax, panels.limits[k].values)
    _mark_float64(ax, panels.float64[k], np.array([line.errors for line in lines]))
    mark_floor(ax, floor)
    ax.set_xlabel("time step dt (s)")
    ax.set_ylabel(f"{spec.label} ({spec.units})")
    # lines that coincide in this panel only: the legend cannot name them
    here = panel_overlaps(
        [panels.fits[0][j].label for j in range(len(lines))],
        [line.errors for line in lines],
        groups,
        spec.floor,
        ax,
        [(dts, on_floor(line.errors, floor)) for line in lines],
    )
    ax.set_title(overlap_title(ax, fig, panel_title(panels.facet, value, panels.reduced), here))
    ax.grid(True, which="major", alpha=0.3)
    return floor, labels


def _mark_float64(ax, level, errors):
    """A dotted line at ``level`` (`FLOOR_FACTOR` times the float64 floor), below which no
    order is fitted, where some of the panel's ``errors`` come within ten times of it (a
    floor far below them would only stretch the axis)."""
    finite = errors[np.isfinite(errors) & (errors > 0.0)]
    if np.isfinite(level) and finite.size and finite.min() <= 10.0 * level:
        _level_line(ax, level, ":", f"{FLOOR_FACTOR:g} x float64 floor: not fitted below")


def _mark_uncertainty(ax, limits):
    """A dashed line at the largest of a panel's ``limits``, below which no order is fitted
    (nothing when no reference of the panel is uncertain)."""
    finite = limits[np.isfinite(limits)]
    if finite.size:
        _level_line(
            ax, finite.max(), "--", f"{UNCERTAINTY_FACTOR:g} x reference uncertainty: not fitted below"
        )


def _level_line(ax, level, linestyle, text):
    """A grey horizontal line at ``level``, ``text`` on it at the right."""
    ax.axhline(level, color="0.35", linewidth=0.8, linestyle=linestyle, zorder=1)
    ax.annotate(
        text,
        (0.99, level),
        xycoords=("axes fraction", "data"),
        xytext=(0, 3),
        textcoords="offset points",
        fontsize=7,
        color="0.3",
        ha="right",
    )


def _legend_label(panels: _Panels, group: list[int], name: str) -> str:
    """The legend entry of the lines ``group`` named together as ``name``: their fitted
    orders over the panels, or value by value where axes are reduced."""
    first = group[0]
    if panels.reduced:
        fits, kind = [lines[first] for lines in panels.value_fits], ERROR_MEASURES[panels.key].floor_kind
        missing = missing_text(panels.bands, panels.line_dim, first, panels.behind)
        return values_label(name, fits, panels.reduced, kind) + aside(missing, "; {}")
    return fit_label(
        name,
        [fit_text(lines[first]) for lines in panels.fits],
        [lines[first].fit for lines in panels.fits],
    )


def _what(ds: xr.Dataset, panels: _Panels, floors: list[float | None]) -> str:
    """What the figure shows, under the study's title: the measure, the circles, what its
    gaps are, its floor line where a panel has one, and the panels left out."""
    zeros = f"; on the dotted floor: {ZERO_LABEL}" if any(f is not None for f in floors) else ""
    unjudged_gap = any(
        not line.failed and not np.isfinite(line.errors).all() for panel in panels.fits for line in panel
    )
    gaps = (
        "failed cases, or cases without a reference"
        if unjudged_gap and unreferenced(ds).any()
        else "failed cases"
    )
    left_out = (
        "; not shown, without a reference: "
        + ", ".join(value_text(str(panels.facet), v) for v in panels.unreferenced)
        if panels.unreferenced
        else ""
    )
    return (
        f"convergence: {ERROR_MEASURES[panels.key].label}; large circles: the fitted asymptotic range; "
        f"gaps: {gaps}{zeros}{left_out}"
    )


def _draw(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str],
    panels: _Panels,
    measure: xr.DataArray,
    schemes: Mapping[str, LineStyle],
) -> pathlib.Path:
    """Draw and write the figure of ``panels`` (``measure``, the errors of every case);
    returns its first file."""
    spec = ERROR_MEASURES[panels.key]
    floor_name = "round-off" if spec.floor_kind == "round-off" else f"the {spec.floor_kind} floor"
    # the lines are the same in every panel: those that coincide in every case (as
    # `coinciding_lines` tells the caption, below the measure's constant floor) are drawn on
    # top of each other in turn and named together
    rows = [line.data.values.ravel() for line in lines_of(measure, panels.line_dim)]
    groups = coincident(rows, spec.floor)
    line_names = [line.label for line in panels.fits[0]]
    names = {
        group[0]: together([line_names[j] for j in group], [rows[j] for j in group], spec.floor, floor_name)
        for group in groups
    }
    drawn = group_styles(groups, [line.key for line in panels.fits[0]], schemes)
    with plt.rc_context(RC):
        fig, axes = grid(len(panels.values), width=5.0, legend_width=LEGEND_WIDTH)
        floors: list[float | None] = []
        handles: dict[int, Line2D] = {}
        labels: list[GuideLabel] = []
        for k, ax in enumerate(axes):
            panel_floor, guides = _draw_panel(ds, fig, ax, panels, k, groups, drawn, handles)
            floors.append(panel_floor)
            labels += guides
        entries = [
            ([handles[j] for j in group], _legend_label(panels, group, names[group[0]])) for group in groups
        ]
        figure_legend(fig, entries + zero_entry(fig), LEGEND_WIDTH)
        title(fig, ds, _what(ds, panels, floors))
        log_labels(fig)  # the ticks as saved: the layout the labels are placed in
        clear_labels(fig, labels)
        return figure_frame.save(fig, folder, ds, f"convergence_{panels.key}", formats)


def convergence(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str] = FORMATS,
    measures: Collection[str] | None = None,
    styles: Mapping[str, Sequence[str]] | None = None,
) -> Figures:
    """Error against dt per measure (``measures``: keys of `ERROR_MEASURES`, default all),
    fitted order per line in the legend; ``styles``: the schemes' registered styles
    (`rbstudy.analysis.figure_lines.line_styles`)."""
    figures = Figures()
    schemes = line_styles(schemes_of(ds), styles)
    if "dt" not in ds.dims:
        return figures
    for key, spec in ERROR_MEASURES.items():
        if measures is not None and key not in measures:
            continue
        measure = error_measure(ds, key)
        if measure is None:
            continue  # not stored: not a figure this study could have
        panels = _panels(ds, key, measure)
        if not _has_order(panels):
            figures.absent[f"convergence_{key}"] = _why_no_order(ds, spec.label)
            continue
        figures.written.append(_draw(ds, folder, formats, panels, measure, schemes))
    return figures
