"""Figures from archived results: never the solver, only the dataset (`rbstudy plot`).

Each figure function takes a dataset opened by `rbstudy.store.open_results` and an output
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

Large sweeps stay readable: a swept axis with at most `MAX_FACETS` values becomes one panel
per value; a longer one is reduced to its worst case, and the title says so.
"""

import pathlib

import matplotlib

matplotlib.use("Agg")  # files only; no display needed or wanted
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter  # noqa: E402

from rbstudy.analytic import symmetric_top  # noqa: E402
from rbstudy.metrics import node_positions  # noqa: E402
from rbstudy.quaternions import quat_to_matrix  # noqa: E402
from rbstudy.summary import ERROR_MEASURES, error_measure, fitted_order  # noqa: E402

__all__ = ["MAX_FACETS", "convergence", "work_precision", "stability_map", "invariant_drift",
           "benchmark", "all_figures", "CAPTIONS"]

MAX_FACETS = 4
REFERENCE_ORDERS = (1, 2, 4)
_FONT = {"font.size": 10, "axes.titlesize": 11, "legend.fontsize": 8}
_CASE_DIMS_EXCLUDED = ("time", "node", "axis", "component")


def _case_dims(ds):
    return [d for d in ds["status"].dims if d not in _CASE_DIMS_EXCLUDED]


def _facets(ds, skip):
    """(facet dim or None, its values, dims reduced to their worst case) for a figure that
    plots along ``skip`` dims."""
    others = [d for d in _case_dims(ds) if d not in skip]
    facet = next((d for d in others if ds.sizes[d] <= MAX_FACETS), None)
    reduced = [d for d in others if d != facet]
    values = list(ds[facet].values) if facet else [None]
    return facet, values, reduced


def _panel_title(dim, value, reduced):
    """``inertia_ratio = 0.5 (worst over spin)``: which cases a panel shows."""
    parts = []
    if dim is not None:
        shown = f"{value:g}" if isinstance(value, (float, np.floating)) else str(value)
        parts.append(f"{dim} = {shown}")
    if reduced:
        parts.append(f"worst over {', '.join(reduced)}")
    return "; ".join(parts)


def _schemes(ds):
    return [str(s) for s in np.atleast_1d(ds["scheme"].values)]


def _per_scheme(da, scheme):
    return da.sel(scheme=scheme) if "scheme" in da.dims else da


def _plain_log_labels(fig):
    """Tick labels of log axes as plain text ("1e-05"): matplotlib's default typesets each
    one with mathtext, which made drawing a figure take seconds."""
    for ax in fig.axes:
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale == "log":
                low, high = axis.get_view_interval()
                axis.set_major_locator(LogLocator(numticks=8))
                axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:.0e}"))
                # less than a decade shown: label the minor ticks too, or none would be
                axis.set_minor_formatter(FuncFormatter(lambda v, _: f"{v:.1g}")
                                         if 0 < low and high / low < 10 else NullFormatter())


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


def _worst(da, reduced):
    return da.max(reduced) if reduced else da


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
    """Error against dt per measure, fitted order per scheme in the legend."""
    if "dt" not in ds.dims:
        return []
    written = []
    dts = ds["dt"].values
    for key, (label, units, *_) in ERROR_MEASURES.items():
        measure = error_measure(ds, key)
        if measure is None or not (measure > 0).any():
            continue  # not stored, or exactly kept in every case: nothing to draw on log axes
        facet, values, reduced = _facets(ds, ("scheme", "dt"))
        with plt.rc_context(_FONT):
            fig, axes = _grid(len(values))
            for ax, value in zip(axes, values, strict=True):
                panel = measure.sel({facet: value}) if facet else measure
                panel = _worst(panel, reduced)
                ax.set_xscale("log")
                for scheme in _schemes(ds):
                    errors = _per_scheme(panel, scheme).values
                    order, used = fitted_order(dts, errors, key)
                    shown = f"{order:.2f}" if np.isfinite(order) else "n/a"
                    # zeros (an invariant kept exactly) have no place on log axes
                    shown_errors = np.where(errors > 0, errors, np.nan)
                    line, = ax.plot(dts, shown_errors, marker="o", markersize=3,
                                    label=f"{scheme} (order {shown})")
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
            fig.suptitle(f"{ds.attrs.get('title', '')}\nconvergence: {label}; circled points "
                         "are those the order is fitted on")
            written.append(_save(fig, folder, f"convergence_{key}"))
    return written


def work_precision(ds, folder):
    """Run time per case against the final orientation error, a line per scheme over dt."""
    measure = error_measure(ds, "orientation")
    if measure is None or "dt" not in ds.dims:
        return []
    facet, values, reduced = _facets(ds, ("scheme", "dt"))
    with plt.rc_context(_FONT):
        fig, axes = _grid(len(values))
        for ax, value in zip(axes, values, strict=True):
            errors = measure.sel({facet: value}) if facet else measure
            times = ds["run_time"].sel({facet: value}) if facet else ds["run_time"]
            errors, times = _worst(errors, reduced), _worst(times, reduced)
            for scheme in _schemes(ds):
                ax.loglog(_per_scheme(errors, scheme).values, _per_scheme(times, scheme).values,
                          marker="o", markersize=3, label=scheme)
            ax.set_xlabel("final orientation error (rad)")
            ax.set_ylabel("run time per case (core-seconds)")
            ax.set_title(_panel_title(facet, value, reduced))
            ax.grid(True, which="major", alpha=0.3)
            ax.legend(loc="upper right")  # cost falls as error grows: this corner stays empty
        fig.suptitle(f"{ds.attrs.get('title', '')}\nwork-precision: kernel CPU time of each "
                     "batch divided among its cases, compilation excluded; each point a dt")
        return [_save(fig, folder, "work_precision")]


def stability_map(ds, folder):
    """``dt |w0|`` of every case against the swept parameter, per scheme."""
    step = ds["dt"] if "dt" in ds.coords else None
    if step is None:
        return []
    load = (step * ds["initial_spin"]).broadcast_like(ds["status"])
    others = [d for d in _case_dims(ds) if d not in ("scheme", "dt")]
    parameter = others[0] if others else None
    schemes = _schemes(ds)
    with plt.rc_context(_FONT):
        fig, axes = _grid(len(schemes), width=3.4, height=2.9, columns=4)
        for ax, scheme in zip(axes, schemes, strict=True):
            status = _per_scheme(ds["status"], scheme)
            h_w = _per_scheme(load, scheme)
            if parameter:
                x = ds[parameter].broadcast_like(status).values.ravel()
                ax.set_xlabel(parameter)
                if np.all(x > 0) and x.max() / x.min() > 50:
                    ax.set_xscale("log")
            else:
                x = np.zeros(status.size)
                ax.set_xticks([])
            y, ok = h_w.values.ravel(), status.values.ravel() == 0
            ax.scatter(x[ok], y[ok], s=14, color="tab:green", label="stable")
            ax.scatter(x[~ok], y[~ok], s=22, marker="x", color="tab:red", label="unstable")
            if parameter:
                xs = np.unique(x)
                largest = [y[ok & (x == v)].max() if (ok & (x == v)).any() else np.nan
                           for v in xs]
                ax.plot(xs, largest, color="tab:green", linewidth=1, label="largest stable")
            ax.set_yscale("log")
            ax.set_ylabel("dt |w0| (rad)")
            ax.set_title(scheme if (~ok).any() else f"{scheme}: all stable")
            ax.grid(True, alpha=0.3)
        axes[0].legend(loc="best")
        fig.suptitle(f"{ds.attrs.get('title', '')}\nstability: every case, by its dt |w0|")
        return [_save(fig, folder, "stability_map")]


def _drift_case(ds, scheme):
    """The case of ``scheme`` shown in drift plots: the largest stable dt, first values of
    the other axes."""
    case = _per_scheme(ds, scheme)
    for dim in [d for d in _case_dims(case) if d != "dt"]:
        case = case.isel({dim: 0})
    if "dt" in case.dims:
        stable = case["status"].values == 0
        if not stable.any():
            return None
        case = case.isel(dt=int(np.argmax(stable)))  # dt runs from large to small
    return case


def invariant_drift(ds, folder):
    """|energy error| and |L| error against time, one case per scheme."""
    if "energy_error" not in ds:
        return []
    with plt.rc_context(_FONT):
        fig, axes = _grid(2)
        for ax, name, label in ((axes[0], "energy_error", "|relative energy error|"),
                                (axes[1], "momentum_error", "relative |L - L0|")):
            for scheme in _schemes(ds):
                case = _drift_case(ds, scheme)
                if case is None:
                    continue
                dt = f", dt = {float(case['dt']):g} s" if "dt" in case.coords else ""
                values = np.maximum(np.abs(case[name].values), 1e-17)  # log axes: 0 shown at 1e-17
                ax.semilogy(ds["time"].values, values, linewidth=1, label=f"{scheme}{dt}")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
            ax.legend(loc="best")
        fig.suptitle(f"{ds.attrs.get('title', '')}\ninvariant drift: bounded (symplectic, "
                     "energy-conserving) or secular; 1e-17 stands for exactly zero")
        return [_save(fig, folder, "invariant_drift")]


def _benchmark_case(ds):
    case = ds
    picks = {"scheme": "hht", "inertia_ratio": 2.0}
    for dim in _case_dims(ds):
        if dim == "dt":
            case = case.isel(dt=0)
        elif dim in picks and picks[dim] in list(ds[dim].values):
            case = case.sel({dim: picks[dim]})
        else:
            case = case.isel({dim: 0})
    return case


def benchmark(ds, folder):
    """The Abaqus benchmark figures of a symmetric body with nodes, exact solution overlaid."""
    if "precession_frequency" not in ds or "node_offset" not in ds:
        return []
    case = _benchmark_case(ds)
    times = ds["time"].values
    q_exact, w_exact = symmetric_top(case["inertia"].values, case["quaternion"].values[0],
                                     case["omega_body"].values[0], times)
    w_space = np.einsum("tij,tj->ti", quat_to_matrix(q_exact), w_exact)
    what = f"{case['scheme'].values}" + (f", dt = {float(case['dt']):g} s"
                                          if "dt" in case.coords else "")
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

        node = str(case["node"].values[-1])
        offset = case["node_offset"].sel(node=node).values
        start = node_positions(case["quaternion"].values[:1], np.zeros((1, 3)), offset[None])
        path = start[0, 0] + case["node_displacement"].sel(node=node).values
        exact = node_positions(q_exact, np.zeros((times.size, 3)), offset[None])[:, 0]
        fig, ax = plt.subplots(figsize=(5.0, 4.8), layout="constrained")
        ax.plot(path[:, 0], path[:, 1], label=what)
        ax.plot(exact[:, 0], exact[:, 1], linestyle="--", color="k", linewidth=1, label="exact")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="best")
        ax.grid(True, alpha=0.3)
        ax.set_title(f"node {node} seen down global z (benchmark figure 6)")
        written.append(_save(fig, folder, "benchmark_node_path"))
    return written


# What each figure shows, for the report (keyed by file name without the measure suffix).
CAPTIONS = {
    "convergence": "Error against the time step, log-log, one line per scheme; the legend "
                   "gives the order fitted on the circled points (the asymptotic range: "
                   "neither at round-off nor above 0.1); dotted lines are slopes 1, 2 and 4.",
    "work_precision": "Kernel run time per case against the final orientation error, one "
                      "point per dt: the cheapest scheme for a given accuracy is the lowest "
                      "line. Run time is the CPU time of the compiled batch call divided "
                      "among its cases, compilation excluded.",
    "stability_map": "Every case by its dt |w0| against the swept parameter: green stable, "
                     "red crosses unstable; the line joins the largest stable value.",
    "invariant_drift": "Energy and angular-momentum errors against time for one case per "
                       "scheme (largest stable dt): bounded oscillation or secular growth.",
    "benchmark": "The Abaqus benchmark figures for HHT at the largest dt on the flat disk, "
                 "with the closed-form solution dashed.",
}


def all_figures(ds, folder):
    """Every figure the dataset supports; returns the PNG paths."""
    written = []
    for figure in (convergence, work_precision, stability_map, invariant_drift, benchmark):
        written += figure(ds, folder)
    return written
