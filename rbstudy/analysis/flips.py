"""The findings of a study whose body flips about its intermediate axis (the Dzhanibekov
effect), in words: the exact flip interval and how many flips the run's samples hold, then per
scheme its flip-interval error at its finest step and the order it converges with, and the
flips it lost or added against the exact solution at the same samples.

A flip is a sign change of the intermediate-axis rate between samples (`flip_count`); its
interval the mean time between them, each placed by linear interpolation between its two
samples, so an interval error below the measure's floor (`ERROR_MEASURES["flip"]`) is the
sampling's, not the scheme's: no order is fitted through it, and the words say so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr

from rbstudy.analysis.finding import Finding
from rbstudy.analysis.measures import ERROR_MEASURES, fitted_order
from rbstudy.analysis.places import significant
from rbstudy.analysis.summary import per_scheme, schemes_of
from rbstudy.physics.metrics import MIN_ASYMPTOTIC_POINTS

__all__ = ["FLIP_VARIABLES", "CONDITIONING_VARIABLES", "NEAR_SEPARATRIX", "flip_findings"]

# What the flip findings read, beside the study's coordinates (and, where the archive has
# them, the separatrix distance and the float64 floor: `NEAR_SEPARATRIX`).
FLIP_VARIABLES = ("flip_interval_exact", "flip_interval_error", "flip_count", "flip_count_exact")
CONDITIONING_VARIABLES = ("separatrix_distance", "float64_floor", "initial_spin")
# A body whose k'^2 lies below this is said to be near the separatrix, its conditioning in
# words (`_conditioning`): k'^2 is there a small difference of the spin's squares, and the
# flip interval grows as ln(4 / k').
NEAR_SEPARATRIX = 1e-2


def flip_findings(ds: xr.Dataset) -> tuple[list[Finding], list[Finding]]:
    """The flip findings of ``ds``: the study's (its headline, which the findings put after
    the recommendation) and one per scheme; both empty where no case's body flips (no
    ``flip_interval_exact``, or none finite: a symmetric or loaded body, a spin about a
    principal axis)."""
    if not set(FLIP_VARIABLES) <= set(ds.variables):
        return [], []
    exact = ds["flip_interval_exact"].values
    if not np.isfinite(exact).any():
        return [], []
    schemes = [_scheme_flips(ds, scheme) for scheme in schemes_of(ds)]
    return [_study_flips(ds, schemes)], schemes


def _range_text(values: np.ndarray, digits: int = 4) -> str:
    """``27.51`` or ``5.2-27.51``: the finite ``values``' least and largest."""
    low, high = float(np.nanmin(values)), float(np.nanmax(values))
    low_text, high_text = significant(low, digits), significant(high, digits)
    return low_text if low_text == high_text else f"{low_text}-{high_text}"


def _study_flips(ds: xr.Dataset, schemes: list[Finding]) -> Finding:
    """The exact flip interval of the study's bodies, the flips of the exact motion, and
    which of the ``schemes`` (their findings) lost or added flips."""
    exact, counts = ds["flip_interval_exact"].values, ds["flip_count_exact"].values
    flipping = np.isfinite(exact)
    duration = float(np.max(ds["time"].values)) if "time" in ds.coords else float("nan")
    flips = counts[np.isfinite(counts)]
    text = (
        f"the body flips about its intermediate axis every {_range_text(exact[flipping])} s "
        f"(exact), {_range_text(flips, 6)} times in the {significant(duration)} s run"
    )
    if not flips.size or np.max(flips) == 0:
        text += ": too short for a flip to show"
    else:
        wrong = [f.numbers["scheme"] for f in schemes if f.numbers["lost_cases"] + f.numbers["added_cases"]]
        text += (
            f"; {', '.join(wrong)} lost or added flips (below)"
            if wrong
            else "; every scheme kept every flip in every case that ran to the end"
        )
    numbers = {
        "flip_interval_exact_s": [float(np.nanmin(exact)), float(np.nanmax(exact))],
        "flips_exact": [float(np.min(flips)), float(np.max(flips))] if flips.size else [],
        "duration_s": duration,
    }
    conditioning = _conditioning(ds, duration)
    if conditioning is not None:
        words, numbers["separatrix_distance"], numbers["float64_floor_rad"] = conditioning
        text += words
    return Finding(kind="flip", text=text, numbers=numbers, cases=({},))


def _conditioning(ds: xr.Dataset, duration: float) -> tuple[str, float, float] | None:
    """How ill-conditioned the study's body nearest the separatrix is, in words, with its
    ``k'^2`` and the largest float64 floor: that floor as ulps of the angle the body turns
    (``|w0| T``), which one ulp is for a well-conditioned motion. None where no body lies
    within `NEAR_SEPARATRIX` (or the archive has not the distance)."""
    if "separatrix_distance" not in ds:
        return None
    distance = ds["separatrix_distance"].values
    if not np.isfinite(distance).any() or np.nanmin(distance) >= NEAR_SEPARATRIX:
        return None
    nearest = float(np.nanmin(distance))
    floor = float(np.nanmax(ds["float64_floor"].values)) if "float64_floor" in ds else float("nan")
    words = (
        f"; near the separatrix (k'^2 = {significant(nearest, 2)}), where the flip interval grows as ln(4/k')"
    )
    if np.isfinite(floor) and "initial_spin" in ds:
        turned = float(np.nanmax(ds["initial_spin"].values)) * duration
        ulps = floor / (np.finfo(float).eps * turned)
        words += (
            f": one ulp of the initial state moves the orientation at {significant(duration)} s by "
            f"{significant(floor, 2)} rad ({significant(ulps, 2)} ulps of the "
            f"{significant(turned, 3)} rad turned)"
        )
    return words, nearest, floor


def _interval_errors(ds: xr.Dataset, scheme: str) -> tuple[np.ndarray, np.ndarray]:
    """The swept steps (or the one step) and, per step, the largest ``|flip interval error|``
    over the scheme's other cases (NaN where every case failed or none flipped twice)."""
    errors = abs(per_scheme(ds["flip_interval_error"], scheme))
    if "dt" in errors.dims:
        others = [d for d in errors.dims if d != "dt"]
        worst = errors.max(others, skipna=True) if others else errors
        return ds["dt"].values, worst.values
    return np.atleast_1d(ds["dt"].values), np.atleast_1d(errors.max(skipna=True).values)


def _order_text(dts: np.ndarray, worst: np.ndarray) -> tuple[str, float | None]:
    """Words for the order the interval errors converge with over ``dts``, and the order."""
    spec = ERROR_MEASURES["flip"]
    finite = worst[np.isfinite(worst)]
    if dts.size < 2 or not finite.size:
        return "", None
    if np.all(finite <= spec.floor):
        return f", at the sampling floor ({significant(spec.floor, 2)} s) at every dt", None
    if finite.size < MIN_ASYMPTOTIC_POINTS:
        return f", too few steps ran to the end for an order ({finite.size} of {dts.size})", None
    fit = fitted_order(dts, worst, "flip")
    if np.isfinite(fit.order):
        return f", order {fit.order:.2f}", float(fit.order)
    return ", no asymptotic range", None


def _count_text(ds: xr.Dataset, scheme: str) -> tuple[str, dict[str, int]]:
    """Words for the flips the scheme lost or added against the exact solution at the same
    samples, over its cases, and the case counts."""
    run = per_scheme(ds["flip_count"], scheme).values.ravel()
    exact = per_scheme(ds["flip_count_exact"].broadcast_like(ds["flip_count"]), scheme).values.ravel()
    measured = np.isfinite(run) & np.isfinite(exact)
    lost, added = measured & (run < exact), measured & (run > exact)
    counts = {"cases": int(measured.sum()), "lost": int(lost.sum()), "added": int(added.sum())}
    if not measured.any():
        return "no case ran to the end", counts
    finished = _cases(counts["cases"], run.size)
    if not lost.any() and not added.any():
        return f"every flip kept in {finished}", counts
    parts = []
    for name, where in (("lost", lost), ("added", added)):
        if where.any():
            worst = int(np.max(np.abs(run[where] - exact[where])))
            parts.append(f"{name} flips in {where.sum()} of {finished} (up to {worst} a case)")
    return "; ".join(parts), counts


def _cases(measured: int, total: int) -> str:
    """``all 4 cases``, ``its one case``, or ``the 3 of 4 cases that ran to the end``."""
    if measured < total:
        return f"the {measured} of {total} cases that ran to the end"
    return "its one case" if total == 1 else f"all {total} cases"


def _scheme_flips(ds: xr.Dataset, scheme: str) -> Finding:
    """One scheme's flips: its interval error at its finest step, their order, the flips it
    lost or added."""
    dts, worst = _interval_errors(ds, scheme)
    finest = np.flatnonzero(np.isfinite(worst))
    numbers: dict[str, Any] = {"scheme": scheme}
    if finest.size:
        k = finest[np.argmin(dts[finest])]
        order_words, order = _order_text(dts, worst)
        text = (
            f"{scheme}: flip interval off by up to {significant(float(worst[k]), 2)} s at "
            f"dt = {significant(float(dts[k]))}{order_words}"
        )
        numbers |= {"flip_interval_error_s": float(worst[k]), "dt": float(dts[k]), "order": order}
    else:
        text = f"{scheme}: no flip interval measured (its runs failed or flipped fewer than twice)"
    count_words, counts = _count_text(ds, scheme)
    numbers |= {f"{name}_cases": value for name, value in counts.items()}
    return Finding(kind="flip", text=f"{text}; {count_words}", numbers=numbers, cases=({"scheme": scheme},))
