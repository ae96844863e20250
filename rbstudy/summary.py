"""The per-scheme summary of a study, read from its dataset (never from a rerun).

The error measures (`ERROR_MEASURES`) and their asymptotic ranges live here, shared by the
terminal table, the figures and the report. For each scheme, `scheme_rows` gives the
observed order of the final orientation error over the swept ``dt`` (fitted per value of
every other swept axis, only where the error is neither at round-off nor too large to be
asymptotic), the errors at the largest and smallest ``dt``, the kernel time per body-step,
the stable range in ``dt |w0|``, and which invariants every stable case kept.
"""

import numpy as np

from rbstudy.metrics import asymptotic_order

__all__ = ["ERROR_MEASURES", "SUMMARY_VARIABLES", "KEPT_TOLERANCE", "error_measure",
           "fitted_order", "scheme_rows", "format_table", "order_text"]

# name -> (label, units, floor, ceiling, stored variable). Errors below the floor are
# round-off (a geodesic angle of 1e-11 rad after a few hundred steps is the sum of per-step
# rounding; energy and |L| are relative to their start and sit lower), above the ceiling
# not asymptotic or unstable: the order fit leaves both out.
ERROR_MEASURES = {
    "orientation": ("final orientation error", "rad", 1e-11, 1e-1, "final_orientation_error"),
    "omega": ("max relative angular velocity error", "1", 1e-11, 1e-1, "omega_error"),
    "nodes": ("max node position error", "m", 1e-11, 1e-1, "node_error"),
    "energy": ("max relative energy error", "1", 1e-13, 1e-1, "max_energy_error"),
    "momentum": ("max relative |L| error", "1", 1e-13, 1e-1, "max_momentum_error"),
    "precession": ("|precession frequency error|", "rad/s", 1e-9, 1e-1,
                   "precession_frequency_error"),
    # zero crossings of samples placed by linear interpolation: ~1e-6 s at best
    "flip": ("|flip interval error|", "s", 1e-5, 1.0, "flip_interval_error"),
}
# What `scheme_rows` reads: per-case scalars only.
SUMMARY_VARIABLES = ("status", "run_time", "n_steps", "final_orientation_error",
                     "max_energy_error", "max_momentum_error", "initial_spin")
# An invariant counts as kept when its largest relative drift over every step of every
# stable case stays below this: round-off over 1e4-1e5 steps, far below any truncation error.
KEPT_TOLERANCE = 1e-10
_ORDER_MEASURE = "orientation"


def error_measure(ds, key):
    """|error measure| ``key`` of every case (time and nodes reduced by max), or None."""
    name = ERROR_MEASURES[key][4]
    if name not in ds:
        return None
    value = ds[name]
    reduce = [d for d in value.dims if d in ("time", "node")]
    return abs(value.max(reduce, skipna=False) if reduce else value)


def fitted_order(dts, errors, key):
    """Observed order of measure ``key`` over its asymptotic range: (order, used mask)."""
    _, _, floor, ceiling, _ = ERROR_MEASURES[key]
    return asymptotic_order(dts, errors, floor, ceiling)


def _per_scheme(variable, scheme):
    return variable.sel(scheme=scheme) if "scheme" in variable.dims else variable


def _orders(errors):
    """Observed orders over ``dt`` for every value of the other swept axes, and the dt used."""
    others = [d for d in errors.dims if d != "dt"]
    stacked = errors.stack(other=others) if others else errors.expand_dims(other=[0])
    dts = errors["dt"].values
    orders, used = [], np.zeros(dts.shape, dtype=bool)
    for k in range(stacked.sizes["other"]):
        order, mask = fitted_order(dts, stacked.isel(other=k).values, _ORDER_MEASURE)
        if np.isfinite(order):
            orders.append(order)
            used |= mask
    return orders, dts[used]


def _kept(ds, scheme, stable):
    kept = []
    for name, label in (("max_energy_error", "energy"), ("max_momentum_error", "|L|")):
        if name in ds:
            drift = _per_scheme(ds[name], scheme).values[stable]
            if drift.size and np.all(drift < KEPT_TOLERANCE):
                kept.append(label)
    return tuple(kept)


def scheme_rows(ds):
    """One dict per scheme.

    Keys: scheme; cases, unstable (counts); order ((min, max) or None) and fit_dt ((smallest,
    largest) dt fitted); error_dt / error (largest dt, worst case) and error_small_dt /
    error_small; ns_per_step (median kernel time per body-step); stable_hw (largest
    ``dt |w0|`` of a stable case), unstable_hw (smallest of an unstable one, NaN if none);
    kept (invariants every stable case kept to `KEPT_TOLERANCE`).
    """
    rows = []
    step = ds["dt"] if "dt" in ds.coords else None
    spin = ds["initial_spin"]
    for scheme in [str(s) for s in np.atleast_1d(ds["scheme"].values)]:
        status = _per_scheme(ds["status"], scheme)
        stable = status.values == 0
        row = {"scheme": scheme, "cases": int(status.size), "unstable": int((~stable).sum()),
               "order": None, "fit_dt": (), "error": None, "error_small": None}
        per_step = _per_scheme(ds["run_time"], scheme) / _per_scheme(ds["n_steps"], scheme)
        row["ns_per_step"] = float(per_step.median()) * 1e9
        load = (_per_scheme(step * spin, scheme).broadcast_like(status).values
                if step is not None else np.full(status.shape, np.nan))
        row["stable_hw"] = float(np.max(load[stable])) if stable.any() else np.nan
        row["unstable_hw"] = float(np.min(load[~stable])) if (~stable).any() else np.nan
        row["kept"] = _kept(ds, scheme, stable)
        errors = error_measure(ds, _ORDER_MEASURE)
        if errors is not None:
            errors = _per_scheme(errors, scheme)
            if "dt" in errors.dims:
                orders, fitted = _orders(errors)
                if orders:
                    row["order"] = (min(orders), max(orders))
                    row["fit_dt"] = (float(fitted.min()), float(fitted.max()))
                for key, pick in (("", errors["dt"].max()), ("_small", errors["dt"].min())):
                    row[f"error{key}_dt"] = float(pick)
                    row[f"error{key}"] = float(errors.sel(dt=pick).max())
            else:
                row["error"] = float(errors.max())
        rows.append(row)
    return rows


def order_text(row):
    """``2.00`` or ``1.98-2.01`` (the range over the other swept axes), ``-`` without a fit."""
    if row["order"] is None:
        return "-"
    low, high = row["order"]
    return f"{low:.2f}" if high - low < 0.005 else f"{low:.2f}-{high:.2f}"


def _short(value, spec=".1e"):
    return "-" if value is None or not np.isfinite(value) else f"{value:{spec}}"


def format_table(rows):
    """The rows as the fixed-width text table `rbstudy sweep` prints (the report's columns)."""
    large = next((row["error_dt"] for row in rows if "error_dt" in row), None)
    small = next((row["error_small_dt"] for row in rows if "error_small_dt" in row), None)
    head_large = f"err dt={large:g}" if large is not None else "final error"
    head_small = f"err dt={small:g}" if small is not None else ""
    lines = [f"{'scheme':10s} {'order':>10s} {'fit over dt (s)':>17s} {head_large:>13s} "
             f"{head_small:>15s} {'ns/step':>8s} {'stable dt|w0|<=':>15s} {'unstable':>9s}  kept"]
    for row in rows:
        fit = "-" if not row["fit_dt"] else f"{row['fit_dt'][0]:.3g}..{row['fit_dt'][1]:.3g}"
        lines.append(
            f"{row['scheme']:10s} {order_text(row):>10s} {fit:>17s} {_short(row['error']):>13s} "
            f"{_short(row.get('error_small')) if small is not None else '':>15s} "
            f"{row['ns_per_step']:8.0f} {_short(row['stable_hw'], '.3g'):>15s} "
            f"{row['unstable']:>4d}/{row['cases']:<4d}  {', '.join(row['kept']) or '-'}")
    lines.append("(errors: final orientation error in rad, worst over the other swept axes; "
                 "order fitted per value of the other axes)")
    return "\n".join(lines)
