"""The per-scheme summary of a study, read from its dataset (never from a rerun).

For each scheme: the observed order of the final orientation error over the swept ``dt``
(fitted only over the asymptotic range, per value of every other swept axis), the error at
the largest ``dt``, the kernel time per body-step, and how many cases ended unstable.
"""

import numpy as np

from rbstudy.metrics import observed_order

__all__ = ["scheme_rows", "format_table", "ORDER_FLOOR", "ORDER_CEILING", "ERROR_MEASURE",
           "SUMMARY_VARIABLES"]

ERROR_MEASURE = "final_orientation_error"
# What `scheme_rows` reads: per-case scalars only.
SUMMARY_VARIABLES = ("status", "run_time", "n_steps", ERROR_MEASURE)
# The order fit skips errors at round-off (an orientation error of 1e-11 rad after a few
# hundred steps is the sum of per-step rounding) and errors too large to be asymptotic
# (0.1 rad: the error expansion no longer holds, or the run went unstable).
ORDER_FLOOR = 1e-11
ORDER_CEILING = 1e-1


def _per_scheme(ds, name, scheme):
    variable = ds[name]
    return variable.sel(scheme=scheme) if "scheme" in variable.dims else variable


def _orders(errors):
    """Observed orders over ``dt`` for every value of the other swept axes, and the dt used."""
    others = [d for d in errors.dims if d != "dt"]
    stacked = errors.stack(other=others) if others else errors.expand_dims(other=[0])
    dts = errors["dt"].values
    orders, used = [], np.zeros(dts.shape, dtype=bool)
    for k in range(stacked.sizes["other"]):
        order, mask = observed_order(dts, stacked.isel(other=k).values, ORDER_FLOOR,
                                     ORDER_CEILING)
        if np.isfinite(order):
            orders.append(order)
            used |= mask
    return orders, dts[used]


def scheme_rows(ds):
    """One dict per scheme: order (min, max) or None, the dt fitted, error at the largest dt,
    nanoseconds per body-step, unstable and total case counts."""
    schemes = [str(s) for s in np.atleast_1d(ds["scheme"].values)]
    rows = []
    for scheme in schemes:
        row = {"scheme": scheme, "order": None, "fit_dt": (), "error": None}
        status = _per_scheme(ds, "status", scheme)
        row["cases"] = int(status.size)
        row["unstable"] = int((status != 0).sum())
        per_step = _per_scheme(ds, "run_time", scheme) / _per_scheme(ds, "n_steps", scheme)
        row["ns_per_step"] = float(per_step.median()) * 1e9
        if ERROR_MEASURE in ds:
            errors = _per_scheme(ds, ERROR_MEASURE, scheme)
            if "dt" in errors.dims:
                orders, fitted = _orders(errors)
                if orders:
                    row["order"] = (min(orders), max(orders))
                    row["fit_dt"] = (float(fitted.min()), float(fitted.max()))
                largest = errors.sel(dt=errors["dt"].max())
                row["error_dt"] = float(errors["dt"].max())
                row["error"] = float(largest.max())
            else:
                row["error"] = float(errors.max())
        rows.append(row)
    return rows


def format_table(rows):
    """The rows as a fixed-width text table."""
    dt = next((row["error_dt"] for row in rows if "error_dt" in row), None)
    error_head = f"error at dt={dt:g} s" if dt is not None else "final error"
    lines = [f"{'scheme':10s} {'order':>11s} {'fit over dt (s)':>19s} {error_head:>22s} "
             f"{'ns/body-step':>12s}  stable"]
    for row in rows:
        order = "-" if row["order"] is None else (
            f"{row['order'][0]:.2f}" if row["order"][1] - row["order"][0] < 0.005
            else f"{row['order'][0]:.2f}-{row['order'][1]:.2f}")
        fit = "-" if not row["fit_dt"] else f"{row['fit_dt'][0]:.3g}..{row['fit_dt'][1]:.3g}"
        error = "-" if row["error"] is None or not np.isfinite(row["error"]) else \
            f"{row['error']:.3e} rad"
        stable = "yes" if not row["unstable"] else f"no: {row['unstable']}/{row['cases']} unstable"
        lines.append(f"{row['scheme']:10s} {order:>11s} {fit:>19s} {error:>22s} "
                     f"{row['ns_per_step']:12.1f}  {stable}")
    return "\n".join(lines)
