"""The invariant-drift figure: |energy error| and |L - L0| / |L0| against time for one case
per scheme, the case and how it was chosen named once in the title; lines drawn on top of
each other, or within a line's width of each other, named over their panel.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.lines import Line2D

# `figure_frame.save` is looked up when a figure is written, so that a test may keep the
# figures instead (tests/test_figures.py's drawn_figures)
from rbstudy.analysis import figure_frame
from rbstudy.analysis.figure_frame import FORMATS, LEGEND_WIDTH, RC, Figures, figure_legend, grid
from rbstudy.analysis.figure_lines import case_dims, group_styles, line_styles, style_of
from rbstudy.analysis.figure_marks import (
    ZERO_LABEL,
    mark_floor,
    on_floor,
    plot_with_zeros,
    zero_entry,
    zero_floor,
)
from rbstudy.analysis.figure_text import overlap_title, title, value_text
from rbstudy.analysis.overlaps import coincident, near_lines, together
from rbstudy.analysis.summary import ERROR_MEASURES, per_scheme, schemes_of
from rbstudy.numerics.state import OK

__all__ = ["invariant_drift"]


class _DriftCase(NamedTuple):
    """The case of a ``scheme`` the figure shows (``case``, the dataset at it) and its
    ``dt`` (None when dt is not swept)."""

    scheme: str
    case: xr.Dataset
    dt: float | None


# The error measure of each invariant-drift panel's variable: its round-off floor.
_DRIFT_MEASURES = {"energy_error": "energy", "momentum_error": "momentum_vector"}


def _drift_case(ds: xr.Dataset, scheme: str) -> _DriftCase | None:
    """The case of ``scheme`` the drift figure shows: the first value of every axis but dt,
    and the largest dt with a stable case (by value); None when none is stable."""
    case = per_scheme(ds, scheme)
    for dim in [d for d in case_dims(case) if d != "dt"]:
        case = case.isel({dim: 0})
    if "dt" not in case.dims:
        return _DriftCase(scheme, case, float(case["dt"]) if "dt" in case.coords else None)
    stable = case["dt"].values[case["status"].values == OK]
    if stable.size == 0:
        return None
    return _DriftCase(scheme, case.sel(dt=stable.max()), float(stable.max()))


def _drift_title(ds: xr.Dataset, steps: dict[str, float | None]) -> str:
    """Which case the drift figure shows and how it was chosen, once: the first value of
    each other swept axis; the largest stable dt (``steps``: scheme -> dt, or None), named
    here when the schemes share it."""
    others = [d for d in case_dims(ds) if d not in ("scheme", "dt")]
    chosen = [value_text(dim, ds[dim].values[0]) for dim in others]
    how = ["the first value of each swept axis"] if others else []
    dts = set(steps.values()) - {None}
    swept = "dt" in case_dims(ds)
    if len(dts) == 1:
        chosen.append(f"dt = {dts.pop():g} s")
        how += ["the largest dt at which every scheme ran stable"] if swept else []
    elif dts:
        how.append("the largest dt at which each scheme ran stable, in the legend")
    how = how or ["the study's one case per scheme"]
    return f"{', '.join(chosen)} ({'; '.join(how)})" if chosen else "; ".join(how)


def _draw_panel(ax, fig, name, label, values, times, cases, names, schemes):
    """Draw the panel of the variable ``name`` (its axis ``label``): ``values``, one series
    over ``times`` per case of ``cases`` (named ``names``); returns its floor line (None: no
    zero)."""
    ax.set_yscale("log")
    floor = zero_floor(np.concatenate(values))
    round_off = ERROR_MEASURES[_DRIFT_MEASURES[name]].floor
    # lines on top of each other in this panel (hht's and midpoint's zero energy
    # error) drawn in turn, dashed over solid, and named over it
    groups = coincident(values, round_off)
    drawn = group_styles(groups, [case.scheme for case in cases], schemes)
    for group in groups:
        for k in group:
            plot_with_zeros(ax, times, values[k], floor, None, drawn[k], markers=False)
    overlaps = [
        together([names[k] for k in group], [values[k] for k in group], round_off)
        for group in groups
        if len(group) > 1
    ]
    mark_floor(ax, floor)
    overlaps += near_lines(
        ax,
        [names[group[0]] for group in groups],
        [(times, on_floor(values[group[0]], floor)) for group in groups],
    )
    ax.set_title(overlap_title(ax, fig, "", overlaps))
    ax.set_xlabel("time (s)")
    ax.set_ylabel(label)
    ax.grid(True, alpha=0.3)
    return floor


def invariant_drift(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str] = FORMATS,
    styles: Mapping[str, Sequence[str]] | None = None,
) -> Figures:
    """|energy error| and |L - L0| / |L0| against time, one case per scheme; ``styles``: the
    schemes' registered styles (`rbstudy.analysis.figure_lines.line_styles`)."""
    figures = Figures()
    panels = [
        (name, label)
        for name, label in (
            ("energy_error", "|relative energy error|"),
            ("momentum_error", "relative |L - L0| (vector)"),
        )
        if name in ds
    ]
    if not panels:
        return figures
    cases = [case for case in (_drift_case(ds, scheme) for scheme in schemes_of(ds)) if case is not None]
    if not cases:
        figures.absent["invariant_drift"] = "every case failed"
        return figures
    steps = {case.scheme: case.dt for case in cases}
    schemes = line_styles(schemes_of(ds), styles)
    several_dts = len(set(steps.values())) > 1
    times = ds["time"].values[1:]  # at t = 0 every error is zero by definition
    series = [[np.abs(case.case[name].values[1:]) for case in cases] for name, _ in panels]
    names = [f"{case.scheme} (dt = {case.dt:g} s)" if several_dts else case.scheme for case in cases]
    with plt.rc_context(RC):
        reserved = LEGEND_WIDTH / 2
        fig, axes = grid(len(panels), width=5.4, legend_width=reserved)
        floors = [
            _draw_panel(ax, fig, name, label, values, times, cases, names, schemes)
            for ax, (name, label), values in zip(axes, panels, series, strict=True)
        ]
        entries = [
            ([Line2D([], [], **{**style_of(case.scheme, schemes), "marker": ""})], name)
            for case, name in zip(cases, names, strict=True)
        ]
        figure_legend(fig, entries + zero_entry(fig), reserved)
        zeros = f"; on the dotted floor: {ZERO_LABEL}" if any(f is not None for f in floors) else ""
        title(fig, ds, f"invariant drift, bounded or secular; case: {_drift_title(ds, steps)}{zeros}")
        figures.written.append(figure_frame.save(fig, folder, ds, "invariant_drift", formats))
    return figures
