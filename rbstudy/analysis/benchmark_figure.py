"""The Abaqus benchmark figures of a symmetric body with nodes, the closed form overlaid:
global w against time, w_x against w_y, and a node's path seen down z.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr

# `figure_frame.save` is looked up when a figure is written, so that a test may keep the
# figures instead (tests/test_figures.py's drawn_figures)
from rbstudy.analysis import figure_frame
from rbstudy.analysis.figure_frame import FORMATS, RC, Figures, grid
from rbstudy.analysis.figure_lines import case_dims, line_styles, style_of
from rbstudy.analysis.figure_text import value_text
from rbstudy.analysis.summary import schemes_of
from rbstudy.numerics.state import OK
from rbstudy.physics.analytic import symmetric_top
from rbstudy.physics.metrics import node_positions
from rbstudy.physics.quaternions import quat_to_matrix

__all__ = ["BENCHMARK_PICKS", "BENCHMARK_NODE", "benchmark_case", "benchmark"]

# The benchmark figures show this case where the study has it (the Abaqus set-up: HHT on the
# flat disk, the node on the symmetry axis), else the first of each axis.
BENCHMARK_PICKS = {"scheme": "hht", "inertia_ratio": 2.0}
BENCHMARK_NODE = "4"


def benchmark_case(ds: xr.Dataset) -> tuple[xr.Dataset, str]:
    """The case the benchmark figures show (`BENCHMARK_PICKS`, the largest dt) and its name
    (``hht, inertia_ratio = 2``)."""
    case, named = ds, []
    for dim in case_dims(ds):
        if dim == "dt":
            case = case.sel(dt=ds["dt"].max())
        elif dim in BENCHMARK_PICKS and BENCHMARK_PICKS[dim] in list(ds[dim].values):
            case = case.sel({dim: BENCHMARK_PICKS[dim]})
        else:
            case = case.isel({dim: 0})
        if dim != "scheme":
            named.append(value_text(dim, case[dim].values[()]))
    return case, ", ".join([str(case["scheme"].values)] + named)


_BENCHMARK_NEEDS = (
    "precession_frequency",
    "node_offset",
    "node_displacement",
    "omega_space",
    "omega_body",
    "quaternion",
)


def benchmark(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str] = FORMATS,
    styles: Mapping[str, Sequence[str]] | None = None,
) -> Figures:
    """The Abaqus benchmark figures of a symmetric body with nodes, exact solution overlaid;
    the case's line in its scheme's style (``styles``: `rbstudy.analysis.figure_lines.line_styles`)."""
    figures = Figures()
    if any(name not in ds for name in _BENCHMARK_NEEDS):
        return figures
    case, what = benchmark_case(ds)
    color = style_of(str(case["scheme"].values), line_styles(schemes_of(ds), styles))["color"]
    if int(case["status"]) != OK:
        figures.absent["benchmark"] = f"the benchmark case ({what}) failed"
        return figures
    times = ds["time"].values
    q_exact, w_exact = symmetric_top(
        case["inertia"].values, case["quaternion"].values[0], case["omega_body"].values[0], times
    )
    w_space = np.einsum("tij,tj->ti", quat_to_matrix(q_exact), w_exact)
    with plt.rc_context(RC):
        fig, axes = grid(3, width=4.2, height=3.0)
        for k, ax in enumerate(axes):
            ax.plot(times, case["omega_space"].values[:, k], color=color, label=what)
            ax.plot(times, w_space[:, k], linestyle="--", color="k", linewidth=1, label="exact")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"global w_{'xyz'[k]} (rad/s)")
            ax.grid(True, alpha=0.3)
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2)
        fig.suptitle("global angular velocity against time (benchmark figures 2-4)")
        figures.written.append(figure_frame.save(fig, folder, ds, "benchmark_omega_time", formats))

        fig, ax = plt.subplots(figsize=(5.0, 5.2), layout="constrained")
        ax.plot(case["omega_space"].values[:, 0], case["omega_space"].values[:, 1], color=color, label=what)
        ax.plot(w_space[:, 0], w_space[:, 1], linestyle="--", color="k", linewidth=1, label="exact")
        ax.set_aspect("equal")
        ax.set_xlabel("global w_x (rad/s)")
        ax.set_ylabel("global w_y (rad/s)")
        fig.legend(loc="outside lower center", ncols=2)
        ax.grid(True, alpha=0.3)
        ax.set_title("w_x against w_y (benchmark figure 5)")
        figures.written.append(figure_frame.save(fig, folder, ds, "benchmark_omega_xy", formats))

        names = [str(n) for n in case["node"].values]
        node = BENCHMARK_NODE if BENCHMARK_NODE in names else names[-1]
        offset = case["node_offset"].sel(node=node).values
        start = node_positions(case["quaternion"].values[:1], np.zeros((1, 3)), offset[None])
        path = start[0, 0] + case["node_displacement"].sel(node=node).values
        exact = node_positions(q_exact, np.zeros((times.size, 3)), offset[None])[:, 0]
        fig, ax = plt.subplots(figsize=(5.0, 5.2), layout="constrained")
        ax.plot(path[:, 0], path[:, 1], color=color, label=what)
        ax.plot(exact[:, 0], exact[:, 1], linestyle="--", color="k", linewidth=1, label="exact")
        ax.set_aspect("equal")
        ax.locator_params(nbins=5)  # short tick labels that do not run into each other
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        fig.legend(loc="outside lower center", ncols=2)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"node {node} seen down global z (benchmark figure 6)")
        figures.written.append(figure_frame.save(fig, folder, ds, "benchmark_node_path", formats))
    return figures
