"""What every figure is drawn in and written as: the look (`RC`), the grid of panels, the
one legend beside them, log ticks that read as their values, and the files (`save`,
`Figures`: what a figure function wrote and what it left out, and why).
"""

from __future__ import annotations

import os
import pathlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")  # files only; no display needed or wanted
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.font_manager import FontProperties  # noqa: E402
from matplotlib.legend_handler import HandlerTuple  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter, NullLocator  # noqa: E402

from rbstudy.analysis.figure_text import em_width, wrapped  # noqa: E402
from rbstudy.archive.files import inside  # noqa: E402

if TYPE_CHECKING:
    from matplotlib.typing import RcKeyType

__all__ = [
    "RC",
    "FORMATS",
    "ALL_FORMATS",
    "LEGEND_WIDTH",
    "Figures",
    "figure_name",
    "grid",
    "save",
    "log_labels",
    "figure_legend",
]

# No "1e-7 + 6.28691" offsets on linear axes: every tick reads as its value.
RC: dict[RcKeyType, Any] = {
    "font.size": 10,
    "axes.titlesize": 10,
    "legend.fontsize": 8,
    "figure.titlesize": 10,
    "axes.formatter.useoffset": False,
}
# File formats: PNG by default (an SVG is slower to write); SVG on request.
FORMATS = ("png",)
ALL_FORMATS = ("png", "svg")
# Inches beside the panels for a figure's legend of scheme names and fitted orders, as
# `grid` reserves them; `figure_legend` then sets the legend's own width, at most
# LEGEND_MAX_WIDTH inches (longer labels wrap). LEGEND_FRAME_EM: the handles, the gap to the
# text and the frame, in em of the legend's font; LEGEND_LINE_EM: the height of a line of it.
LEGEND_WIDTH = 3.4
LEGEND_MAX_WIDTH = 4.6
LEGEND_FRAME_EM = 7.0
LEGEND_LINE_EM = 1.75


@dataclass
class Figures:
    """The PNG files written, and why each figure not drawn was left out (name -> reason)."""

    written: list[pathlib.Path] = field(default_factory=list)
    absent: dict[str, str] = field(default_factory=dict)

    def __iadd__(self, other: Figures) -> Figures:
        self.written += other.written
        self.absent.update(other.absent)
        return self


def figure_name(ds: xr.Dataset, name: str) -> str:
    """``<study>_<name>``: figures of several studies can share a folder."""
    return f"{ds.attrs.get('study', 'results')}_{name}"


def _power_of_ten(value: float, _position: Any = None) -> str:
    """``10^{-2}``, ``2x10^{-3}`` or ``1.5x10^{-2}`` in mathtext: the tick label of a log
    axis, its mantissa to three digits, so that no tick reads as a value it is not (a tick
    at 0.015 once read "2x10^{-2}")."""
    exponent = int(np.floor(np.log10(value) + 1e-9))
    mantissa = float(f"{value / 10.0**exponent:.3g}")
    if mantissa == 1:
        return f"$10^{{{exponent}}}$"
    return f"${mantissa:g}\\times10^{{{exponent}}}$"


def log_labels(fig: Figure) -> None:
    """Tick labels of log axes as powers of ten, a few labelled ticks per axis: matplotlib's
    default labels every minor tick it may need, each typeset with mathtext, which is slow;
    at most eight labels an axis cost no more than plain text."""
    for ax in fig.axes:
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale == "log":
                low, high = axis.get_view_interval()
                # under two decades shown: ticks at 1, 2 and 5 of each decade (under one,
                # also at 3), or a single tick (or none) would be labelled; no
                # unlabelled minor ticks between them (a good share of each figure's
                # drawing time). Where even those leave one tick, matplotlib places linear ones.
                ratio = high / low if low > 0 else np.inf
                short = ratio < 100
                subs = (1.0, 2.0, 5.0) if ratio >= 10 else (1.0, 2.0, 3.0, 5.0)
                axis.set_major_locator(LogLocator(subs=subs) if short else LogLocator(numticks=8))
                axis.set_major_formatter(FuncFormatter(_power_of_ten))
                if short:
                    axis.set_minor_locator(NullLocator())
                else:
                    axis.set_minor_formatter(NullFormatter())


def save(
    fig: Figure, folder: str | os.PathLike[str], ds: xr.Dataset, name: str, formats: Sequence[str]
) -> pathlib.Path:
    """Write the figure in each of ``formats``; returns the first file."""
    log_labels(fig)
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [inside(folder, f"{figure_name(ds, name)}.{suffix}") for suffix in formats]
    for path in paths:  # constrained layout fits the labels: no second "tight" pass
        fig.savefig(path, dpi=110)
    plt.close(fig)
    return paths[0]


def grid(
    count: int, width: float = 5.4, height: float = 4.2, columns: int = 2, legend_width: float = 0.0
) -> tuple[Figure, list[Axes]]:
    """``count`` panels of ``width`` x ``height`` inches, and ``legend_width`` inches beside
    them for the figure's legend."""
    columns = min(count, columns)
    rows = (count + columns - 1) // columns
    fig, axes = plt.subplots(
        rows,
        columns,
        figsize=(width * columns + legend_width, height * rows),
        squeeze=False,
        layout="constrained",
    )
    for extra in axes.flat[count:]:
        extra.set_visible(False)
    return fig, list(axes.flat[:count])


def figure_legend(fig: Figure, entries: list[tuple[list[Any], str]], reserved: float) -> None:
    """One legend for the whole figure, right of its panels: ``entries`` are (handles,
    label), several handles drawn side by side for lines named together. The figure was made
    ``reserved`` inches wider than its panels for it; it takes the legend's own width
    instead (estimated from its labels, `em_width`), so that twenty schemes' names never
    squeeze the panels. A label wider than `LEGEND_MAX_WIDTH` wraps, and the figure grows
    taller where the legend's lines need it."""
    if not entries:
        return
    points = FontProperties(size=plt.rcParams["legend.fontsize"]).get_size_in_points()
    longest = max(em_width(label) for _, label in entries)
    text_em = min(longest, (LEGEND_MAX_WIDTH - LEGEND_FRAME_EM * points / 72) * 72 / points)
    labels = [wrapped(label, text_em) for _, label in entries]
    width = (text_em + LEGEND_FRAME_EM) * points / 72
    fig.set_figwidth(fig.get_figwidth() - reserved + width)
    lines = sum(label.count("\n") + 1 for label in labels)
    fig.set_figheight(max(fig.get_figheight(), (lines * LEGEND_LINE_EM + 2) * points / 72 + 1.2))
    fig.legend(  # type: ignore[call-overload]  # tuples of handles, which HandlerTuple draws
        [tuple(handles) for handles, _ in entries],
        labels,
        handler_map={tuple: HandlerTuple(ndivide=None, pad=0.6)},
        loc="outside right center",
    )
