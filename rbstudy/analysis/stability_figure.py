"""The stability map: every case marked accurate, finished but inaccurate, or failed, by its
``dt |w0|``.

A strip chart (a row per scheme) when each scheme's cases lie along one axis, else a panel
per scheme with a boundary against the swept parameter, the largest accurate value joined (a
named parameter, such as a Radioss option, one column per name); the OpenRadioss limit
``dt |w| = 1`` where some case passed it. Not drawn when every case is accurate.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any, NamedTuple

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure

# `figure_frame.save` is looked up when a figure is written, so that a test may keep the
# figures instead (tests/test_figures.py's drawn_figures)
from rbstudy.analysis import figure_frame
from rbstudy.analysis.figure_frame import FORMATS, RC, Figures, grid
from rbstudy.analysis.figure_lines import case_dims
from rbstudy.analysis.figure_text import title
from rbstudy.analysis.summary import per_scheme, schemes_of, step_load, verdicts
from rbstudy.numerics.state import OK, RADIOSS_STEP_ANGLE, STATUSES

__all__ = ["stability_map"]

# Inches per scheme row of the stability strip chart.
STRIP_ROW_HEIGHT = 0.32
# A swept parameter spanning more than this ratio gets a log axis in the stability map.
LOG_AXIS_RATIO = 50


class _Parameter(NamedTuple):
    """The swept parameter of the map's x axis: its coordinate ``name``, its ``values`` per
    case and its axis ``label`` (with units)."""

    name: str
    values: xr.DataArray
    label: str


def _parameter(ds: xr.Dataset) -> _Parameter | None:
    """The swept parameter of the stability map's x axis, or None. A zipped dimension shows
    its first axis."""
    others = [d for d in case_dims(ds) if d not in ("scheme", "dt")]
    if not others:
        return None
    dim = others[0]
    auxiliary = [name for name, c in ds.coords.items() if c.dims == (dim,) and name != dim]
    name = str(auxiliary[0] if auxiliary else dim)
    units = ds[name].attrs.get("units")
    label = f"{name} ({units})" if units and units != "1" else name
    return _Parameter(name, ds[name].broadcast_like(ds["status"]), label)


def _verdict_kinds(ds):
    """(label, scatter keywords) of accurate, inaccurate, failed and unjudged cases, in the
    order of `verdicts`' masks."""
    bound = ds.attrs.get("accuracy_bound")
    return (
        ("accurate", dict(s=14, color="tab:green")),
        (
            "finished, inaccurate" + (f" (error or drift > {bound:g})" if bound is not None else ""),
            dict(s=22, marker="^", color="tab:orange"),
        ),
        (
            f"failed ({' or '.join(status.name.replace('_', ' ') for status in STATUSES[OK + 1 :])})",
            dict(s=22, marker="x", color="tab:red"),
        ),
        (
            "finished, no reference (unjudged)",
            dict(s=22, marker="s", facecolors="none", edgecolors="tab:gray"),
        ),
    )


def _is_strip(ds, load):
    """Whether the stability map is a strip chart: each scheme's cases lie along one axis
    (dt or one parameter), or none, with a dt |w0| of their own, which orders them."""
    others = [d for d in case_dims(ds) if d != "scheme"]
    if len(others) > 1:
        return False
    count = ds.sizes[others[0]] if others else 1
    return all(np.unique(per_scheme(load, scheme).values).size == count for scheme in schemes_of(ds))


def _strip_chart(
    ds: xr.Dataset, load: xr.DataArray, judged: dict[str, Any], radioss: bool
) -> tuple[Figure, list[Axes]]:
    """One row per scheme, its cases at their dt |w0|, marked by verdict."""
    schemes = list(judged)
    fig, ax = plt.subplots(figsize=(7.5, 1.2 + STRIP_ROW_HEIGHT * len(schemes)), layout="constrained")
    for row, (scheme, masks) in enumerate(judged.items()):
        x = per_scheme(load, scheme).values.ravel()
        for cases, (label, kind) in zip(masks, _verdict_kinds(ds), strict=True):
            cases = cases.ravel()
            if cases.any():
                ax.scatter(x[cases], np.full(cases.sum(), row), label=label, **kind)
    if radioss:
        ax.axvline(
            RADIOSS_STEP_ANGLE,
            color="0.35",
            linestyle=":",
            linewidth=1,
            label=f"OpenRadioss aborts past dt |w| = {RADIOSS_STEP_ANGLE:g}",
        )
    ax.set_yticks(range(len(schemes)), schemes)
    ax.set_ylim(len(schemes) - 0.5, -0.5)  # the first scheme on top
    ax.set_xscale("log")
    ax.set_xlabel("dt |w0| (rad)")
    ax.grid(True, axis="x", alpha=0.3)
    return fig, [ax]


def _map_panels(
    ds: xr.Dataset, load: xr.DataArray, judged: dict[str, Any], radioss: bool
) -> tuple[Figure, list[Axes]]:
    """One panel per scheme: dt |w0| against the swept parameter, the largest accurate
    value at each of its values joined."""
    parameter = _parameter(ds)
    fig, axes = grid(len(judged), width=3.4, height=2.9, columns=4)
    for ax, (scheme, masks) in zip(axes, judged.items(), strict=True):
        good = masks[0].ravel()
        y = per_scheme(load, scheme).values.ravel()
        if parameter:
            x = per_scheme(parameter.values, scheme).values.ravel()
            ax.set_xlabel(parameter.label)
            named = x.dtype.kind not in "iuf"
            if named:  # names or flags: one column each
                names, x = np.unique(x, return_inverse=True)
                ax.set_xticks(range(len(names)), [str(name) for name in names])
                ax.set_xlim(-0.5, len(names) - 0.5)
            elif np.all(x > 0) and x.max() / x.min() > LOG_AXIS_RATIO:
                ax.set_xscale("log")
        else:
            x = np.zeros(y.size)
            ax.set_xticks([])
        for cases, (label, kind) in zip(masks, _verdict_kinds(ds), strict=True):
            cases = cases.ravel()
            if cases.any():  # the legend lists what occurs, nothing else
                ax.scatter(x[cases], y[cases], label=label, **kind)
        if parameter:
            xs = np.unique(x)
            largest = [y[good & (x == v)].max() if (good & (x == v)).any() else np.nan for v in xs]
            # a bar at each value, so that one accurate value alone still shows; joined
            # only along a numeric axis (names or flags have nothing between them)
            ax.plot(
                xs,
                largest,
                color="tab:green",
                linewidth=0 if named else 1,
                marker="_",
                markersize=12,
                label="largest accurate",
            )
        if radioss:
            ax.axhline(
                RADIOSS_STEP_ANGLE,
                color="0.35",
                linestyle=":",
                linewidth=1,
                label=f"OpenRadioss aborts past dt |w| = {RADIOSS_STEP_ANGLE:g}",
            )
        ax.set_yscale("log")
        ax.set_ylabel("dt |w0| (rad)")
        ax.set_title(scheme)
        ax.grid(True, alpha=0.3)
    return fig, axes


def stability_map(
    ds: xr.Dataset, folder: str | os.PathLike[str], formats: Sequence[str] = FORMATS
) -> Figures:
    """Every case's verdict (accurate, finished but inaccurate, failed) by its ``dt |w0|``:
    a strip chart, a row per scheme, when each scheme's cases lie along one axis; else one
    panel per scheme against the swept parameter. Not drawn when every case is accurate."""
    figures = Figures()
    if "dt" not in ds.coords:
        return figures
    load = step_load(ds)
    judged = {scheme: verdicts(ds, scheme) for scheme in schemes_of(ds)}
    if all(masks[0].all() for masks in judged.values()):
        figures.absent["stability_map"] = (
            f"every case is accurate (dt |w0| up to {float(load.max()):.3g} rad): no "
            "stability or accuracy boundary to show"
        )
        return figures
    # the limit is drawn where some case passed it and it lies among the plotted dt |w0|: a
    # case flagged for the spin it reached later must not stretch a map of small dt |w0|
    radioss = bool((ds["radioss_dt_limit"] == 1).any()) and bool((load >= RADIOSS_STEP_ANGLE).any())
    strip = _is_strip(ds, load)
    what = "stability and accuracy: every case by its dt |w0|"
    if not strip:  # a panel of nothing but accurate cases shows no boundary: named instead
        accurate = [scheme for scheme, masks in judged.items() if masks[0].all()]
        judged = {scheme: masks for scheme, masks in judged.items() if scheme not in accurate}
        what += f"; accurate in every case: {', '.join(accurate)}" if accurate else ""
    with plt.rc_context(RC):
        fig, axes = (_strip_chart if strip else _map_panels)(ds, load, judged, radioss)
        handles = {}
        for ax in axes:  # every category that occurs in some panel, once
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
                handles[label] = handle
        kinds = [label for label, _ in _verdict_kinds(ds)]
        handles = dict(
            sorted(handles.items(), key=lambda item: kinds.index(item[0]) if item[0] in kinds else len(kinds))
        )
        fig.legend(
            list(handles.values()),
            list(handles),
            loc="outside lower center",
            ncols=min(len(handles), 2 if strip else 4),
        )
        title(fig, ds, what)
        figures.written.append(figure_frame.save(fig, folder, ds, "stability_map", formats))
    return figures
