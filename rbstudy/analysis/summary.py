"""The per-scheme summary of a study, read from its dataset (never from a rerun).

The error measures (`ERROR_MEASURES`) and their asymptotic ranges live here, shared by the
terminal table, the figures and the report. For each scheme, `scheme_rows` gives the
observed order of the final orientation error over the swept ``dt`` (fitted per value of
every other swept axis, only where the error is neither at round-off nor too large to be
asymptotic), the errors at the largest and smallest ``dt``, the kernel time per body-step,
the stable range in ``dt |w0|``, and which invariants every stable case kept. Everything
comes from the archive (the nominal order from its ``nominal_order`` coordinate): nothing here
needs the scheme registry or a compiler.

The table of those rows is defined once (`table_columns`: a `Column` per value, with its
header and units, its cell text, whether the default table shows it and its footnotes) and
rendered by tabulate as text, Markdown, CSV or HTML (`format_table`). The default text keeps
to `TERMINAL_WIDTH` columns for every shipped study, its footnotes to six lines.
"""

import csv
import html
import io
import textwrap
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from tabulate import tabulate

from rbstudy.archive.variables import ACCURATE, INACCURATE, UNJUDGED
from rbstudy.errors import counted
from rbstudy.numerics.state import INVARIANTS, OK, STATUSES
from rbstudy.physics.metrics import MIN_ASYMPTOTIC_POINTS, asymptotic_order

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
    "ROUND_OFF_ULPS",
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


class ErrorMeasure(NamedTuple):
    """An error measure of the archive, as the table, the figures and the report show it.

    label, units : its words and units. floor, ceiling : its asymptotic range: below the floor
    an error is round-off, above the ceiling it is not asymptotic (or the run failed).
    variable : the archive's variable. uncertainty : the variable of the uncertainty of its
    reference, or None (a closed form, or a measure not against a reference). turns : whether
    its round-off grows with the angle the body turns (`round_off_of`).
    """

    label: str
    units: str
    floor: float
    ceiling: float
    variable: str
    uncertainty: str | None = None
    turns: bool = False


# The floor is a few hundred ulps of the quantity (rounding summed over 1e3-1e4 steps, relative
# to 1); energy and |L| are relative to their exact start values and sit lower.
# `metrics.asymptotic_order` also cuts the range where the local slopes stop agreeing, so a
# floor set a little low costs nothing. A measure taken against an integrated reference also
# has a floor of `UNCERTAINTY_FACTOR` times that reference's uncertainty, case by case.
ERROR_MEASURES = {
    "orientation": ErrorMeasure(
        label="final orientation error",
        units="rad",
        floor=1e-13,
        ceiling=1e-1,
        variable="final_orientation_error",
        uncertainty="reference_uncertainty",
        turns=True,
    ),
    "omega": ErrorMeasure(
        label="max relative angular velocity error",
        units="1",
        floor=1e-13,
        ceiling=1e-1,
        variable="omega_error",
        uncertainty="reference_omega_uncertainty",
        turns=True,
    ),
    "nodes": ErrorMeasure(
        label="max node position error",
        units="m",
        floor=1e-13,
        ceiling=1e-1,
        variable="node_error",
        uncertainty="reference_node_uncertainty",
    ),
    "energy": ErrorMeasure(
        label="max relative energy error", units="1", floor=1e-15, ceiling=1e-1, variable="max_energy_error"
    ),
    "momentum_magnitude": ErrorMeasure(
        label="max relative error of |L| (magnitude)",
        units="1",
        floor=1e-15,
        ceiling=1e-1,
        variable="max_momentum_magnitude_error",
    ),
    # the vector L = R m at the samples carries the rounding of R and m over thousands of
    # steps: 1e-14 to 1e-13 for the schemes that keep it
    "momentum_vector": ErrorMeasure(
        label="max relative |L - L0| (vector)",
        units="1",
        floor=1e-12,
        ceiling=1e-1,
        variable="momentum_error",
    ),
    "precession": ErrorMeasure(
        label="|precession frequency error|",
        units="rad/s",
        floor=1e-13,
        ceiling=1e-1,
        variable="precession_frequency_error",
    ),
    # zero crossings of samples placed by linear interpolation: ~1e-6 s at best
    "flip": ErrorMeasure(
        label="|flip interval error|", units="s", floor=1e-5, ceiling=1.0, variable="flip_interval_error"
    ),
}
# An error within this factor of its reference's uncertainty says as much about the reference
# as about the scheme: no order is fitted through it.
UNCERTAINTY_FACTOR = 10.0
# A measure that turns with the body rounds about an ulp a step and an ulp of the largest
# angle the run's motion sweeps: exact_split, exact on a free body, ends the Abaqus top
# 9.8e-13 rad off after 6,400 steps (0.7 ulp a step) and stiff_inertia's disk of I3/I1 = 1e4
# (its precession sweeps 6.3e4 rad in 1 s) 1.4e-11 rad off at every dt, at most 1.3 ulps of
# steps and angle together; twice that is round-off (`round_off_of`). Ten times it took MuJoCo's
# and rbstudy's rk4 for round-off on Drake's floating body, whose errors at 3,200 steps
# (2.4e-12 rad) still fall by 16 a halving: a floor must sit under the errors a scheme makes.
ROUND_OFF_ULPS = 2.0
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
    "max_step_angle",
    "inertia",
)
# An invariant counts as kept when its largest relative drift over every step of every
# stable case stays below this: round-off over 1e4-1e5 steps, far below any truncation error.
KEPT_TOLERANCE = 1e-10
# Two errors "agree to 3 digits" when they differ by at most half a unit of the third
# significant digit, relative to the larger (`agree`).
COINCIDENT_DIGITS = 3
COINCIDENCE_RTOL = 0.5 * 10.0**-COINCIDENT_DIGITS
_ORDER_MEASURE = "orientation"


def error_measure(ds, key):
    """|error measure| ``key`` of every case (time and nodes reduced by max), or None."""
    name = ERROR_MEASURES[key].variable
    if name not in ds:
        return None
    value = ds[name]
    reduce = [d for d in value.dims if d in ("time", "node")]
    return abs(value.max(reduce, skipna=False) if reduce else value)


def uncertainty_of(ds, key, like):
    """The uncertainty of the reference of measure ``key`` per case, broadcast like the
    measure ``like``; None where the archive has none (closed-form references)."""
    name = ERROR_MEASURES[key].uncertainty
    return ds[name].broadcast_like(like) if name is not None and name in ds else None


def round_off_of(ds, key, like):
    """The round-off floor of measure ``key`` per case, broadcast like the measure ``like``:
    its constant ``floor`` (relative to 1), raised for a measure that ``turns`` with the body to
    `ROUND_OFF_ULPS` float64 ulps of its steps (``n_steps``) plus the largest angle the run's
    motion sweeps: ``|w| T`` (``max_step_angle`` times ``n_steps``) times the inertia's
    largest over its smallest moment, as fast as ``|L| / I_min``, the precession of L seen
    from the body, can outrun ``|w|``. A relative measure that does not turn (units 1: the
    energy, ``|L|`` and ``L`` drifts) is raised to `ROUND_OFF_ULPS` ulps of its steps alone:
    the schemes that keep them end 1e-15 to 1e-13 off after hundreds of steps, no order to
    fit. A failed case (no finite angle) keeps the constant floor: its error is NaN."""
    spec = ERROR_MEASURES[key]
    floor = like.copy(data=np.full(like.shape, spec.floor))
    if not spec.turns:
        if spec.units != "1" or "n_steps" not in ds.variables:
            return floor
        steps = (ROUND_OFF_ULPS * np.finfo(float).eps * ds["n_steps"]).broadcast_like(like)
        return np.fmax(floor, steps.transpose(*like.dims))
    if not {"max_step_angle", "n_steps", "inertia"} <= set(ds.variables):
        return floor
    inertia = ds["inertia"]
    steps = ds["n_steps"]
    swept = steps + ds["max_step_angle"] * steps * inertia.max("axis") / inertia.min("axis")
    scaled = (ROUND_OFF_ULPS * np.finfo(float).eps * swept).broadcast_like(like).transpose(*like.dims)
    return np.fmax(floor, scaled.where(np.isfinite(scaled)))


def fitted_order(dts, errors, key, uncertainty=None, round_off=None):
    """Observed order of measure ``key`` over its asymptotic range, an
    `rbstudy.physics.metrics.OrderFit` (order, used mask, finest pair's slope). A point at the
    floor is not fitted: at or below its ``round_off`` (per point, `round_off_of`; None: the
    measure's constant floor), or below `UNCERTAINTY_FACTOR` times its reference's
    ``uncertainty`` (per point; NaN or None: none known)."""
    spec = ERROR_MEASURES[key]
    return asymptotic_order(dts, errors, _floor(spec.floor, uncertainty, round_off), spec.ceiling)


def _floor(constant, uncertainty, round_off):
    """The larger of the round-off floor (``round_off`` per point, else ``constant``) and
    `UNCERTAINTY_FACTOR` times the reference's ``uncertainty`` (NaN: none known)."""
    floor = constant if round_off is None else np.asarray(round_off, dtype=float)
    if uncertainty is not None:
        floor = np.fmax(floor, UNCERTAINTY_FACTOR * np.asarray(uncertainty, dtype=float))
    return floor


def at_floor(errors, round_off, uncertainty=None):
    """Why no order can be fitted through ``errors`` over the steps: ``"round-off"`` when too
    few finite errors lie above their ``round_off`` (per point) for a fit (fewer than
    `MIN_ASYMPTOTIC_POINTS` where that many are finite, else none), ``"reference"`` when too
    few lie above `UNCERTAINTY_FACTOR` times the reference's ``uncertainty`` as well; None
    when enough do (or no error is finite: the cases failed)."""
    errors = np.asarray(errors, dtype=float)
    finite = np.isfinite(errors)

    def too_few(above):
        shown = finite & above
        enough = finite.sum() >= MIN_ASYMPTOTIC_POINTS
        return shown.sum() < MIN_ASYMPTOTIC_POINTS and (enough or not shown.any())

    if not finite.any():
        return None
    if too_few(errors > round_off):
        return "round-off"
    return "reference" if too_few(errors > _floor(0.0, uncertainty, round_off)) else None


def schemes_of(ds):
    """The scheme names of a dataset (swept or scalar coordinate)."""
    return [str(s) for s in np.atleast_1d(ds["scheme"].values)]


def per_scheme(variable, scheme):
    """``variable`` for one scheme (all of it when the study has one)."""
    return variable.sel(scheme=scheme) if "scheme" in variable.dims else variable


def status_counts(ds, schemes=None):
    """code -> {scheme: cases} of each status other than ok among the cases of ``schemes``
    (default: every scheme) in ``ds``, in the order of `STATUSES`; empty when all finished."""
    counts = {}
    for scheme in schemes_of(ds) if schemes is None else schemes:
        codes, cases = np.unique(per_scheme(ds["status"], scheme).values, return_counts=True)
        for code, count in zip(codes.tolist(), cases.tolist(), strict=True):
            if code != OK:
                counts.setdefault(int(code), {})[scheme] = count
    return dict(sorted(counts.items()))


def status_text(code, cases):
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


def step_load(ds):
    """``dt |w0|`` of every case (the step parameter of a physical body, docs/theory.md s7)."""
    return (ds["dt"] * ds["initial_spin"]).broadcast_like(ds["status"])


def _column_fits(errors, uncertainty, round_off):
    """The fit of the observed order over ``dt`` at each value of the other swept axes (a
    column, in C order over ``errors``'s other dimensions): (dts, per column its fit, or None
    and `at_floor`'s reason, and the column's index along each other dimension).
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
    columns = []
    for k in range(stacked.sizes["other"]):
        values, floor = stacked.isel(other=k).values, floors.isel(other=k).values
        limit = None if limits is None else limits.isel(other=k).values
        fit = fitted_order(dts, values, _ORDER_MEASURE, limit, floor)
        columns.append((fit, None) if np.isfinite(fit.order) else (None, at_floor(values, floor, limit)))
    shape = tuple(errors.sizes[d] for d in others)
    index = dict(zip(others, np.unravel_index(np.arange(len(columns)), shape), strict=True)) if others else {}
    return dts, columns, index


def _no_order():
    """The order fields of a row without a fit (`_orders`)."""
    return {"order": None, "finest": None, "fits": 0, "tries": 0, "floored": {}, "fit_dt": ()}


def _orders(dts, columns):
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


def _order_inputs(ds):
    """Every case's orientation error, its reference's uncertainty (or None) and its
    round-off floor, the measures the orders are fitted to; None where there is no error."""
    orientation = error_measure(ds, _ORDER_MEASURE)
    if orientation is None:
        return None
    uncertainty = uncertainty_of(ds, _ORDER_MEASURE, orientation)
    return orientation, uncertainty, round_off_of(ds, _ORDER_MEASURE, orientation)


def _scheme_fits(inputs, scheme):
    """`_column_fits` of ``scheme``'s errors (``inputs``: `_order_inputs`)."""
    orientation, uncertainty, round_off = inputs
    return _column_fits(
        per_scheme(orientation, scheme),
        None if uncertainty is None else per_scheme(uncertainty, scheme),
        per_scheme(round_off, scheme),
    )


def orders_along(ds, dim):
    """``scheme -> [the order fields of scheme_rows(ds.isel({dim: k})) for each k]`` (order,
    finest, fits, tries, floored, fit_dt), for a study whose ``dt`` is swept and whose
    nominal orders do not change along any axis: each value of the other axes is fitted
    once, as in the study's own rows, and its fit counted at its value along ``dim``. A row
    per value took the findings of the default study 0.8 s, four fifths of them."""
    inputs = _order_inputs(ds)
    along = {}
    for scheme in schemes_of(ds):
        if inputs is None or "dt" not in per_scheme(inputs[0], scheme).dims:
            along[scheme] = [_no_order() for _ in range(ds.sizes[dim])]
            continue
        dts, columns, index = _scheme_fits(inputs, scheme)
        at = index.get(dim)  # None: the errors do not change along dim
        along[scheme] = [
            _orders(dts, columns if at is None else [c for c, i in zip(columns, at, strict=True) if i == k])
            for k in range(ds.sizes[dim])
        ]
    return along


def verdicts(ds, scheme):
    """Boolean masks (accurate, inaccurate, failed, unjudged) over the cases of ``scheme``:
    the archive's accuracy verdict, and its status where the archive has no verdict (all
    finished cases then count as accurate). Unjudged: finished, but without a reference."""
    status = per_scheme(ds["status"], scheme).values
    failed = status != OK
    if "accuracy" not in ds:
        return ~failed, np.zeros_like(failed), failed, np.zeros_like(failed)
    verdict = per_scheme(ds["accuracy"], scheme).values
    return (
        (verdict == ACCURATE) & ~failed,
        (verdict == INACCURATE) & ~failed,
        failed,
        (verdict == UNJUDGED) & ~failed,
    )


def _smallest(values):
    return float(np.min(values)) if values.size else np.nan


def _nominal_order(ds, scheme):
    if "nominal_order" not in ds.coords:
        return None
    return int(per_scheme(ds["nominal_order"], scheme))


def _kept(drifts, scheme, stable):
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


def scheme_rows(ds):
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


def _scheme_rows(ds):
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
        accurate, inaccurate, failed, unjudged = verdicts(ds, scheme)
        row = {
            "scheme": scheme,
            "nominal": _nominal_order(ds, scheme),
            "cases": int(status.size),
            "unstable": int(failed.sum()),
            "inaccurate": int(inaccurate.sum()) if judged else None,
            "unjudged": int(unjudged.sum()),
            **_no_order(),
            "error": None,
            "error_small": None,
            "radioss": int((per_scheme(ds["radioss_dt_limit"], scheme) == 1).sum()),
        }
        # the cost the findings rank by: the calibrated seconds a step where the archive has
        # them (the same in every run on this machine), else the run's measured time
        seconds = (
            per_scheme(ds["n_steps"] * ds["step_seconds"], scheme)
            if "step_seconds" in ds
            else per_scheme(ds["run_time"], scheme)
        )
        row["ns_per_step"] = float(seconds.sum() / per_scheme(ds["n_steps"], scheme).sum()) * 1e9
        # dt |w0| is the step parameter of physical bodies only (for a stress body beyond the
        # triangle inequality the precession rate W outgrows |w0|): those cases alone count
        scheme_load = per_scheme(load, scheme).values
        real = per_scheme(physical, scheme).values
        first = {
            name: _smallest(scheme_load[cases & real])
            for name, cases in (("inaccurate", inaccurate), ("failed", failed))
        }
        limit = np.fmin(first["inaccurate"], first["failed"])  # NaN when every case is fine
        good = accurate & real & (scheme_load < limit if np.isfinite(limit) else True)
        row["accurate_hw"] = float(np.max(scheme_load[good])) if good.any() else np.nan
        # what a missing dt |w0| means: no physical body, or none judged (no reference)
        row["physical"] = int(real.sum())
        row["judged_physical"] = int((real & ~unjudged).sum())
        row["inaccurate_hw"], row["unstable_hw"] = first["inaccurate"], first["failed"]
        row["kept"], row["invariants_measured"] = _kept(drifts, scheme, ~failed)
        if inputs is not None:
            errors = per_scheme(inputs[0], scheme)
            if "dt" in errors.dims:
                row |= _orders(*_scheme_fits(inputs, scheme)[:2])
                for key, pick in (("", errors["dt"].max()), ("_small", errors["dt"].min())):
                    row[f"error{key}_dt"] = float(pick)
                    row[f"error{key}"] = _worst(errors.sel(dt=pick), status.sel(dt=pick))
            else:
                row["error"] = _worst(errors, status)
        rows.append(row)
    return rows


def _worst(errors, status):
    """The largest of ``errors``: NaN when a case failed (a failure is never hidden behind the
    stable cases), None when the errors are missing only because a case had no reference."""
    worst = float(errors.max(skipna=False))
    return None if np.isnan(worst) and not (status != OK).any() else worst


def span(values):
    """``2.00``, or ``1.98-2.01`` when the ``values`` (orders, slopes) differ at two decimals."""
    low, high = min(values), max(values)
    return f"{low:.2f}" if high - low < 0.005 else f"{low:.2f}-{high:.2f}"


def agree(first, second):
    """Whether two arrays of errors agree to `COINCIDENT_DIGITS` digits case by case
    (`COINCIDENCE_RTOL`; both NaN counts as agreeing: the same failure); at least one case
    must be finite in both. The one test of "these lines coincide" of the findings, the
    figures' legends and the report's captions."""
    both = np.isfinite(first) & np.isfinite(second)
    same_gap = np.isnan(first) == np.isnan(second)
    close = np.abs(first - second) <= COINCIDENCE_RTOL * np.fmax(np.abs(first), np.abs(second))
    return bool(both.any() and same_gap.all() and np.all(close | ~both))


def coinciding_pairs(ds, errors):
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


# The words a cell shows where it has no number, each explained under the table where used
# (`Column.marks`): a "-" said "no reference", "no accurate step" and "none kept" alike.
NOT_APPLICABLE = "n/a"
NONE = "none"
NO_REFERENCE = "no ref"
FAILED = "failed"
ROUND_OFF = "round-off"
REFERENCE_FLOOR = "ref floor"
# What the findings say for a row whose every value was at the floor (`at_floor`'s reason).
FLOOR_WORDS = {
    "round-off": "at the floor (round-off)",
    "reference": f"at the floor ({UNCERTAINTY_FACTOR:g}x the reference's uncertainty)",
}


def floor_reason(row):
    """``"round-off"`` or ``"reference"`` (`at_floor`) when no value of the other axes had a
    fit and every one of them was at the floor (round-off where any was), else None."""
    floored = row.get("floored", {})
    if row["order"] is not None or not row["tries"] or sum(floored.values()) < row["tries"]:
        return None
    return "round-off" if floored.get("round-off") else "reference"


def order_text(row):
    """``2.00`` or ``1.98-2.01`` (the range over the other swept axes), with ``(3/4)`` when
    some values of the other axes had no asymptotic range; without any, why: `ROUND_OFF` or
    `REFERENCE_FLOOR` (every value at the floor, `floor_reason`), `NONE` (no asymptotic
    range, ``(0/4)``) or `NOT_APPLICABLE` (dt not swept)."""
    if row["order"] is not None:
        text = span(row["order"])
    elif not row["tries"]:
        return NOT_APPLICABLE
    else:
        reason = floor_reason(row)
        if reason is not None:
            return ROUND_OFF if reason == "round-off" else REFERENCE_FLOOR
        text = NONE
    whole = row["fits"] == row["tries"] or row["tries"] == 1  # (0/1) says nothing more
    return text if whole else f"{text} ({row['fits']}/{row['tries']})"


def _error(value):
    if value is None:
        return NO_REFERENCE
    return FAILED if not np.isfinite(value) else f"{value:.1e}"


def _number(value, spec, missing=NONE):
    return missing if value is None or not np.isfinite(value) else f"{value:{spec}}"


def _step_load(row, key):
    """The ``dt |w0|`` cell ``key`` of ``row``, or why it has none: `NOT_APPLICABLE` (no
    physical body), `NO_REFERENCE` (none of them judged), `NONE` (no such case)."""
    if not row["physical"]:
        return _number(row[key], ".3g", NOT_APPLICABLE)
    if key != "unstable_hw" and not row["judged_physical"]:
        return _number(row[key], ".3g", NO_REFERENCE)
    return _number(row[key], ".3g")


def _kept_text(row):
    if row["kept"]:
        return ", ".join(row["kept"])
    return NONE if row["invariants_measured"] else NOT_APPLICABLE


# The terminal's width the default table and its footnotes keep to (characters).
TERMINAL_WIDTH = 100
TABLE_FORMATS = ("text", "markdown", "csv", "html")


@dataclass(frozen=True)
class Column:
    """A column of the per-scheme table: its ``key``, its ``header`` (the name, then its
    units; the terminal shows each line of it on a line of its own, the other formats one
    line), the ``cell`` text of a row, whether the default ``narrow`` table shows it, its
    footnotes ``notes`` (none when the header says it all), and ``marks``: (word, footnote)
    pairs, each word a cell may hold instead of a number with what it means there, noted
    only under a table whose cells of the column use it."""

    key: str
    header: str
    cell: Callable
    narrow: bool
    notes: tuple = ()
    left: bool = False
    marks: tuple = ()


def table_columns(rows):
    """Every `Column` of the per-scheme table, shared by the terminal, the report, Markdown
    and CSV; a column with nothing to show in these ``rows`` is left out."""
    large = next((row["error_dt"] for row in rows if "error_dt" in row), None)
    small = next((row["error_small_dt"] for row in rows if "error_small_dt" in row), None)

    def error_at(dt):
        return "error\n(rad)" if dt is None else f"error at\ndt={dt:g} s\n(rad)"

    errors = (
        (FAILED, f'"{FAILED}": a case blew up'),
        (NO_REFERENCE, f'error "{NO_REFERENCE}": a case had no reference'),
    )
    load_marks = (
        (NONE, f'dt|w0| "{NONE}": no such case'),
        (NOT_APPLICABLE, f'dt|w0| "{NOT_APPLICABLE}": no physical body'),
        (NO_REFERENCE, f'dt|w0| "{NO_REFERENCE}": none had a reference'),
    )
    columns = [
        Column("scheme", "scheme", lambda row: row["scheme"], True, left=True),
        Column(
            "nominal",
            "nominal\norder",
            lambda row: NOT_APPLICABLE if row["nominal"] is None else str(row["nominal"]),
            True,
            marks=((NOT_APPLICABLE, f'nominal "{NOT_APPLICABLE}": not in the archive'),),
        ),
        Column(
            "order",
            "observed\norder",
            order_text,
            True,
            ("observed order: per value of the other axes, (k/n): k of n fitted",),
            marks=(
                (ROUND_OFF, f'"{ROUND_OFF}": errors at round-off'),
                (REFERENCE_FLOOR, f'"{REFERENCE_FLOOR}": under {UNCERTAINTY_FACTOR:g}x its uncertainty'),
                (NONE, f'order "{NONE}": no asymptotic range'),
                (NOT_APPLICABLE, f'order "{NOT_APPLICABLE}": dt not swept'),
            ),
        ),
        Column(
            "finest",
            "finest\npair",
            lambda row: NONE if row["finest"] is None else span(row["finest"]),
            False,
            ("finest pair: slope of the two finest fitted steps",),
        ),
        Column(
            "fit_dt",
            "fit over\ndt (s)",
            lambda row: NONE if not row["fit_dt"] else f"{row['fit_dt'][0]:.3g}..{row['fit_dt'][1]:.3g}",
            False,
            marks=((NONE, f'finest pair, fit over "{NONE}": no order fitted'),),
        ),
        Column(
            "error",
            error_at(large),
            lambda row: _error(row["error"]),
            True,
            ("error: final orientation error, worst case",),
            marks=errors,
        ),
    ]
    if small is not None and small != large:
        columns.append(
            Column(
                "error_small",
                error_at(small),
                lambda row: _error(row.get("error_small")),
                False,
                marks=errors,
            )
        )
    columns += [
        Column(
            "ns_per_step",
            "ns per\nstep",
            lambda row: _number(row["ns_per_step"], ".0f", NOT_APPLICABLE),
            True,
            ("ns: kernel time a step, as the findings cost it",),
            marks=((NOT_APPLICABLE, f'ns "{NOT_APPLICABLE}": no step timed'),),
        ),
        Column(
            "accurate_hw",
            "accurate\nto dt|w0|\n(rad)",
            lambda row: _step_load(row, "accurate_hw"),
            True,
            (
                "accurate to: largest accurate dt|w0| below any inaccurate or failed",
                "dt|w0|: physical bodies only",
            ),
            marks=load_marks,
        ),
        Column(
            "inaccurate_hw",
            "first\ninaccurate\ndt|w0| (rad)",
            lambda row: _step_load(row, "inaccurate_hw"),
            False,
            marks=load_marks,
        ),
        Column(
            "unstable_hw",
            "first\nfailed\ndt|w0| (rad)",
            lambda row: _step_load(row, "unstable_hw"),
            False,
            marks=load_marks,
        ),
        Column(
            "inaccurate",
            "inaccurate\ncases",
            lambda row: (
                NOT_APPLICABLE
                if row["inaccurate"] is None
                else f"{row['inaccurate']}/{row['cases']}"
                + (f" ({row['unjudged']} unjudged)" if row["unjudged"] else "")
            ),
            False,
            ("inaccurate: past the accuracy bound (unjudged: no reference)",),
            marks=((NOT_APPLICABLE, f'inaccurate "{NOT_APPLICABLE}": the archive has no verdict'),),
        ),
        Column(
            "failed",
            "failed\ncases",
            lambda row: f"{row['unstable']}/{row['cases']}",
            True,
            # what each means and what to try: the findings (`status_text`)
            (f"failed: {' or '.join(status.name for status in STATUSES[OK + 1 :])}",),
        ),
    ]
    if any(row["radioss"] for row in rows):  # only where the limit was passed
        columns.append(
            Column(
                "radioss",
                "past\nRadioss\nlimit",
                lambda row: f"{row['radioss']}/{row['cases']}",
                False,
                ("past Radioss limit: dt|w| > 1, where OpenRadioss aborts",),
            )
        )
    columns.append(
        Column(
            "kept",
            "kept",
            _kept_text,
            True,
            (f"kept: drift < {KEPT_TOLERANCE:g} in every stable case (L at the samples)",),
            left=True,
            marks=(
                (NONE, f'kept "{NONE}": no invariant kept'),
                (NOT_APPLICABLE, f'kept "{NOT_APPLICABLE}": none measured (a moment acts)'),
            ),
        )
    )
    return columns


def table_notes(columns, rows, width=TERMINAL_WIDTH):
    """The footnotes of ``columns`` over ``rows``, as lines of at most ``width`` characters:
    each column's notes, then what each of its `Column.marks` means, of those its cells of
    ``rows`` hold (a mark's note said once, where columns share it)."""
    notes = []
    for column in columns:
        notes += column.notes
        used = {column.cell(row) for row in rows}
        notes += [note for mark, note in column.marks if any(cell.startswith(mark) for cell in used)]
    return wrap_clauses("; ".join(dict.fromkeys(notes)), width)


def wrap_clauses(line, width=TERMINAL_WIDTH, indent=""):
    """``line`` as lines of at most ``width`` characters: broken after a "; " where it can,
    else between words (a word longer than ``width``, a path, stays whole); the lines after
    the first start with ``indent``."""
    clauses = line.split("; ")
    lines = []
    for clause in [f"{clause};" for clause in clauses[:-1]] + clauses[-1:]:
        if lines and len(lines[-1]) + len(" ") + len(clause) <= width:
            lines[-1] += " " + clause
        else:
            lines.append((indent if lines else "") + clause)
    return [
        short
        for long in lines
        for short in textwrap.wrap(
            long, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False
        )
    ]


def format_table(rows, wide=False, fmt="text"):
    """The per-scheme table of ``rows`` (`scheme_rows`) as ``fmt`` (one of `TABLE_FORMATS`):
    the columns that answer how accurate, how stable and at what cost (each line within
    `TERMINAL_WIDTH` for the shipped studies), or every column when ``wide``; under it its
    footnotes (not in CSV, which holds the values alone)."""
    columns = [c for c in table_columns(rows) if wide or c.narrow]
    cells = [[column.cell(row) for column in columns] for row in rows]
    align = ["left" if column.left else "right" for column in columns]
    if fmt == "text":  # the headers as rows: tabulate pads a header row by two more spaces
        lines = [
            line.rstrip()
            for line in tabulate(
                [[c.header for c in columns], *cells], tablefmt="plain", colalign=align, disable_numparse=True
            ).splitlines()
        ]
        # the footnotes of a wide table as wide as it
        return "\n".join(lines + table_notes(columns, rows, max(TERMINAL_WIDTH, *map(len, lines))))
    headers = [_one_line(c.header) for c in columns]
    if fmt == "csv":
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerows([headers, *cells])
        return text.getvalue()
    notes = table_notes(columns, rows)
    if fmt == "markdown":  # a | inside a cell (|L|, dt|w0|) would end it
        table = tabulate(
            [[_pipes(text) for text in line] for line in cells],
            [_pipes(text) for text in headers],
            tablefmt="github",
            colalign=align,
            disable_numparse=True,
        )
        return "\n\n".join([table, "\n".join(notes)])
    if fmt == "html":
        table = tabulate(cells, headers, tablefmt="html", colalign=align, disable_numparse=True)
        return f"{table}\n<p>" + "<br>\n".join(html.escape(note) for note in notes) + "</p>"
    raise ValueError(f"format_table: no format {fmt!r}; one of {', '.join(TABLE_FORMATS)}")


def _one_line(header):
    return header.replace("\n", " ")


def _pipes(text):
    return text.replace("|", "\\|")
