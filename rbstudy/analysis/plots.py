"""Figures from archived results: never the solver, only the dataset (`rbstudy plot`).

Each figure function takes a dataset opened by `rbstudy.pipeline.store.open_results` and an output
folder, writes ``<name>.png`` and ``<name>.svg`` and returns the PNG paths it wrote (none
when the dataset lacks what the figure needs: no ``dt`` axis, no nodes, ...).

- `convergence`: error against dt, log-log, a line per scheme with its fitted order, and
  reference slopes; one figure per error measure.
- `work_precision`: run time per case against error, a line per scheme.
- `stability_map`: ``dt |w0|`` of every case against the swept parameter, stable and
  unstable marked, the largest stable value per scheme joined.
- `invariant_drift`: |energy| and |L| errors against time for one case per scheme.
- `benchmark`: the Abaqus figures (global w against time, w_x against w_y, a node's path
  seen down z) with the closed form overlaid.

Large sweeps stay readable: lines are the schemes (or, in a one-scheme study, the values of
a swept axis with at most `MAX_LINES` values); a further axis with at most `MAX_FACETS`
values becomes one panel per value; any other axis is reduced to its worst case (a failed
case makes the worst case a gap, never hidden), and the panel title says so.
"""

import pathlib

import matplotlib

matplotlib.use("Agg")  # files only; no display needed or wanted
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from rbstudy.analysis.summary import (  # noqa: E402
    ERROR_MEASURES,
    error_measure,
    fitted_order,
    per_scheme,
    schemes_of,
    step_load,
)
from rbstudy.physics.analytic import symmetric_top  # noqa: E402
from rbstudy.physics.metrics import node_positions  # noqa: E402
from rbstudy.physics.quaternions import quat_to_matrix  # noqa: E402

__all__ = ["MAX_FACETS", "MAX_LINES", "convergence", "work_precision", "stability_map",
           "invariant_drift", "benchmark", "all_figures", "CAPTIONS"]

MAX_FACETS = 4
MAX_LINES = 8
REFERENCE_ORDERS = (1, 2, 4)
# An invariant kept exactly has error 0, which log axes cannot show: it is drawn here.
ZERO_SHOWN_AT = 1e-17
# A swept parameter spanning more than this ratio gets a log axis in the stability map.
LOG_AXIS_RATIO = 50
# The benchmark figures show this case where the study has it (the Abaqus set-up: HHT on the
# flat disk, the node on the symmetry axis), else the first of each axis.
BENCHMARK_PICKS = {"scheme": "hht", "inertia_ratio": 2.0}
BENCHMARK_NODE = "4"
_FONT = {"font.size": 10, "axes.titlesize": 10, "legend.fontsize": 8,
         "figure.titlesize": 10}
_CASE_DIMS_EXCLUDED = ("time", "node", "axis", "component")


def _case_dims(ds):
    return [d for d in ds["status"].dims if d not in _CASE_DIMS_EXCLUDED]


def _layout(ds):
    """(line dim, facet dim, reduced dims) of a figure along dt.

    Lines are the schemes; a one-scheme study draws one line per value of its first other
    axis instead (if short enough). Then panels, then worst cases.
    """
    others = [d for d in _case_dims(ds) if d not in ("scheme", "dt")]
    if "scheme" in _case_dims(ds):
        line = "scheme"
    else:
        line = next((d for d in others if ds.sizes[d] <= MAX_LINES), None)
    others = [d for d in others if d != line]
    facet = next((d for d in others if ds.sizes[d] <= MAX_FACETS), None)
    return line, facet, [d for d in others if d != facet]


def _value_text(dim, value):
    shown = f"{value:g}" if isinstance(value, (float, np.floating)) else str(value)
    return f"{dim} = {shown}"


def _panel_title(dim, value, reduced):
    """``inertia_ratio = 0.5; worst over spin``: which cases a panel shows."""
    parts = [] if dim is None else [_value_text(dim, value)]
    if reduced:
        parts.append(f"worst over {', '.join(reduced)}")
    return "; ".join(parts)


def _lines(da, line):
    """(label, data) per line of a panel."""
    if line is None:
        return [("", da)]
    if line == "scheme":
        return [(scheme, per_scheme(da, scheme)) for scheme in schemes_of(da)]
    return [(_value_text(line, v), da.sel({line: v})) for v in da[line].values]


def _worst(da, reduced):
    """The worst case over ``reduced`` dims; a failed (NaN) case makes it NaN, never hidden."""
    return da.max(reduced, skipna=False) if reduced else da


def _plain_log_labels(fig):
    """Tick labels of log axes as plain text ("1e-05"): matplotlib's default typesets each
    one with mathtext, which made drawing a figure take seconds."""
    for ax in fig.axes:
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale == "log":
                low, high = axis.get_view_interval()
                axis.set_major_locator(LogLocator(numticks=8))
                axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.0e}"))
                # less than a decade shown: label the minor ticks at 2 and 5, or none would be
                short = 0 < low and high / low < 10
                axis.set_minor_formatter(FuncFormatter(_two_and_five) if short
                                         else NullFormatter())


def _two_and_five(value, _):
    mantissa = f"{value:.0e}"
    return mantissa if mantissa[0] in "25" else ""


def _save(fig, folder, name):
    _plain_log_labels(fig)
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    png = folder / f"{name}.png"
    fig.savefig(png, dpi=110)  # constrained layout fits the labels: no second "tight" pass
    fig.savefig(folder / f"{name}.svg")
    plt.close(fig)
    return png


def _grid(count, width=5.4, height=4.2, columns=2):
    columns = min(count, columns)
    rows = (count + columns - 1) // columns
    fig, axes = plt.subplots(rows, columns, figsize=(width * columns, height * rows),
                             squeeze=False, layout="constrained")
    for extra in axes.flat[count:]:
        extra.set_visible(False)
    return fig, list(axes.flat[:count])


def _title(fig, ds, what):
    fig.suptitle(f"{ds.attrs.get('title', '')}\n{what}", wrap=True)


def _reference_slopes(ax, dts, errors):
    finite = errors[np.isfinite(errors) & (errors > 0)]
    if finite.size == 0:
        return
    anchor_dt, anchor = dts.max(), np.median(finite)
    for order in REFERENCE_ORDERS:
        ax.plot(dts, anchor * (dts / anchor_dt) ** order, color="0.6", linestyle=":",
                linewidth=1)
        ax.annotate(f"order {order}", (dts.min(), anchor * (dts.min() / anchor_dt) ** order),
                    fontsize=7, color="0.4")


def convergence(ds, folder):
    """Error against dt per measure, fitted order per line in the legend."""
    if "dt" not in ds.dims:
        return []
    written = []
    dts = ds["dt"].values
    line_dim, facet, reduced = _layout(ds)
    values = list(ds[facet].values) if facet else [None]
    for key, (label, units, *_) in ERROR_MEASURES.items():
        measure = error_measure(ds, key)
        if measure is None or not (measure > 0).any():
            continue  # not stored, or exactly kept in every case: nothing to draw on log axes
        with plt.rc_context(_FONT):
            fig, axes = _grid(len(values))
            for ax, value in zip(axes, values, strict=True):
                panel = _worst(measure.sel({facet: value}) if facet else measure, reduced)
                ax.set_xscale("log")
                for name, data in _lines(panel, line_dim):
                    errors = data.values
                    order, used = fitted_order(dts, errors, key)
                    shown = f"{order:.2f}" if np.isfinite(order) else "n/a"
                    # zeros (an invariant kept exactly) have no place on log axes
                    line, = ax.plot(dts, np.where(errors > 0, errors, np.nan), marker="o",
                                    markersize=3, label=f"{name} (order {shown})".strip())
                    ax.plot(dts[used], errors[used], linestyle="none", marker="o",
                            markersize=6, markerfacecolor="none", color=line.get_color())
                if (panel.values > 0).any():
                    ax.set_yscale("log")
                    _reference_slopes(ax, dts, panel.values.ravel())
                else:
                    ax.text(0.5, 0.5, "zero in every case", transform=ax.transAxes,
                            ha="center")
                ax.set_xlabel("time step dt (s)")
                ax.set_ylabel(f"{label} ({units})")
                ax.set_title(_panel_title(facet, value, reduced))
                ax.grid(True, which="major", alpha=0.3)
                ax.legend(loc="lower right")  # lines rise to the right: this corner stays empty
            _title(fig, ds, f"convergence: {label}; circled points: the fitted asymptotic "
                            "range; gaps: failed cases")
            written.append(_save(fig, folder, f"convergence_{key}"))
    return written


def work_precision(ds, folder):
    """Run time per case against the final orientation error, a line per scheme over dt."""
    measure = error_measure(ds, "orientation")
    if measure is None or "dt" not in ds.dims:
        return []
    line_dim, facet, reduced = _layout(ds)
    values = list(ds[facet].values) if facet else [None]
    with plt.rc_context(_FONT):
        fig, axes = _grid(len(values))
        for ax, value in zip(axes, values, strict=True):
            pick = {facet: value} if facet else {}
            errors = _worst(measure.sel(pick), reduced)
            times = _worst(ds["run_time"].sel(pick), reduced)
            for (name, error_line), (_, time_line) in zip(_lines(errors, line_dim),
                                                          _lines(times, line_dim), strict=True):
                ax.loglog(error_line.values, time_line.values, marker="o", markersize=3,
                          label=name or None)
            ax.set_xlabel("final orientation error (rad)")
            ax.set_ylabel("run time per case (core-seconds)")
            ax.set_title(_panel_title(facet, value, reduced))
            ax.grid(True, which="major", alpha=0.3)
            if line_dim:
                ax.legend(loc="upper right")  # cost falls as error grows: this corner is empty
        _title(fig, ds, "work-precision: kernel CPU time of each batch divided among its "
                        "cases, compilation excluded; each point a dt")
        return [_save(fig, folder, "work_precision")]


def _parameter(ds):
    """The swept parameter of the stability map's x axis: (name, values per case, label) or
    None. A zipped dimension shows its first axis."""
    others = [d for d in _case_dims(ds) if d not in ("scheme", "dt")]
    if not others:
        return None
    dim = others[0]
    auxiliary = [name for name, c in ds.coords.items() if c.dims == (dim,) and name != dim]
    name = auxiliary[0] if auxiliary else dim
    units = ds[name].attrs.get("units")
    label = f"{name} ({units})" if units and units != "1" else name
    return name, ds[name].broadcast_like(ds["status"]), label


def stability_map(ds, folder):
    """``dt |w0|`` of every case against the swept parameter, one panel per scheme."""
    if "dt" not in ds.coords:
        return []
    load = step_load(ds)
    parameter = _parameter(ds)
    schemes = schemes_of(ds)
    with plt.rc_context(_FONT):
        fig, axes = _grid(len(schemes), width=3.4, height=2.9, columns=4)
        for ax, scheme in zip(axes, schemes, strict=True):
            status = per_scheme(ds["status"], scheme)
            y, ok = per_scheme(load, scheme).values.ravel(), status.values.ravel() == 0
            if parameter:
                name, values, label = parameter
                x = per_scheme(values, scheme).values.ravel()
                ax.set_xlabel(label)
                if np.all(x > 0) and x.max() / x.min() > LOG_AXIS_RATIO:
                    ax.set_xscale("log")
            else:
                x = np.zeros(y.size)
                ax.set_xticks([])
            ax.scatter(x[ok], y[ok], s=14, color="tab:green", label="stable")
            ax.scatter(x[~ok], y[~ok], s=22, marker="x", color="tab:red",
                       label="failed (unstable or not converged)")
            if parameter:
                xs = np.unique(x)
                largest = [y[ok & (x == v)].max() if (ok & (x == v)).any() else np.nan
                           for v in xs]
                ax.plot(xs, largest, color="tab:green", linewidth=1, label="largest stable")
            ax.set_yscale("log")
            ax.set_ylabel("dt |w0| (rad)")
            ax.set_title(scheme if (~ok).any() else f"{scheme}: all stable")
            ax.grid(True, alpha=0.3)
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=3)
        _title(fig, ds, "stability: every case by its dt |w0|")
        return [_save(fig, folder, "stability_map")]


def _drift_case(ds, scheme):
    """The case of ``scheme`` the drift figure shows, and its label: the largest dt with a
    stable case (by value), the first value of every other axis."""
    case = per_scheme(ds, scheme)
    named = [scheme]
    for dim in [d for d in _case_dims(case) if d != "dt"]:
        case = case.isel({dim: 0})
        named.append(_value_text(dim, case[dim].values[()]))
    if "dt" in case.dims:
        stable = case["dt"].values[case["status"].values == 0]
        if stable.size == 0:
            return None, None
        case = case.sel(dt=stable.max())
    if "dt" in case.coords:
        named.append(f"dt = {float(case['dt']):g} s")
    return case, ", ".join(named)


def invariant_drift(ds, folder):
    """|energy error| and |L| error against time, one case per scheme."""
    panels = [(name, label) for name, label in (("energy_error", "|relative energy error|"),
                                                ("momentum_error", "relative |L - L0|"))
              if name in ds]
    if not panels:
        return []
    with plt.rc_context(_FONT):
        fig, axes = _grid(len(panels))
        for ax, (name, label) in zip(axes, panels, strict=True):
            for scheme in schemes_of(ds):
                case, case_label = _drift_case(ds, scheme)
                if case is None:
                    continue
                values = np.maximum(np.abs(case[name].values), ZERO_SHOWN_AT)
                ax.semilogy(ds["time"].values, values, linewidth=1, label=case_label)
            ax.set_xlabel("time (s)")
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="best")
        _title(fig, ds, "invariant drift: bounded or secular; "
                        f"{ZERO_SHOWN_AT:g} stands for exactly zero")
        return [_save(fig, folder, "invariant_drift")]


def _benchmark_case(ds):
    case, named = ds, []
    for dim in _case_dims(ds):
        if dim == "dt":
            case = case.sel(dt=ds["dt"].max())
        elif dim in BENCHMARK_PICKS and BENCHMARK_PICKS[dim] in list(ds[dim].values):
            case = case.sel({dim: BENCHMARK_PICKS[dim]})
        else:
            case = case.isel({dim: 0})
        if dim != "scheme":
            named.append(_value_text(dim, case[dim].values[()]))
    return case, ", ".join([str(case["scheme"].values)] + named)


_BENCHMARK_NEEDS = ("precession_frequency", "node_offset", "node_displacement", "omega_space",
                    "omega_body", "quaternion")


def benchmark(ds, folder):
    """The Abaqus benchmark figures of a symmetric body with nodes, exact solution overlaid."""
    if any(name not in ds for name in _BENCHMARK_NEEDS):
        return []
    case, what = _benchmark_case(ds)
    times = ds["time"].values
    q_exact, w_exact = symmetric_top(case["inertia"].values, case["quaternion"].values[0],
                                     case["omega_body"].values[0], times)
    w_space = np.einsum("tij,tj->ti", quat_to_matrix(q_exact), w_exact)
    written = []
    with plt.rc_context(_FONT):
        fig, axes = _grid(3, width=4.2, height=3.0)
        for k, ax in enumerate(axes):
            ax.plot(times, case["omega_space"].values[:, k], label=what)
            ax.plot(times, w_space[:, k], linestyle="--", color="k", linewidth=1, label="exact")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"global w_{'xyz'[k]} (rad/s)")
            ax.grid(True, alpha=0.3)
        axes[0].legend(loc="best")
        fig.suptitle("global angular velocity against time (benchmark figures 2-4)")
        written.append(_save(fig, folder, "benchmark_omega_time"))

        fig, ax = plt.subplots(figsize=(5.0, 4.8), layout="constrained")
        ax.plot(case["omega_space"].values[:, 0], case["omega_space"].values[:, 1], label=what)
        ax.plot(w_space[:, 0], w_space[:, 1], linestyle="--", color="k", linewidth=1,
                label="exact")
        ax.set_aspect("equal")
        ax.set_xlabel("global w_x (rad/s)")
        ax.set_ylabel("global w_y (rad/s)")
        ax.legend(loc="best")
        ax.grid(True, alpha=0.3)
        ax.set_title("w_x against w_y (benchmark figure 5)")
        written.append(_save(fig, folder, "benchmark_omega_xy"))

        names = [str(n) for n in case["node"].values]
        node = BENCHMARK_NODE if BENCHMARK_NODE in names else names[-1]
        offset = case["node_offset"].sel(node=node).values
        start = node_positions(case["quaternion"].values[:1], np.zeros((1, 3)), offset[None])
        path = start[0, 0] + case["node_displacement"].sel(node=node).values
        exact = node_positions(q_exact, np.zeros((times.size, 3)), offset[None])[:, 0]
        fig, ax = plt.subplots(figsize=(5.0, 4.8), layout="constrained")
        ax.plot(path[:, 0], path[:, 1], label=what)
        ax.plot(exact[:, 0], exact[:, 1], linestyle="--", color="k", linewidth=1, label="exact")
        ax.set_aspect("equal")
        ax.locator_params(nbins=5)  # short tick labels that do not run into each other
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="best")
        ax.grid(True, alpha=0.3)
        ax.set_title(f"node {node} seen down global z (benchmark figure 6)")
        written.append(_save(fig, folder, "benchmark_node_path"))
    return written


# What each figure shows, for the report (keyed by file name without the measure suffix).
CAPTIONS = {
    "convergence": "Error against the time step, log-log, one line per scheme (or per value "
                   "of the swept axis in a one-scheme study); the legend gives the order "
                   "fitted on the circled points, the asymptotic range (see the table); "
                   "dotted lines are slopes 1, 2 and 4; a gap is a failed case.",
    "work_precision": "Kernel run time per case against the final orientation error, one "
                      "point per dt: the cheapest scheme for a given accuracy is the lowest "
                      "line. Run time is the CPU time of the compiled batch call divided "
                      "among its cases, compilation excluded.",
    "stability_map": "Every case by its dt |w0| against the swept parameter: green stable, "
                     "red crosses failed; the line joins the largest stable value.",
    "invariant_drift": "Energy and angular-momentum errors against time for one case per "
                       "scheme, named in the legend (the largest stable dt when dt is swept; "
                       "a failed case ends where it failed): bounded oscillation or secular "
                       "growth.",
    "benchmark": "The Abaqus benchmark figures for the case named in the legend (HHT on the "
                 "flat disk at the largest dt where the study has it), with the closed-form "
                 "solution dashed.",
}


def all_figures(ds, folder):
    """Every figure the dataset supports; returns the PNG paths."""
    written = []
    for figure in (convergence, work_precision, stability_map, invariant_drift, benchmark):
        written += figure(ds, folder)
    return written
