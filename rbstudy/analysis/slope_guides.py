"""The slope guides of a convergence panel: a dotted line per order (1, 2, 4 and the
nominal orders of the panel's schemes), each placed where it crosses no line of the data and
no other guide, its label ("order n") moved clear of the data once the figure is laid out
(`rbstudy.analysis.figure_marks.clear_labels`).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
import xarray as xr
from matplotlib.axes import Axes

from rbstudy.analysis.figure_marks import GuideLabel

__all__ = ["REFERENCE_ORDERS", "guide_orders", "reference_slopes"]

REFERENCE_ORDERS = (1, 2, 4)
# A slope guide spans three consecutive steps (a factor 4 when dt is halved), two where
# three do not fit the errors' range; it keeps this many decades clear of every line, and
# its place is searched on a grid of this many decades.
GUIDE_STEPS = 3
GUIDE_CLEARANCE = 0.5
GUIDE_GRID = 0.125


def guide_orders(ds: xr.Dataset, facet: str | None, value: Any) -> tuple[int, ...]:
    """`REFERENCE_ORDERS` and the nominal orders of a panel's schemes (a composition's 6, 8):
    the panel of ``ds`` at ``value`` of the axis ``facet`` (None: the one panel)."""
    if "nominal_order" not in ds.coords:
        return REFERENCE_ORDERS
    nominal = ds["nominal_order"]
    if facet in nominal.dims:
        nominal = nominal.sel({facet: value})
    return tuple(sorted(set(REFERENCE_ORDERS) | {int(o) for o in np.ravel(nominal.values)}))


def _conflicts(guides, obstacles):
    """Per guide (rows of log10 values over some steps), how many ``obstacles`` (rows of
    log10 values over the same steps, NaN where not drawn) it crosses or passes within
    `GUIDE_CLEARANCE` decades of. Both are straight between the steps on log axes, so a row
    that stays on one side at every step stays on it in between."""
    gaps = obstacles[None, :, :] - guides[:, None, :]
    near = np.abs(gaps) < GUIDE_CLEARANCE
    crossed = (gaps > 0).any(axis=2) & (gaps < 0).any(axis=2)
    return np.sum(near.any(axis=2) | crossed, axis=1)


def reference_slopes(
    ax: Axes, dts: np.ndarray, errors: np.ndarray, orders: Iterable[int]
) -> list[GuideLabel]:
    """A dotted guide per order in ``orders``, each over `GUIDE_STEPS` consecutive steps
    placed where it crosses no line of ``errors`` (lines x steps) and no other guide, within
    the errors' range (a guide never stretches the axis): of the places that cross fewest,
    the longest, at the largest steps, nearest the errors' middle. Returns the labels
    ("order n") to place clear of the data once the figure is laid out
    (`rbstudy.analysis.figure_marks.clear_labels`)."""
    labels: list[GuideLabel] = []
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.log10(np.where(errors > 0, errors, np.nan))
    if not np.isfinite(logs).any():
        return labels
    order_of_steps = np.argsort(dts)
    x, logs = np.log10(dts[order_of_steps]), logs[:, order_of_steps]
    low, high = np.nanmin(logs), np.nanmax(logs)
    middle = np.nanmedian(logs)
    anchors = np.arange(low, high + GUIDE_GRID / 2, GUIDE_GRID)  # a guide's largest value
    for order in sorted(orders, reverse=True):  # the steepest, hardest to place, first
        best = None
        for steps in range(min(GUIDE_STEPS, x.size), 1, -1):
            for start in range(x.size - steps, -1, -1):
                span = slice(start, start + steps)
                guides = anchors[:, None] + order * (x[span] - x[span][-1])[None, :]
                inside_range = guides.min(axis=1) >= low
                if not inside_range.any():
                    continue
                guides = guides[inside_range]
                conflicts = _conflicts(guides, logs[:, span])
                distances = np.abs(guides.mean(axis=1) - middle)
                pick = np.lexsort((distances, conflicts))[0]
                score = (conflicts[pick], -steps, x.size - start, distances[pick])
                if best is None or score < best[0]:
                    best = (score, span, guides[pick])
        if best is None:
            continue
        _, span, guide = best
        row = np.full(x.size, np.nan)
        row[span] = guide
        logs = np.vstack([logs, row])  # the next guide keeps clear of this one
        shown_dts, shown = 10.0 ** x[span], 10.0**guide
        (line,) = ax.plot(shown_dts, shown, color="0.6", linestyle=":", linewidth=1, zorder=1)
        # named at its middle, else at one of its steps: wherever its box is clear of the data
        centre = (10.0 ** x[span].mean(), 10.0 ** guide.mean())
        text = ax.annotate(
            f"order {order}",
            centre,
            xytext=(0, 2),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=7,
            color="0.4",
        )
        labels.append(GuideLabel(text, line, [centre, *zip(shown_dts, shown, strict=True)]))
    return labels
