"""The words of a convergence figure's legend: each line's fitted order and the slope of its
finest fitted pair (``rk4 (order 4.00, finest 3.99-4.01)``), or why it has none; for a line
that stands for many cases (a band), the orders fitted value by value.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import xarray as xr

from rbstudy.analysis.figure_lines import lines_of
from rbstudy.analysis.summary import UNCERTAINTY_FACTOR, at_floor, fitted_order, span
from rbstudy.physics.metrics import OrderFit

__all__ = ["FittedLine", "fit_text", "fit_label", "value_fits", "values_label"]


class FittedLine(NamedTuple):
    """A line of a convergence panel: its `rbstudy.analysis.figure_lines.Line` label and
    style key, its ``errors`` (one per dt), the order ``fit`` through them (`fitted_order`),
    whether a case ``failed`` on it, per dt the reference's uncertainty (``limits``) and the
    measure's floor (``floors``), and what sets that floor (``floor_kind``,
    `rbstudy.analysis.measures.ErrorMeasure`)."""

    label: str
    key: str | int
    errors: np.ndarray
    fit: OrderFit
    failed: bool
    limits: np.ndarray
    floors: np.ndarray
    floor_kind: str = "round-off"


def fit_text(line: FittedLine) -> str:
    """``order 4.00, finest 4.01`` in one panel, or why the ``line`` has no order: failed (a
    case of the line did; else it had no reference), exact, at the floor (`at_floor`: too
    few errors above their round-off (an invariant kept), or above their limits,
    `UNCERTAINTY_FACTOR` times the reference's uncertainty), or no asymptotic range."""
    errors, fit = line.errors, line.fit
    finite = errors[np.isfinite(errors)]
    if np.isfinite(fit.order):
        text = f"order {fit.order:.2f}, finest {fit.finest_slope:.2f}"
    elif not finite.size:
        text = "failed at every dt" if line.failed else "no reference at any dt"
    elif np.all(finite == 0.0):
        text = "exact at every dt"
    elif why := at_floor(errors, line.floors, line.limits / UNCERTAINTY_FACTOR):  # in a legend's ( )
        text = (
            f"at the {line.floor_kind} floor"
            if why == "round-off"
            else f"within {UNCERTAINTY_FACTOR:g}x the reference's uncertainty"
        )
    else:
        text = "no asymptotic range"
    return text


def fit_label(name: str, texts: list[str], fits: list[OrderFit]) -> str:
    """The legend entry of a line over a figure's panels (``texts`` and ``fits``, one per
    panel): ``rk4 (order 4.00, finest 3.99-4.01)``, ``in 3 of 4 panels`` where the others
    had none; ``name``: the line's, or the lines' that coincide
    (`rbstudy.analysis.overlaps.together`)."""
    fitted = [fit for fit in fits if np.isfinite(fit.order)]
    if len(set(texts)) == 1:
        text = texts[0]
    elif fitted:
        text = f"order {span([f.order for f in fitted])}, finest {span([f.finest_slope for f in fitted])}"
        if len(fitted) < len(fits):
            text += f" in {len(fitted)} of {len(fits)} panels"
    else:
        text = "; ".join(dict.fromkeys(texts))
    return f"{name} ({text})".strip()


def value_fits(
    dts: np.ndarray,
    measure: xr.DataArray,
    uncertainty: xr.DataArray | None,
    round_off: xr.DataArray,
    facet: str | None,
    value: Any,
    line_dim: str | None,
    reduced: list[str],
    key: str,
) -> list[list[tuple[OrderFit, str | None]]]:
    """Per line of a panel (``measure`` of its cases, ``round_off`` their floors, at
    ``value`` of the axis ``facet``), the `fitted_order` of measure ``key`` at each value of
    the ``reduced`` axes with why it has none (`at_floor`: ``"round-off"``, ``"reference"``
    or None), as pairs; none when no axis is reduced."""
    if not reduced:
        return []
    limits = None
    if uncertainty is not None:
        limits = uncertainty.sel({facet: value}) if facet else uncertainty

    def rows(da, k):  # line k's cases, a row per value of the reduced axes
        return lines_of(da, line_dim)[k].data.stack(value=reduced).transpose("value", "dt").values

    result = []
    for k in range(len(lines_of(measure, line_dim))):
        errors, floors = rows(measure, k), rows(round_off, k)
        bounds = [None] * len(errors) if limits is None else rows(limits, k)
        result.append(
            [
                (fitted_order(dts, row, key, bound, floor), at_floor(row, floor, bound))
                for row, floor, bound in zip(errors, floors, bounds, strict=True)
            ]
        )
    return result


def values_label(
    name: str,
    fits: list[list[tuple[OrderFit, str | None]]],
    reduced: list[str],
    floor_kind: str = "round-off",
) -> str:
    """The legend entry of a line that stands for the values of ``reduced`` axes: its orders
    fitted value by value (``fits``: per panel, a (fit, floor) pair per value, `value_fits`),
    ``rk4 (order 3.98-4.02, finest 3.9-4.1, at 12 of 17 values of inertia_ratio)``, ``... of
    body over 2 panels`` where the figure has several; a line
    whose every value lies at a floor says which (exact_split's round-off; ``floor_kind``, the
    measure's)."""
    every = [pair for panel in fits for pair in panel]
    fitted = [fit for fit, _ in every if np.isfinite(fit.order)]
    # the legend serves every panel: their values are counted together, and said to be
    axes = ", ".join(reduced) + (f" over {len(fits)} panels" if len(fits) > 1 else "")
    where = f"at {len(fitted)} of {len(every)} values of {axes}"
    if not fitted:
        floors = {floor for _, floor in every}
        if floors == {"round-off"}:
            return f"{name} (at the {floor_kind} floor at all {len(every)} values of {axes})"
        return f"{name} (no asymptotic range at any of {len(every)} values of {axes})"
    orders = f"order {span([f.order for f in fitted])}, finest {span([f.finest_slope for f in fitted])}"
    return f"{name} ({orders}, {where})"
