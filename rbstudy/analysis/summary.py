"""The per-scheme summary of a study, read from its dataset (never from a rerun).

For each scheme, `scheme_rows` gives the observed order of the final orientation error over
the swept ``dt`` (fitted per value of every other swept axis, only where the error is neither
at round-off nor too large to be asymptotic: `rbstudy.analysis.measures`), the errors at the
largest and smallest ``dt``, the kernel time per body-step, the stable range in
``dt |w0|``, and which invariants every stable case kept. Everything comes from the archive
(the nominal order from its ``nominal_order`` coordinate): nothing here needs the scheme
registry or a compiler.

The table of those rows is defined once and rendered in every form by
`rbstudy.analysis.table`; the error measures are `rbstudy.analysis.measures`'. This module
also gives their names, so that a reader of the summary finds them in one place.
"""

from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from typing import Any, NamedTuple, TypeVar

import numpy as np
import xarray as xr

from rbstudy.analysis.measures import (
    ERROR_MEASURES,
    FLOOR_FACTOR,
    KEPT_TOLERANCE,
    ROUND_OFF_ULPS,
    UNCERTAINTY_FACTOR,
    ErrorMeasure,
    at_floor,
    error_measure,
    fitted_order,
    round_off_of,
    uncertainty_of,
)
from rbstudy.analysis.table import (
    FLOOR_WORDS,
    NONE,
    TABLE_FORMATS,
    TERMINAL_WIDTH,
    Column,
    Row,
    floor_reason,
    format_table,
    order_text,
    span,
    table_columns,
    table_notes,
    wrap_clauses,
)
from rbstudy.archive.variables import ACCURATE, INACCURATE, UNJUDGED
from rbstudy.errors import counted
from rbstudy.numerics.state import INVARIANTS, OK, STATUSES
from rbstudy.physics.metrics import OrderFit

# A dataset or one of its variables: what `per_scheme` takes, it gives back.
XarrayT = TypeVar("XarrayT", xr.Dataset, xr.DataArray)

__all__ = [
    "ERROR_MEASURES",
    "ErrorMeasure",
    "SUMMARY_VARIABLES",
    "KEPT_TOLERANCE",
    "TERMINAL_WIDTH",
    "status_counts",
    "status_text",
    "TABLE_FORMATS",
    "error_measure",
    "fitted_order",
    "uncertainty_of",
    "round_off_of",
    "at_floor",
    "UNCERTAINTY_FACTOR",
    "FLOOR_FACTOR",
    "ROUND_OFF_ULPS",
    "Verdicts",
    "verdicts",
    "orders_along",
    "scheme_rows",
    "format_table",
    "order_text",
    "floor_reason",
    "FLOOR_WORDS",
    "NONE",
    "Column",
    "table_columns",
    "table_notes",
    "wrap_clauses",
    "schemes_of",
    "per_scheme",
    "step_load",
    "span",
    "agree",
    "coinciding_pairs",
    "COINCIDENT_DIGITS",
    "COINCIDENCE_RTOL",
]

# What `scheme_rows` reads: per-case scalars, and momentum_error (the vector L is checked at
# the samples: a time series per case). step_seconds is the step cost its "ns per step" column
# gives (an archive older than the cost model has none: run_time is read in its place).
SUMMARY_VARIABLES = (
    "status",
    "accuracy",
    "run_time",
    "step_seconds",
    "n_steps",
    "final_orientation_error",
    "max_energy_error",
    "max_momentum_magnitude_error",
    "momentum_error",
    "initial_spin",
    "physical_body",
    "radioss_dt_limit",
    "reference_uncertainty",
    "float64_floor",
    "max_step_angle",
    "inertia",
)
# Two errors "agree to 3 digits" when they differ by at most half a unit of the third
# significant digit, relative to the larger (`agree`).
COINCIDENT_DIGITS = 3
COINCIDENCE_RTOL = 0.5 * 10.0**-COINCIDENT_DIGITS
_ORDER_MEASURE = "orientation"


def schemes_of(ds: xr.Dataset | xr.DataArray) -> list[str]:
    """The scheme names of a dataset (swept or scalar coordinate)."""
    return [str(s) for s in np.atleast_1d(ds["scheme"].values)]


def per_scheme(variable: XarrayT, scheme: str) -> XarrayT:
    """``variable`` for one scheme (all of it when the study has one)."""
    return variable.sel(scheme=scheme) if "scheme" in variable.dims else variable


def status_counts(ds: xr.Dataset, schemes: Sequence[str] | None = None) -> dict[int, dict[str, int]]:
    """code -> {scheme: cases} of each status other than ok among the cases of ``schemes``
    (default: every scheme) in ``ds``, in the order of `STATUSES`; empty when all finished."""
    counts: dict[int, dict[str, int]] = {}
    for scheme in schemes_of(ds) if schemes is None else schemes:
        codes, cases = np.unique(per_scheme(ds["status"], scheme).values, return_counts=True)
        for code, count in zip(codes.tolist(), cases.tolist(), strict=True):
            if code != OK:
                counts.setdefault(int(code), {})[scheme] = count
    return dict(sorted(counts.items()))


def status_text(code: int, cases: Mapping[str, int] | str) -> str:
    """What the status ``code`` of ``cases`` (scheme -> how many, or a text naming them) says
    and what to try, from `STATUSES`: ``unstable: 12 cases (euler 8, leapfrog 4): blew up
    (...); take a smaller dt (...)``."""
    name, message, fix = STATUSES[code]
    which = (
        cases
        if isinstance(cases, str)
        else (
            f"{counted(sum(cases.values()), 'case')} ("
            + ", ".join(f"{scheme} {count}" for scheme, count in cases.items())
            + ")"
        )
    )
    return f"{name}: {which}: {message}; {fix}"


def step_load(ds: xr.Dataset) -> xr.DataArray:
    """``dt |w0|`` of every case (the step parameter of a physical body, docs/theory.md s7)."""
    return (ds["dt"] * ds["initial_spin"]).broadcast_like(ds["status"])


class _Fits(NamedTuple):
    """The fits of one scheme's observed order (`_column_fits`): the swept ``dts``; per
    column (a value of the other swept axes, in C order) its fit, or None and `at_floor`'s
    reason; and each column's ``positions`` along each other dimension (dim -> indices)."""

    dts: np.ndarray
    columns: list[tuple[OrderFit | None, str | None]]
    positions: dict[Hashable, np.ndarray]


def _column_fits(errors: xr.DataArray, uncertainty: xr.DataArray | None, round_off: xr.DataArray) -> _Fits:
    """The fit of the observed order over ``dt`` at each value of the other swept axes (a
    column, in C order over ``errors``'s other dimensions), as `_Fits`.
    ``uncertainty``: the reference's, like ``errors``, or None; ``round_off``: the round-off
    floor, like ``errors``."""
    others = [d for d in errors.dims if d != "dt"]

    def stack(values):
        values = values.transpose(*errors.dims)
        return values.stack(other=others) if others else values.expand_dims(other=[0])

    stacked = stack(errors)
    limits = None if uncertainty is None else stack(uncertainty)
    floors = stack(round_off)
    dts = errors["dt"].values
    columns: list[tuple[OrderFit | None, str | None]] = []
    for k in range(stacked.sizes["other"]):
        values, floor = stacked.isel(other=k).values, floors.isel(other=k).values
        limit = None if limits is None else limits.isel(other=k).values
        fit = fitted_order(dts, values, _ORDER_MEASURE, limit, floor)
        columns.append((fit, None) if np.isfinite(fit.order) else (None, at_floor(values, floor, limit)))
    shape = tuple(errors.sizes[d] for d in others)
    index = dict(zip(others, np.unravel_index(np.arange(len(columns)), shape), strict=True)) if others else {}
    return _Fits(dts=dts, columns=columns, positions=index)


def _no_order() -> dict[str, Any]:
    """The order fields of a row without a fit (`_orders`)."""
    return {"order": None, "finest": None, "fits": 0, "tries": 0, "floored": {}, "fit_dt": ()}


def _orders(dts: np.ndarray, columns: list[tuple[OrderFit | None, str | None]]) -> dict[str, Any]:
    """The order fields of a row over ``columns`` (`_column_fits`): the range of the
    successful fits' orders and finest-pair slopes, how many fitted of how many tried, of
    the values without a fit how many were at the floor (`at_floor`: reason -> count), and
    the smallest and largest dt fitted."""
    fields = _no_order() | {"tries": len(columns)}
    fits = [fit for fit, _ in columns if fit is not None]
    for _, why in columns:
        if why:
            fields["floored"][why] = fields["floored"].get(why, 0) + 1
    fields["fits"] = len(fits)
    if fits:
        used = np.logical_or.reduce([fit.used for fit in fits])
        fields["order"] = (min(f.order for f in fits), max(f.order for f in fits))
        fields["finest"] = (min(f.finest_slope for f in fits), max(f.finest_slope for f in fits))
        fields["fit_dt"] = (float(dts[used].min()), float(dts[used].max()))
    return fields


class _OrderInputs(NamedTuple):
    """What the orders are fitted to: every case's ``orientation`` error, its reference's
    ``uncertainty`` (or None) and its ``round_off`` floor (`round_off_of`, which holds the
    float64 floor), and its reference's ``float64`` floor alone (or None)."""

    orientation: xr.DataArray
    uncertainty: xr.DataArray | None
    round_off: xr.DataArray
    float64: xr.DataArray | None


def _order_inputs(ds: xr.Dataset) -> _OrderInputs | None:
    """The `_OrderInputs` of every case; None where there is no error."""
    orientation = error_measure(ds, _ORDER_MEASURE)
    if orientation is None:
        return None
    uncertainty = uncertainty_of(ds, _ORDER_MEASURE, orientation)
    float64 = ds["float64_floor"].broadcast_like(orientation) if "float64_floor" in ds else None
    return _OrderInputs(orientation, uncertainty, round_off_of(ds, _ORDER_MEASURE, orientation), float64)


def _scheme_fits(inputs: _OrderInputs, scheme: str) -> _Fits:
    """`_column_fits` of ``scheme``'s errors (``inputs``: `_order_inputs`)."""
    return _column_fits(
        per_scheme(inputs.orientation, scheme),
        None if inputs.uncertainty is None else per_scheme(inputs.uncertainty, scheme),
        per_scheme(inputs.round_off, scheme),
    )


def orders_along(ds: xr.Dataset, dim: str) -> dict[str, list[dict[str, Any]]]:
    """``scheme -> [the order fields of scheme_rows(ds.isel({dim: k})) for each k]`` (order,
    finest, fits, tries, floored, fit_dt), for a study whose ``dt`` is swept and whose
    nominal orders do not change along any axis: each value of the other axes is fitted
    once, as in the study's own rows, and its fit counted at its value along ``dim``. A row
    per value took most of the time of the default study's findings."""
    inputs = _order_inputs(ds)
    along: dict[str, list[dict[str, Any]]] = {}
    for scheme in schemes_of(ds):
        if inputs is None or "dt" not in per_scheme(inputs.orientation, scheme).dims:
            along[scheme] = [_no_order() for _ in range(ds.sizes[dim])]
            continue
        fits = _scheme_fits(inputs, scheme)
        at = fits.positions.get(dim)  # None: the errors do not change along dim
        along[scheme] = [
            _orders(
                fits.dts,
                fits.columns if at is None else [c for c, i in zip(fits.columns, at, strict=True) if i == k],
            )
            for k in range(ds.sizes[dim])
        ]
    return along


class Verdicts(NamedTuple):
    """Boolean masks over the cases of a scheme, each of the shape of its ``status``."""

    accurate: np.ndarray
    inaccurate: np.ndarray
    failed: np.ndarray
    unjudged: np.ndarray


def verdicts(ds: xr.Dataset, scheme: str) -> Verdicts:
    """`Verdicts` (accurate, inaccurate, failed, unjudged) over the cases of ``scheme``:
    the archive's accuracy verdict, and its status where the archive has no verdict (all
    finished cases then count as accurate). Unjudged: finished, but without a reference."""
    status = per_scheme(ds["status"], scheme).values
    failed = status != OK
    if "accuracy" not in ds:
        return Verdicts(~failed, np.zeros_like(failed), failed, np.zeros_like(failed))
    verdict = per_scheme(ds["accuracy"], scheme).values
    return Verdicts(
        accurate=(verdict == ACCURATE) & ~failed,
        inaccurate=(verdict == INACCURATE) & ~failed,
        failed=failed,
        unjudged=(verdict == UNJUDGED) & ~failed,
    )


def _smallest(values: np.ndarray) -> float:
    return float(np.min(values)) if values.size else np.nan


def _nominal_order(ds: xr.Dataset, scheme: str) -> int | None:
    if "nominal_order" not in ds.coords:
        return None
    return int(per_scheme(ds["nominal_order"], scheme))


def _kept(
    drifts: dict[str, xr.DataArray | None], scheme: str, stable: np.ndarray
) -> tuple[tuple[str, ...], bool]:
    """The labels of the invariants (`INVARIANTS`) whose ``drifts`` (label -> every case's
    largest drift, or None) every ``stable`` case of ``scheme`` keeps: the energy and |L|
    over every step (the driver's drifts), the space vector L at the samples; and whether any
    was measured at all (an archive of bodies under a moment stores none: nothing to keep)."""
    kept, measured = [], False
    for label, drift in drifts.items():
        if drift is not None:
            drift = per_scheme(drift, scheme).values[stable]
            measured = measured or bool(np.isfinite(drift).any())
            if drift.size and np.all(drift < KEPT_TOLERANCE):
                kept.append(label)
    return tuple(kept), measured


def scheme_rows(ds: xr.Dataset) -> list[Row]:
    """One dict per scheme (`_scheme_rows`), and per value of a swept composition.

    Where the study sweeps an option that sets the nominal order (``composition``: the
    archive's ``nominal_order`` runs along its dimension too), a scheme whose order changes
    along it gets a row per value, named ``splitting, composition 4``, fitted over that
    value's cases alone; a scheme the option does not apply to keeps one row.
    """
    dims = [d for d in ds["nominal_order"].dims if d != "scheme"] if "nominal_order" in ds.coords else []
    if not dims:
        return _scheme_rows(ds)
    dim = dims[0]
    per_value = [_scheme_rows(ds.isel({dim: k})) for k in range(ds.sizes[dim])]
    rows = []
    for i, scheme in enumerate(schemes_of(ds)):
        if np.unique(per_scheme(ds["nominal_order"], scheme).values).size == 1:
            rows.append(per_value[0][i])
            continue
        for k, value in enumerate(ds[dim].values):
            row = per_value[k][i]
            row["scheme"] = f"{scheme}, {dim} {value:g}"
            rows.append(row)
    return rows


def _scheme_rows(ds: xr.Dataset) -> list[Row]:
    """One dict per scheme.

    Keys: scheme; nominal (the scheme's nominal order as archived, None if the archive does
    not record it); cases, unstable (cases that failed), inaccurate (cases that finished but
    were judged inaccurate, None for an archive without the verdict), unjudged (finished
    without a reference), radioss (cases past the OpenRadioss limit dt |w| = 1); order
    ((min, max) over the successful fits, or None) and finest ((min, max) of the fits'
    finest-pair slopes),
    fits and tries (how many of the other axes' values gave an asymptotic range), floored (of
    the others, how many had too few errors above the floor, by `at_floor`'s reason), fit_dt
    ((smallest, largest) dt fitted); error_dt / error at the largest dt and error_small_dt /
    error_small at the smallest, the worst over the other axes (NaN when a case there failed:
    a failure is never hidden behind the stable cases; None when a case there had no
    reference); ns_per_step (kernel time per body-step, all the scheme's time over all its
    steps: at its calibrated ``step_seconds`` where the archive has them, else its measured
    ``run_time``); and over physical cases, by
    ``dt |w0|``: accurate_hw (accurate up to: the largest of an accurate case below the
    first that is not), inaccurate_hw (the smallest of a finished but inaccurate case) and
    unstable_hw (the smallest of a failed one), NaN where none; physical and judged_physical
    (its cases of a physical body, and of those the ones with a reference); kept (invariants
    every stable case kept to `KEPT_TOLERANCE`) and invariants_measured (whether any was).
    """
    rows = []
    load = step_load(ds)
    physical = (ds["physical_body"] == 1).broadcast_like(ds["status"])
    judged = "accuracy" in ds
    # every case's error measures, once for all schemes
    drifts = {label: error_measure(ds, key) for key, label in INVARIANTS.items()}
    inputs = _order_inputs(ds)
    for scheme in schemes_of(ds):
        status = per_scheme(ds["status"], scheme)
        verdict = verdicts(ds, scheme)
        row = {
            "scheme": scheme,
            "nominal": _nominal_order(ds, scheme),
            "cases": int(status.size),
            "unstable": int(verdict.failed.sum()),
            "inaccurate": int(verdict.inaccurate.sum()) if judged else None,
            "unjudged": int(verdict.unjudged.sum()),
            **_no_order(),
            "error": None,
            "error_small": None,
            "float64_floor": None,
            "radioss": int((per_scheme(ds["radioss_dt_limit"], scheme) == 1).sum()),
            "ns_per_step": _ns_per_step(ds, scheme),
            **_step_load_fields(
                per_scheme(load, scheme).values, per_scheme(physical, scheme).values, verdict
            ),
        }
        row["kept"], row["invariants_measured"] = _kept(drifts, scheme, ~verdict.failed)
        if inputs is not None:
            row |= _error_fields(inputs, scheme, status)
        rows.append(row)
    return rows


def _ns_per_step(ds: xr.Dataset, scheme: str) -> float:
    """The kernel nanoseconds a body-step of ``scheme``, all its time over all its steps: the
    cost the findings rank by, the calibrated seconds a step where the archive has them (the
    same in every run on this machine), else the run's measured time."""
    seconds = (
        per_scheme(ds["n_steps"] * ds["step_seconds"], scheme)
        if "step_seconds" in ds
        else per_scheme(ds["run_time"], scheme)
    )
    return float(seconds.sum() / per_scheme(ds["n_steps"], scheme).sum()) * 1e9


def _step_load_fields(load: np.ndarray, real: np.ndarray, verdict: Verdicts) -> dict[str, Any]:
    """A row's ``dt |w0|`` fields (accurate_hw, physical, judged_physical, inaccurate_hw,
    unstable_hw) from the ``load`` of each case of a scheme, whether its body is ``real``
    (physical) and its `Verdicts`. dt |w0| is the step parameter of physical bodies only (for
    a stress body beyond the triangle inequality the precession rate W outgrows |w0|): those
    cases alone count."""
    first = {
        name: _smallest(load[cases & real])
        for name, cases in (("inaccurate", verdict.inaccurate), ("failed", verdict.failed))
    }
    limit = np.fmin(first["inaccurate"], first["failed"])  # NaN when every case is fine
    good = verdict.accurate & real & (load < limit if np.isfinite(limit) else True)
    return {
        "accurate_hw": float(np.max(load[good])) if good.any() else np.nan,
        # what a missing dt |w0| means: no physical body, or none judged (no reference)
        "physical": int(real.sum()),
        "judged_physical": int((real & ~verdict.unjudged).sum()),
        "inaccurate_hw": first["inaccurate"],
        "unstable_hw": first["failed"],
    }


def _error_fields(inputs: _OrderInputs, scheme: str, status: xr.DataArray) -> dict[str, Any]:
    """A row's order fields (`_orders`) and its worst errors (`_worst`): at the largest and
    the smallest ``dt`` where ``dt`` is swept, else over every case."""
    errors = per_scheme(inputs.orientation, scheme)
    if "dt" not in errors.dims:
        return {"error": _worst(errors, status)}
    fits = _scheme_fits(inputs, scheme)
    fields = _orders(fits.dts, fits.columns)
    for key, pick in (("", errors["dt"].max()), ("_small", errors["dt"].min())):
        fields[f"error{key}_dt"] = float(pick)
        fields[f"error{key}"] = _worst(errors.sel(dt=pick), status.sel(dt=pick))
    fields["float64_floor"] = _at_float64_floor(errors, inputs.float64, scheme)
    return fields


def _at_float64_floor(
    errors: xr.DataArray, float64: xr.DataArray | None, scheme: str
) -> tuple[float, float, bool] | None:
    """Where ``scheme``'s ``errors`` lie at the float64 floor (within `FLOOR_FACTOR` of
    ``float64``, its reference's): the largest such floor (rad), the largest dt (s) at it,
    and whether every finite error does; None where none does."""
    if float64 is None:
        return None
    floor = per_scheme(float64, scheme)
    finite = np.isfinite(errors)
    at = finite & (errors <= FLOOR_FACTOR * floor)
    if not bool(at.any()):
        return None
    every = bool(at.sum() == finite.sum())
    return float(floor.where(at).max()), float(errors["dt"].broadcast_like(errors).where(at).max()), every


def _worst(errors: xr.DataArray, status: xr.DataArray) -> float | None:
    """The largest of ``errors``: NaN when a case failed (a failure is never hidden behind the
    stable cases), None when the errors are missing only because a case had no reference."""
    worst = float(errors.max(skipna=False))
    return None if np.isnan(worst) and not (status != OK).any() else worst


def agree(first: np.ndarray, second: np.ndarray) -> bool:
    """Whether two arrays of errors agree to `COINCIDENT_DIGITS` digits case by case
    (`COINCIDENCE_RTOL`; both NaN counts as agreeing: the same failure); at least one case
    must be finite in both. The one test of "these lines coincide" of the findings, the
    figures' legends and the report's captions."""
    both = np.isfinite(first) & np.isfinite(second)
    same_gap = np.isnan(first) == np.isnan(second)
    close = np.abs(first - second) <= COINCIDENCE_RTOL * np.fmax(np.abs(first), np.abs(second))
    return bool(both.any() and same_gap.all() and np.all(close | ~both))


def coinciding_pairs(ds: xr.Dataset, errors: xr.DataArray | None) -> list[tuple[str, str]]:
    """The (first, second) schemes of ``ds`` whose ``errors`` (a measure of `error_measure`)
    `agree` in every case; none where the study has one scheme."""
    if errors is None or "scheme" not in errors.dims:
        return []
    values = {scheme: per_scheme(errors, scheme).values for scheme in schemes_of(ds)}
    names = list(values)
    return [
        (first, second)
        for i, first in enumerate(names)
        for second in names[i + 1 :]
        if agree(values[first], values[second])
    ]
