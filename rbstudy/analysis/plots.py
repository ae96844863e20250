"""Figures from archived results: never the solver, only the dataset (`rbstudy plot`).

Each figure function takes a dataset opened by `rbstudy.archive.load.open_results`, an
output folder and the file formats (`FORMATS`: PNG; SVG on request), writes
``<study>_<name>.<format>`` and returns a `Figures`: the files it wrote (in the first
format), and for each figure it could have drawn but did not, the reason (it would have
nothing to show).

- `convergence`: error against dt, log-log, a line per scheme with its fitted order and the
  slope of the finest fitted pair, and reference slopes; one figure per error measure, drawn
  only when at least one line has an asymptotic range.
- `work_precision`: run time per case against error, a line per scheme.
- `stability_map`: every case marked accurate, finished but inaccurate, or failed by its
  ``dt |w0|``: a strip chart (a row per scheme) when each scheme's cases lie along one axis,
  else a panel per scheme with a boundary against the swept parameter, the largest accurate
  value joined (a named parameter, such as a Radioss option, one column per name); the
  OpenRadioss limit ``dt |w| = 1`` where some case passed it. Not drawn when every case is
  accurate.
- `invariant_drift`: |energy| and |L - L0| errors against time for one case per scheme, the
  case and how it was chosen named once in the title.
- `benchmark`: the Abaqus figures (global w against time, w_x against w_y, a node's path
  seen down z) with the closed form overlaid.

Every scheme keeps one colour, marker and line style in every figure: the style it registers
(`rbstudy.schemes.Style`, in the scheme's own file), which the command line reads from the
registry and hands to the figure functions (``styles``: this layer never loads the schemes);
a scheme without one gets a style no other line of the study wears (`line_styles`). Schemes
whose values agree to 3 digits (`rbstudy.analysis.overlaps`, round-off aside) are drawn on top of each
other, differing in marker and dash so that both stay visible, and named together in every
figure type ("euler = leapfrog to 3 digits": in the legend of a convergence or
work-precision figure, over each invariant-drift panel); lines that agree so in one panel
only are named over it, the legend's pairs not again, and so are lines that differ but lie
within a line's width of each other on the page ("euler ≈ leapfrog (within 1.4%)"; both
tests in `rbstudy.analysis.overlaps`). A figure has one
legend, outside the data. An exact zero, which log axes cannot show, lies on a floor line labelled
"0 (exact)", its line running down to it, with its own mark and legend entry ("exact
zero"); a gap is a failed case, or a case without a reference (its DOP853 reference passed
its step budget: `reference = none`). The slope guides' labels sit where their boxes cover
no line (`figure_marks.clear_labels`). The work-precision figure draws the accuracy bound and
marks the findings' recommendation.

Large sweeps stay readable: lines are the schemes (or, in a one-scheme study, the values of
a swept axis with at most `MAX_LINES` values); a further axis with at most `MAX_FACETS`
values becomes one panel per value; any other axis is reduced to a band (`band`): the line
is its worst case over the cases that gave a value, a thin dotted line its best, the legend
counts the cases that gave none (failed or unjudged) and gives the orders fitted value by
value; the panel title says so.
"""

import contextlib
import json
import multiprocessing
import pathlib
import shutil
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import matplotlib

matplotlib.use("Agg")  # files only; no display needed or wanted
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.font_manager import FontProperties  # noqa: E402
from matplotlib.legend_handler import HandlerTuple  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter, NullLocator  # noqa: E402

from rbstudy.analysis.figure_marks import (  # noqa: E402
    BOUND_STYLE,
    RECOMMENDED_STYLE,
    band,
    bound_label,
    clear_labels,
    recommended_point,
    zero_entry,
    zero_marks,
)
from rbstudy.analysis.findings import calibrated, case_seconds  # noqa: E402
from rbstudy.analysis.overlaps import coincident, near_lines, panel_overlaps, together  # noqa: E402
from rbstudy.analysis.summary import (  # noqa: E402
    ERROR_MEASURES,
    UNCERTAINTY_FACTOR,
    at_floor,
    error_measure,
    fitted_order,
    per_scheme,
    round_off_of,
    schemes_of,
    span,
    step_load,
    uncertainty_of,
    verdicts,
)
from rbstudy.archive.files import inside, write_text_atomic
from rbstudy.errors import counted  # noqa: E402
from rbstudy.numerics.state import OK, RADIOSS_STEP_ANGLE, STATUSES  # noqa: E402
from rbstudy.physics.analytic import REFERENCE_KINDS, symmetric_top  # noqa: E402
from rbstudy.physics.metrics import node_positions  # noqa: E402
from rbstudy.physics.quaternions import quat_to_matrix  # noqa: E402
from rbstudy.pipeline.progress import SILENT  # noqa: E402

__all__ = [
    "MAX_FACETS",
    "MAX_LINES",
    "line_styles",
    "ZERO_LABEL",
    "FORMATS",
    "ALL_FORMATS",
    "Figures",
    "convergence",
    "work_precision",
    "stability_map",
    "invariant_drift",
    "benchmark",
    "all_figures",
    "CAPTIONS",
    "figure_name",
    "figure_layout",
    "benchmark_case",
    "zero_floor",
    "plot_with_zeros",
]

MAX_FACETS = 4
MAX_LINES = 8
REFERENCE_ORDERS = (1, 2, 4)
# A slope guide spans three consecutive steps (a factor 4 when dt is halved), two where
# three do not fit the errors' range; it keeps this many decades clear of every line, and
# its place is searched on a grid of this many decades.
GUIDE_STEPS = 3
GUIDE_CLEARANCE = 0.5
GUIDE_GRID = 0.125
# Inches beside the panels for a figure's legend of scheme names and fitted orders, as
# `_grid` reserves them; `_figure_legend` then sets the legend's own width, at most
# LEGEND_MAX_WIDTH inches (longer labels wrap). LEGEND_FRAME_EM: the handles, the gap to the
# text and the frame, in em of the legend's font; LEGEND_LINE_EM: the height of a line of it.
LEGEND_WIDTH = 3.4
LEGEND_MAX_WIDTH = 4.6
LEGEND_FRAME_EM = 7.0
LEGEND_LINE_EM = 1.75
# Inches per scheme row of the stability strip chart.
STRIP_ROW_HEIGHT = 0.32
# A swept parameter spanning more than this ratio gets a log axis in the stability map.
LOG_AXIS_RATIO = 50
# The benchmark figures show this case where the study has it (the Abaqus set-up: HHT on the
# flat disk, the node on the symmetry axis), else the first of each axis.
BENCHMARK_PICKS = {"scheme": "hht", "inertia_ratio": 2.0}
BENCHMARK_NODE = "4"
# No "1e-7 + 6.28691" offsets on linear axes: every tick reads as its value.
_RC = {
    "font.size": 10,
    "axes.titlesize": 10,
    "legend.fontsize": 8,
    "figure.titlesize": 10,
    "axes.formatter.useoffset": False,
}
_CASE_DIMS_EXCLUDED = ("time", "node", "axis", "component")
_NO_REFERENCE = REFERENCE_KINDS.index("none")

# (colour, marker, line style) of lines that are not schemes (the values of a swept axis), in
# turn; a scheme that registers no style (`rbstudy.schemes.Style`) takes the first of them no
# registered line of the study wears, then the same colours with `_MORE_MARKERS`.
_OTHER_STYLES = [
    ("tab:blue", "o", "-"),
    ("tab:orange", "s", "--"),
    ("tab:green", "^", "-."),
    ("tab:red", "D", ":"),
    ("tab:purple", "v", "-"),
    ("tab:brown", "P", "--"),
    ("tab:pink", "X", "-."),
    ("tab:gray", "*", ":"),
]
_MORE_MARKERS = ("<", ">", "h", "d", "p", "8", "H", "x")
ZERO_LABEL = "0 (exact)"
# File formats: PNG by default (an SVG takes as long again to write); SVG on request.
FORMATS = ("png",)
ALL_FORMATS = ("png", "svg")


@dataclass
class Figures:
    """The PNG files written, and why each figure not drawn was left out (name -> reason)."""

    written: list = field(default_factory=list)
    absent: dict = field(default_factory=dict)

    def __iadd__(self, other):
        self.written += other.written
        self.absent.update(other.absent)
        return self


def figure_name(ds, name):
    """``<study>_<name>``: figures of several studies can share a folder."""
    return f"{ds.attrs.get('study', 'results')}_{name}"


def _case_dims(ds):
    return [d for d in ds["status"].dims if d not in _CASE_DIMS_EXCLUDED]


def figure_layout(ds):
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


def _panel_title(dim, value, reduced, lines="line: worst, thin dots: best"):
    """``inertia_ratio = 0.5; line: worst, thin dots: best, over spin``: which cases a
    panel shows, its ``lines`` over the ``reduced`` axes (`band`)."""
    parts = [] if dim is None else [_value_text(dim, value)]
    if reduced:
        parts.append(f"{lines}, over {', '.join(reduced)}")
    return "; ".join(parts)


class _Line(NamedTuple):
    """One line of a panel: its legend ``label``, the key of its style (a scheme, or the
    line's index) and its ``data``."""

    label: str
    key: Any
    data: Any


class _FittedLine(NamedTuple):
    """A line of a convergence panel: its `_Line` label and style key, its ``errors`` (one per
    dt), the order ``fit`` through them (`fitted_order`), whether a case ``failed`` on it, and
    per dt the reference's uncertainty (``limits``) and the round-off floor (``floors``)."""

    label: str
    key: Any
    errors: np.ndarray
    fit: Any
    failed: bool
    limits: np.ndarray
    floors: np.ndarray


class _CostLine(NamedTuple):
    """A line of a work-precision panel: its `_Line` label and style key, and per dt its worst
    ``errors`` and dearest ``times`` over the reduced axes."""

    label: str
    key: Any
    errors: np.ndarray
    times: np.ndarray


def _lines(da, line):
    """The `_Line` of each line of a panel."""
    if line is None:
        return [_Line("", 0, da)]
    if line == "scheme":
        return [_Line(scheme, scheme, per_scheme(da, scheme)) for scheme in schemes_of(da)]
    return [_Line(_value_text(line, v), k, da.sel({line: v})) for k, v in enumerate(da[line].values)]


def line_styles(schemes, styles=None):
    """scheme name -> (colour, marker, line style) for the lines of ``schemes`` (the study's
    scheme names): the registered style of each scheme in ``styles`` (name -> style, as
    `rbstudy.schemes.scheme_styles` gives), and for each other scheme, in turn, one that no
    line of the study wears, so that every line stays told apart."""
    styles = styles or {}
    chosen = {name: tuple(styles[name]) for name in schemes if name in styles}
    colours = {colour for colour, _, _ in chosen.values()}
    # the colours no registered line wears first; then every colour with other markers
    candidates = (
        [style for style in _OTHER_STYLES if style[0] not in colours]
        + [style for style in _OTHER_STYLES if style[0] in colours]
        + [(colour, marker, dash) for marker in _MORE_MARKERS for colour, _, dash in _OTHER_STYLES]
    )
    worn = {style[:2] for style in chosen.values()}
    free = (style for style in candidates if style[:2] not in worn)
    for name in schemes:
        if name not in chosen:
            chosen[name] = next(free, _OTHER_STYLES[0])
            worn.add(chosen[name][:2])
    return chosen


def _style(key, schemes):
    """Keyword arguments that draw the line ``key``: a scheme name, in its style of
    ``schemes`` (`line_styles`), or the number of a line of other values."""
    color, marker, dash = schemes[key] if key in schemes else _OTHER_STYLES[key % len(_OTHER_STYLES)]
    solid = dash == "-"
    return dict(
        color=color,
        marker=marker,
        linestyle=dash,
        linewidth=2.0 if solid else 1.2,
        markersize=7 if solid else 4,
        zorder=2 if solid else 3,
        markerfacecolor="none" if solid else color,
    )


def _power_of_ten(value, _position=None):
    """``10^{-2}``, ``2x10^{-3}`` or ``1.5x10^{-2}`` in mathtext: the tick label of a log
    axis, its mantissa to three digits, so that no tick reads as a value it is not (a tick
    at 0.015 once read "2x10^{-2}")."""
    exponent = int(np.floor(np.log10(value) + 1e-9))
    mantissa = float(f"{value / 10.0**exponent:.3g}")
    if mantissa == 1:
        return f"$10^{{{exponent}}}$"
    return f"${mantissa:g}\\times10^{{{exponent}}}$"


def _log_labels(fig):
    """Tick labels of log axes as powers of ten, a few labelled ticks per axis: matplotlib's
    default labels every minor tick it may need, and each label typeset with mathtext cost
    a figure seconds; at most eight labels an axis cost no more than plain text."""
    for ax in fig.axes:
        for axis, scale in ((ax.xaxis, ax.get_xscale()), (ax.yaxis, ax.get_yscale())):
            if scale == "log":
                low, high = axis.get_view_interval()
                # under two decades shown: ticks at 1, 2 and 5 of each decade (under one,
                # also at 3), or a single tick (or none) would be labelled; no
                # unlabelled minor ticks between them (a sixth of each figure's drawing
                # time). Where even those leave one tick, matplotlib places linear ones.
                ratio = high / low if low > 0 else np.inf
                short = ratio < 100
                subs = (1.0, 2.0, 5.0) if ratio >= 10 else (1.0, 2.0, 3.0, 5.0)
                axis.set_major_locator(LogLocator(subs=subs) if short else LogLocator(numticks=8))
                axis.set_major_formatter(FuncFormatter(_power_of_ten))
                if short:
                    axis.set_minor_locator(NullLocator())
                else:
                    axis.set_minor_formatter(NullFormatter())


def _save(fig, folder, ds, name, formats):
    """Write the figure in each of ``formats``; returns the first file."""
    _log_labels(fig)
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = [inside(folder, f"{figure_name(ds, name)}.{suffix}") for suffix in formats]
    for path in paths:  # constrained layout fits the labels: no second "tight" pass
        fig.savefig(path, dpi=110)
    plt.close(fig)
    return paths[0]


def _grid(count, width=5.4, height=4.2, columns=2, legend_width=0.0):
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


# Widths of DejaVu Sans characters in em, rounded up (`_em_width`): matplotlib's own wrapping
# measures the text word by word at every draw, a sixteenth of a figure's drawing time.
_NARROW, _WIDE = set(" .,;:'|!()[]ijlft-"), set("MWmw")


_NARROWEST_EM = 0.35
# The study's title heads every figure in at most this many lines, its end cut with an
# ellipsis: an archive made elsewhere may carry a title of any length (a megabyte of one took
# `plot` 171 s, and its lines covered every panel).
TITLE_LINES = 2
_ELLIPSIS = "\u2026"


def _em_width(text):
    return sum(
        _NARROWEST_EM if c in _NARROW else 1.0 if c in _WIDE else 0.75 if c.isupper() else 0.64 for c in text
    )


def _wrapped(text, width_em):
    """``text`` broken at spaces into lines of at most ``width_em`` (by `_em_width`)."""
    lines = []
    for word in text.split(" "):
        if lines and _em_width(f"{lines[-1]} {word}") <= width_em:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return "\n".join(lines)


def _fitting(text, width_em):
    """How many of ``text``'s first characters fit in ``width_em`` (at least one)."""
    width = 0.0
    for count, character in enumerate(text):
        width += _em_width(character)
        if width > width_em:
            return max(count, 1)
    return len(text)


def _shortened(text, width_em, lines):
    """``text`` wrapped to ``width_em`` in at most ``lines`` lines (a word wider than a line
    broken), its end cut with an ellipsis when it is longer. Only what could fit is measured,
    once runs of white space are one space (a run longer than the room would leave fewer
    lines than ``lines`` and the words after it unseen)."""
    text = " ".join(text.split())
    room = int(lines * width_em / _NARROWEST_EM) + 1
    words = []
    for word in text[:room].split():
        while len(word) > 1 and _em_width(word) > width_em:
            cut = _fitting(word, width_em)
            words.append(word[:cut])
            word = word[cut:]
        words.append(word)
    wrapped = _wrapped(" ".join(words), width_em).split("\n")
    if len(wrapped) <= lines and len(text) <= room:
        return "\n".join(wrapped)
    last = wrapped[lines - 1]
    last = last[: _fitting(last, width_em - _em_width(_ELLIPSIS))].rstrip()
    return "\n".join([*wrapped[: lines - 1], last + _ELLIPSIS])


def _title(fig, ds, what):
    """The study's title (at most `TITLE_LINES` lines of it) and what the figure shows, each
    wrapped to the figure's width."""
    size = FontProperties(size=plt.rcParams["figure.titlesize"]).get_size_in_points()
    width_em = 0.97 * fig.get_figwidth() * 72 / size
    title = _shortened(str(ds.attrs.get("title", "")), width_em, TITLE_LINES)
    fig.suptitle(f"{title}\n{_wrapped(what, width_em)}")


def zero_floor(values):
    """The y of the floor line on which exact zeros of ``values`` are drawn: half a decade
    below the decade under the smallest positive value (between tick labels, so that no
    label reads as the value of a zero), or None when no value is zero."""
    values = np.asarray(values, dtype=float)
    if not np.any(values == 0.0):
        return None
    positive = values[values > 0]
    decade = np.floor(np.log10(positive.min())) - 1 if positive.size else -16.0
    return 10.0 ** (decade - 0.5)


def _uncertainty_limit(uncertainty, facet, value, reduced, like):
    """`UNCERTAINTY_FACTOR` times the reference's uncertainty of a panel's points, the
    largest over the ``reduced`` dims (cases whose reference is exact do not count), like
    the panel ``like``: NaN where no case's reference is uncertain."""
    if uncertainty is None:
        return like.copy(data=np.full(like.shape, np.nan))
    picked = uncertainty.sel({facet: value}) if facet else uncertainty
    return UNCERTAINTY_FACTOR * (picked.max(reduced, skipna=True) if reduced else picked)


def _mark_uncertainty(ax, limits):
    """A dashed line at the largest of a panel's ``limits``, below which no order is fitted
    (nothing when no reference of the panel is uncertain)."""
    finite = limits[np.isfinite(limits)]
    if not finite.size:
        return
    ax.axhline(finite.max(), color="0.35", linewidth=0.8, linestyle="--", zorder=1)
    ax.annotate(
        f"{UNCERTAINTY_FACTOR:g} x reference uncertainty: not fitted below",
        (0.99, finite.max()),
        xycoords=("axes fraction", "data"),
        xytext=(0, 3),
        textcoords="offset points",
        fontsize=7,
        color="0.3",
        ha="right",
    )


def _mark_floor(ax, floor):
    """Draw and label the floor line (after the data, so that the limits know the data)."""
    if floor is None:
        return
    ax.axhline(floor, color="0.5", linewidth=0.8, linestyle=":", zorder=1)
    ax.annotate(
        ZERO_LABEL,
        (0.01, floor),
        xycoords=("axes fraction", "data"),
        xytext=(0, 3),
        textcoords="offset points",
        fontsize=7,
        color="0.3",
    )
    ax.set_ylim(bottom=floor / 2.0, top=max(ax.get_ylim()[1], floor * 10.0))


# A dense time series marks every this many of its exact zeros (each point would be a smear).
ZERO_MARK_EVERY = 8


def _on_floor(y, floor):
    """``y`` as `plot_with_zeros` draws it: its exact zeros on the ``floor`` line (None: it
    has no zero)."""
    y = np.asarray(y, dtype=float)
    return y if floor is None else np.where(y == 0.0, floor, y)


def plot_with_zeros(ax, x, y, floor, label, style, markers=True):
    """A line with its exact zeros on the floor line, the line running down to them, each
    with the exact-zero mark (`rbstudy.analysis.figure_marks.zero_marks`) instead of the
    line's own (for a dense time series, ``markers`` off, no marks of its own, the zeros
    marked every `ZERO_MARK_EVERY`): only a failed case (NaN) is a gap."""
    y = np.asarray(y, dtype=float)
    zero = y == 0.0
    drawn = np.where(y > 0, y, np.where(zero, np.nan if floor is None else floor, np.nan))
    line_style = style if markers else {**style, "marker": ""}
    if markers and zero.any():  # the line's marks on its non-zero points only
        every = style.get("markevery") or (0, 1)
        line_style = {**style, "markevery": [k for k in range(every[0], y.size, every[1]) if not zero[k]]}
    (line,) = ax.plot(x, drawn, label=label, **line_style)
    zero_marks(ax, x, zero, floor, style, every=1 if markers else ZERO_MARK_EVERY)
    return line


def _guide_orders(ds, facet, value):
    """`REFERENCE_ORDERS` and the nominal orders of a panel's schemes (a composition's 6, 8)."""
    if "nominal_order" not in ds.coords:
        return REFERENCE_ORDERS
    nominal = ds["nominal_order"]
    if facet in nominal.dims:
        nominal = nominal.sel({facet: value})
    return tuple(sorted(set(REFERENCE_ORDERS) | {int(o) for o in np.ravel(nominal.values)}))


def _conflicts(guides, obstacles):
    """Per guide (rows of log10 values over some steps), how many ``obstacles`` (rows of
    log10 values over the same steps, NaN where not drawn) it crosses or passes within
    `GUIDE_CLEARANCE` decades of. Both are straight between the steps on log axes, so a row
    that stays on one side at every step stays on it in between."""
    gaps = obstacles[None, :, :] - guides[:, None, :]
    near = np.abs(gaps) < GUIDE_CLEARANCE
    crossed = (gaps > 0).any(axis=2) & (gaps < 0).any(axis=2)
    return np.sum(near.any(axis=2) | crossed, axis=1)


def _reference_slopes(ax, dts, errors, orders):
    """A dotted guide per order in ``orders``, each over `GUIDE_STEPS` consecutive steps
    placed where it crosses no line of ``errors`` (lines x steps) and no other guide, within
    the errors' range (a guide never stretches the axis): of the places that cross fewest,
    the longest, at the largest steps, nearest the errors' middle. Returns the labels
    ("order n") to place clear of the data once the figure is laid out
    (`rbstudy.analysis.figure_marks.clear_labels`): (annotation, guide, anchors along it)."""
    labels = []
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.log10(np.where(errors > 0, errors, np.nan))
    if not np.isfinite(logs).any():
        return labels
    order_of_steps = np.argsort(dts)
    x, logs = np.log10(dts[order_of_steps]), logs[:, order_of_steps]
    low, high = np.nanmin(logs), np.nanmax(logs)
    middle = np.nanmedian(logs)
    anchors = np.arange(low, high + GUIDE_GRID / 2, GUIDE_GRID)  # a guide's largest value
    for order in sorted(orders, reverse=True):  # the steepest, hardest to place, first
        best = None
        for steps in range(min(GUIDE_STEPS, x.size), 1, -1):
            for start in range(x.size - steps, -1, -1):
                span = slice(start, start + steps)
                guides = anchors[:, None] + order * (x[span] - x[span][-1])[None, :]
                inside_range = guides.min(axis=1) >= low
                if not inside_range.any():
                    continue
                guides = guides[inside_range]
                conflicts = _conflicts(guides, logs[:, span])
                distances = np.abs(guides.mean(axis=1) - middle)
                pick = np.lexsort((distances, conflicts))[0]
                score = (conflicts[pick], -steps, x.size - start, distances[pick])
                if best is None or score < best[0]:
                    best = (score, span, guides[pick])
        if best is None:
            continue
        _, span, guide = best
        row = np.full(x.size, np.nan)
        row[span] = guide
        logs = np.vstack([logs, row])  # the next guide keeps clear of this one
        shown_dts, shown = 10.0 ** x[span], 10.0**guide
        (line,) = ax.plot(shown_dts, shown, color="0.6", linestyle=":", linewidth=1, zorder=1)
        # named at its middle, else at one of its steps: wherever its box is clear of the data
        centre = (10.0 ** x[span].mean(), 10.0 ** guide.mean())
        text = ax.annotate(
            f"order {order}",
            centre,
            xytext=(0, 2),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=7,
            color="0.4",
        )
        labels.append((text, line, [centre, *zip(shown_dts, shown, strict=True)]))
    return labels


def _fit_text(errors, fit, failed, limits, round_off):
    """``order 4.00, finest 4.01`` in one panel, or why a line has no order: failed (``failed``: a
    case of the line did; else it had no reference), exact, at the floor (`at_floor`: too few
    errors above their ``round_off`` (an invariant kept), or above their ``limits``,
    `UNCERTAINTY_FACTOR` times the reference's uncertainty), or no asymptotic range."""
    present = np.isfinite(errors)
    finite = errors[present]
    if np.isfinite(fit.order):
        text = f"order {fit.order:.2f}, finest {fit.finest_slope:.2f}"
    elif not finite.size:
        text = "failed at every dt" if failed else "no reference at any dt"
    elif np.all(finite == 0.0):
        text = "exact at every dt"
    elif why := at_floor(errors, round_off, limits / UNCERTAINTY_FACTOR):  # in a legend's ( )
        text = (
            "at the round-off floor"
            if why == "round-off"
            else f"within {UNCERTAINTY_FACTOR:g}x the reference's uncertainty"
        )
    else:
        text = "no asymptotic range"
    return text


def _fit_label(name, texts, fits):
    """The legend entry of a line over a figure's panels (``texts`` and ``fits``, one per
    panel): ``rk4 (order 4.00, finest 3.99-4.01)``, ``in 3 of 4 panels`` where the others
    had none; ``name``: the line's, or the lines' that coincide (`together`)."""
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


def _missing_text(bands, line_dim, index, behind):
    """``no value in 17 of 68 cases`` for the line ``index`` of a figure whose points each
    stand for ``behind`` cases (`band`, per panel: more than one where an axis is reduced),
    where some of them failed or had no reference; else nothing."""
    if behind == 1:
        return ""
    counts = [_lines(panel.missing, line_dim)[index].data.values for panel in bands]
    missing, cases = sum(int(c.sum()) for c in counts), sum(c.size for c in counts) * behind
    return f"no value in {missing} of {cases} cases" if missing else ""


def _value_fits(dts, measure, uncertainty, round_off, facet, value, line_dim, reduced, key):
    """Per line of a panel (``measure`` of its cases, ``round_off`` their floors), the
    `fitted_order` at each value of the ``reduced`` axes with why it has none (`at_floor`:
    ``"round-off"``, ``"reference"`` or None), as pairs; none when no axis is reduced."""
    if not reduced:
        return []
    limits = None
    if uncertainty is not None:
        limits = uncertainty.sel({facet: value}) if facet else uncertainty

    def rows(da, k):  # line k's cases, a row per value of the reduced axes
        return _lines(da, line_dim)[k].data.stack(value=reduced).transpose("value", "dt").values

    result = []
    for k in range(len(_lines(measure, line_dim))):
        errors, floors = rows(measure, k), rows(round_off, k)
        bounds = [None] * len(errors) if limits is None else rows(limits, k)
        result.append(
            [
                (fitted_order(dts, row, key, bound, floor), at_floor(row, floor, bound))
                for row, floor, bound in zip(errors, floors, bounds, strict=True)
            ]
        )
    return result


def _values_label(name, fits, reduced):
    """The legend entry of a line that stands for the values of ``reduced`` axes: its orders
    fitted value by value (``fits``: per panel, a (fit, floor) pair per value, `_value_fits`),
    ``rk4 (order 3.98-4.02, finest 3.9-4.1, at 12 of 17 values of inertia_ratio)``; a line
    whose every value lies at a floor says which (exact_split's round-off)."""
    every = [pair for panel in fits for pair in panel]
    fitted = [fit for fit, _ in every if np.isfinite(fit.order)]
    axes = ", ".join(reduced)
    where = f"at {len(fitted)} of {len(every)} values of {axes}"
    if not fitted:
        floors = {floor for _, floor in every}
        if floors == {"round-off"}:
            return f"{name} (at the round-off floor at all {len(every)} values of {axes})"
        return f"{name} (no asymptotic range at any of {len(every)} values of {axes})"
    orders = f"order {span([f.order for f in fitted])}, finest {span([f.finest_slope for f in fitted])}"
    return f"{name} ({orders}, {where})"


def _aside(text, form):
    """``text`` in ``form`` (``"; {}"``), or nothing when there is no text."""
    return form.format(text) if text else ""


def _draw_band(ax, x, best, worst, floor, style):
    """The band from a line's best to its worst value (`band`), faint, its best edge a
    thin dotted line in the line's colour, zeros on the floor."""
    low = np.where(best > 0, best, floor if floor is not None else np.nan)
    ax.fill_between(x, low, worst, color=style["color"], alpha=0.05, linewidth=0, zorder=1)
    ax.plot(x, low, color=style["color"], linestyle=(0, (1, 2)), linewidth=0.9, zorder=1)


def _overlap_title(ax, fig, title, notes):
    """A panel's ``title`` and, on lines of their own wrapped to the panel's width, the
    ``notes`` of the lines it draws on top of each other (`rbstudy.analysis.overlaps`): over the
    panel, never over its data."""
    if not notes:
        return title
    width_em = 0.9 * ax.get_position().width * fig.get_figwidth() * 72 / plt.rcParams["axes.titlesize"]
    note = _wrapped(f"on top of each other: {'; '.join(notes)}", width_em)
    return f"{title}\n{note}" if title else note


def _coincident_style(style, rank, count):
    """A line's style as the ``rank``-th of ``count`` lines drawn on top of each other: each
    marks every ``count``-th point, starting at its rank, so that the points alternate
    between them; the first hollow on a solid line under the others, the later ones filled
    on dashed lines above it, so that every colour shows."""
    if rank == 0:
        return {
            **style,
            "markersize": 8,
            "markerfacecolor": "none",
            "linewidth": 2.0,
            "zorder": 2,
            "linestyle": "-",
            "markevery": (0, count),
        }
    return {
        **style,
        "markersize": 6,
        "markerfacecolor": style["color"],
        "linewidth": 1.2,
        "zorder": 2 + rank,
        "markevery": (rank, count),
        "linestyle": "--" if style["linestyle"] == "-" else style["linestyle"],
    }


def _figure_legend(fig, entries, reserved):
    """One legend for the whole figure, right of its panels: ``entries`` are (handles,
    label), several handles drawn side by side for lines named together. The figure was made
    ``reserved`` inches wider than its panels for it; it takes the legend's own width
    instead (estimated from its labels, `_em_width`), so that twenty schemes' names never
    squeeze the panels. A label wider than `LEGEND_MAX_WIDTH` wraps, and the figure grows
    taller where the legend's lines need it."""
    if not entries:
        return
    points = FontProperties(size=plt.rcParams["legend.fontsize"]).get_size_in_points()
    longest = max(_em_width(label) for _, label in entries)
    text_em = min(longest, (LEGEND_MAX_WIDTH - LEGEND_FRAME_EM * points / 72) * 72 / points)
    labels = [_wrapped(label, text_em) for _, label in entries]
    width = (text_em + LEGEND_FRAME_EM) * points / 72
    fig.set_figwidth(fig.get_figwidth() - reserved + width)
    lines = sum(label.count("\n") + 1 for label in labels)
    fig.set_figheight(max(fig.get_figheight(), (lines * LEGEND_LINE_EM + 2) * points / 72 + 1.2))
    fig.legend(
        [tuple(handles) for handles, _ in entries],
        labels,
        handler_map={tuple: HandlerTuple(ndivide=None, pad=0.6)},
        loc="outside right center",
    )


def convergence(ds, folder, formats=FORMATS, measures=None, styles=None):
    """Error against dt per measure (``measures``: keys of `ERROR_MEASURES`, default all),
    fitted order per line in the legend; ``styles``: the schemes' registered styles
    (`line_styles`)."""
    figures = Figures()
    schemes = line_styles(schemes_of(ds), styles)
    if "dt" not in ds.dims:
        return figures
    dts = ds["dt"].values
    line_dim, facet, reduced = figure_layout(ds)
    values = list(ds[facet].values) if facet else [None]
    for key, spec in ERROR_MEASURES.items():
        label, units = spec.label, spec.units
        if measures is not None and key not in measures:
            continue
        measure = error_measure(ds, key)
        name = f"convergence_{key}"
        if measure is None:
            continue  # not stored: not a figure this study could have
        bands = [band(measure.sel({facet: value}) if facet else measure, reduced) for value in values]
        behind = int(np.prod([ds.sizes[d] for d in reduced]))  # cases behind each point
        panels = [panel.worst for panel in bands]
        uncertainty = uncertainty_of(ds, key, measure)
        limits = [
            _uncertainty_limit(uncertainty, facet, value, reduced, panel)
            for value, panel in zip(values, panels, strict=True)
        ]
        # the round-off floor of the worst case is the largest of the panel's (`round_off_of`)
        round_off = round_off_of(ds, key, measure)
        round_offs = [
            band(round_off.sel({facet: value}) if facet else round_off, reduced).worst for value in values
        ]
        failures = [
            band((ds["status"] != OK).sel({facet: value}) if facet else ds["status"] != OK, reduced).worst
            for value in values
        ]
        # a panel whose every case finished without a reference has nothing to show
        shown = [
            k
            for k, (panel, failed) in enumerate(zip(panels, failures, strict=True))
            if np.isfinite(panel.values).any() or failed.values.any()
        ] or list(range(len(values)))
        unreferenced = [values[k] for k in range(len(values)) if k not in shown]
        facet_values, panels, failures, limits, round_offs, bands = (
            [items[k] for k in shown] for items in (values, panels, failures, limits, round_offs, bands)
        )
        fits = [
            [
                _FittedLine(
                    line.label,
                    line.key,
                    line.data.values,
                    fitted_order(dts, line.data.values, key, limit.data.values, floor.data.values),
                    bool(failed.data.values.any()),
                    limit.data.values,
                    floor.data.values,
                )
                for line, failed, limit, floor in zip(
                    _lines(panel, line_dim),
                    _lines(failures_of_panel, line_dim),
                    _lines(panel_limits, line_dim),
                    _lines(panel_floors, line_dim),
                    strict=True,
                )
            ]
            for panel, failures_of_panel, panel_limits, panel_floors in zip(
                panels, failures, limits, round_offs, strict=True
            )
        ]
        # where a line stands for many cases, an order is fitted at each value of the reduced
        # axes (the table's fits), never through the worst case's envelope
        value_fits = [
            _value_fits(
                dts,
                measure.sel({facet: value}) if facet else measure,
                uncertainty,
                round_off.sel({facet: value}) if facet else round_off,
                facet,
                value,
                line_dim,
                reduced,
                key,
            )
            for value in facet_values
        ]
        if not any(
            np.isfinite(fit.order)
            for panel in (value_fits if reduced else [[[(line.fit, None)] for line in p] for p in fits])
            for line in panel
            for fit, _ in line
        ):
            figures.absent[name] = (
                f"no case has a reference to measure the {label} against (reference = none)"
                if _unreferenced(ds).all()
                else f"no line shows an asymptotic range of the {label} (every line failed, "
                "stalled, or was exact or at the round-off floor at every dt)"
            )
            continue
        # the lines are the same in every panel: those that coincide in every case (as
        # `coinciding_lines` tells the caption) are drawn on top of each other in turn and
        # named together
        rows = [line.data.values.ravel() for line in _lines(measure, line_dim)]
        # coinciding below the measure's constant floor, as `coinciding_lines` tells the caption
        groups = coincident(rows, spec.floor)
        group_names = {
            group[0]: together([fits[0][j].label for j in group], [rows[j] for j in group], spec.floor)
            for group in groups
        }
        drawn = {
            j: (
                _coincident_style(_style(fits[0][j].key, schemes), rank, len(group))
                if len(group) > 1
                else _style(fits[0][j].key, schemes)
            )
            for group in groups
            for rank, j in enumerate(group)
        }
        with plt.rc_context(_RC):
            fig, axes = _grid(len(facet_values), width=5.0, legend_width=LEGEND_WIDTH)
            reserved = LEGEND_WIDTH
            floors, handles, labels = [], {}, []
            for ax, value, panel, lines, limit, panel_band in zip(
                axes, facet_values, panels, fits, limits, bands, strict=True
            ):
                ax.set_xscale("log")
                ax.set_yscale("log")
                floor = zero_floor(panel.values)
                floors.append(floor)
                for j, (line, least) in enumerate(zip(lines, _lines(panel_band.best, line_dim), strict=True)):
                    errors, fit, style = line.errors, line.fit, drawn[j]
                    handles.setdefault(j, plot_with_zeros(ax, dts, errors, floor, None, style))
                    if reduced:
                        _draw_band(ax, dts, least.data.values, errors, floor, style)
                    ax.plot(
                        dts[fit.used],
                        errors[fit.used],
                        linestyle="none",
                        marker="o",
                        markersize=11,
                        markerfacecolor="none",
                        markeredgewidth=0.8,
                        color=style["color"],
                        zorder=1,
                    )
                labels += _reference_slopes(
                    ax, dts, np.array([line.errors for line in lines]), _guide_orders(ds, facet, value)
                )
                _mark_uncertainty(ax, limit.values)
                _mark_floor(ax, floor)
                ax.set_xlabel("time step dt (s)")
                ax.set_ylabel(f"{label} ({units})")
                # lines that coincide in this panel only: the legend cannot name them
                here = panel_overlaps(
                    [fits[0][j].label for j in range(len(lines))],
                    [line.errors for line in lines],
                    groups,
                    spec.floor,
                    ax,
                    [(dts, _on_floor(line.errors, floor)) for line in lines],
                )
                ax.set_title(_overlap_title(ax, fig, _panel_title(facet, value, reduced), here))
                ax.grid(True, which="major", alpha=0.3)
            _figure_legend(
                fig,
                [
                    (
                        [handles[j] for j in group],
                        _fit_label(
                            group_names[group[0]],
                            [
                                _fit_text(line.errors, line.fit, line.failed, line.limits, line.floors)
                                for line in (lines[group[0]] for lines in fits)
                            ],
                            [lines[group[0]].fit for lines in fits],
                        )
                        if not reduced
                        else _values_label(
                            group_names[group[0]], [lines[group[0]] for lines in value_fits], reduced
                        )
                        + _aside(_missing_text(bands, line_dim, group[0], behind), "; {}"),
                    )
                    for group in groups
                ]
                + zero_entry(fig),
                reserved,
            )
            zeros = f"; on the dotted floor: {ZERO_LABEL}" if any(f is not None for f in floors) else ""
            unjudged_gap = any(
                not line.failed and not np.isfinite(line.errors).all() for panel in fits for line in panel
            )
            gaps = (
                "failed cases, or cases without a reference"
                if unjudged_gap and _unreferenced(ds).any()
                else "failed cases"
            )
            left_out = (
                "; not shown, without a reference: " + ", ".join(_value_text(facet, v) for v in unreferenced)
                if unreferenced
                else ""
            )
            _title(
                fig,
                ds,
                f"convergence: {label}; large circles: the fitted asymptotic range; "
                f"gaps: {gaps}{zeros}{left_out}",
            )
            _log_labels(fig)  # the ticks as saved: the layout the labels are placed in
            clear_labels(fig, labels)
            figures.written.append(_save(fig, folder, ds, name, formats))
    return figures


def work_precision(ds, folder, formats=FORMATS, styles=None):
    """Cost per case against the final orientation error, a line per scheme over dt, the
    accuracy bound and the study's recommended point (`recommended_point`): the cost the
    findings rank by (`case_seconds`: steps at the scheme's calibrated seconds a step, or an
    older archive's run time), so that the star lies where the words put it;
    ``styles``: the schemes' registered styles (`line_styles`)."""
    figures = Figures()
    schemes = line_styles(schemes_of(ds), styles)
    measure = error_measure(ds, "orientation")
    if measure is None or "dt" not in ds.dims:
        return figures
    if not (measure > 0).any():
        figures.absent["work_precision"] = "no case has a finite, non-zero orientation error"
        return figures
    line_dim, facet, reduced = figure_layout(ds)
    values = list(ds[facet].values) if facet else [None]
    picks = [{facet: value} if facet else {} for value in values]
    # a line's points: the worst error over the reduced axes and the dearest time, of the
    # cases that finished (`band`)
    bands = [band(measure.sel(pick), reduced) for pick in picks]
    cost = case_seconds(ds)
    behind = int(np.prod([ds.sizes[d] for d in reduced]))  # cases behind each point
    panels = [
        [
            _CostLine(line.label, line.key, line.data.values, times.data.values)
            for line, times in zip(
                _lines(errors_band.worst, line_dim),
                _lines(band(cost.sel(pick), reduced).worst, line_dim),
                strict=True,
            )
        ]
        for pick, errors_band in zip(picks, bands, strict=True)
    ]
    # lines drawn on top of each other (error and time alike at every point) named together
    groups = coincident(
        [np.concatenate([np.r_[p[j].errors, p[j].times] for p in panels]) for j in range(len(panels[0]))]
    )
    drawn = {
        j: _coincident_style(_style(panels[0][j].key, schemes), rank, len(group))
        if len(group) > 1
        else _style(panels[0][j].key, schemes)
        for group in groups
        for rank, j in enumerate(group)
    }
    bound = ds.attrs.get("accuracy_bound")
    point = recommended_point(ds)
    with plt.rc_context(_RC):
        reserved = LEGEND_WIDTH / 2
        fig, axes = _grid(len(values), width=5.0, legend_width=reserved)
        handles, extras = {}, {}
        for ax, pick, lines in zip(axes, picks, panels, strict=True):
            for j, cost_line in enumerate(lines):
                shown = cost_line.errors > 0  # an exact zero has no place on a log axis: said in the title
                (line,) = ax.loglog(np.where(shown, cost_line.errors, np.nan), cost_line.times, **drawn[j])
                handles.setdefault(j, line)
            if bound is not None:
                extras.setdefault("bound", (ax.axvline(bound, **BOUND_STYLE), bound_label(bound)))
            for j, cost_line in enumerate(lines if point is not None else []):
                # the line the answer lies on: its scheme's, or in a one-scheme study the
                # line of each value of the answer's cases
                at = pick if line_dim in (None, "scheme") else {**pick, line_dim: ds[line_dim].values[j]}
                if (line_dim == "scheme" and cost_line.label != point.scheme) or not point.covers(at):
                    continue
                k = int(np.flatnonzero(ds["dt"].values == point.dt)[0])
                (star,) = ax.plot(cost_line.errors[k], cost_line.times[k], **RECOMMENDED_STYLE)
                extras.setdefault("point", (star, point.label))
            ax.set_xlabel("final orientation error (rad)")
            ax.set_ylabel("cost per case (core-seconds)")
            here = panel_overlaps(
                [line.label for line in lines],
                [np.r_[line.errors, line.times] for line in lines],
                groups,
                ax=ax,
                curves=[(line.errors, line.times) for line in lines],  # zeros not drawn
            )
            title = _panel_title(facet, pick.get(facet), reduced, "the worst error and cost")
            ax.set_title(_overlap_title(ax, fig, title, here))
            ax.grid(True, which="major", alpha=0.3)
        entries = (
            [
                (
                    [handles[j] for j in group],
                    together([panels[0][j].label for j in group])
                    + _aside(_missing_text(bands, line_dim, group[0], behind), " ({})"),
                )
                for group in groups
            ]
            if line_dim
            else []
        )
        _figure_legend(fig, entries + [([h], text) for h, text in extras.values()], reserved)
        zeros = " (exact zeros, which a log axis cannot show, left out)" if (measure == 0).any() else ""
        _title(
            fig,
            ds,
            (
                "work-precision: cost as the findings rank it, each case's steps at its scheme's "
                "seconds a step, calibrated once on this machine"
                if calibrated(ds)
                else "work-precision: kernel CPU time of each batch divided among its cases, "
                "compilation excluded"
            )
            + f"; each point a dt{zeros}",
        )
        figures.written.append(_save(fig, folder, ds, "work_precision", formats))
    return figures


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


def _verdict_kinds(ds):
    """(label, scatter keywords) of accurate, inaccurate, failed and unjudged cases, in the
    order of `verdicts`' masks."""
    bound = ds.attrs.get("accuracy_bound")
    return (
        ("accurate", dict(s=14, color="tab:green")),
        (
            "finished, inaccurate" + (f" (error or drift > {bound:g})" if bound is not None else ""),
            dict(s=22, marker="^", color="tab:orange"),
        ),
        (
            f"failed ({' or '.join(status.name.replace('_', ' ') for status in STATUSES[OK + 1 :])})",
            dict(s=22, marker="x", color="tab:red"),
        ),
        (
            "finished, no reference (unjudged)",
            dict(s=22, marker="s", facecolors="none", edgecolors="tab:gray"),
        ),
    )


def _is_strip(ds, load):
    """Whether the stability map is a strip chart: each scheme's cases lie along one axis
    (dt or one parameter), or none, with a dt |w0| of their own, which orders them."""
    others = [d for d in _case_dims(ds) if d != "scheme"]
    if len(others) > 1:
        return False
    count = ds.sizes[others[0]] if others else 1
    return all(np.unique(per_scheme(load, scheme).values).size == count for scheme in schemes_of(ds))


def _strip_chart(ds, load, judged, radioss):
    """One row per scheme, its cases at their dt |w0|, marked by verdict."""
    schemes = list(judged)
    fig, ax = plt.subplots(figsize=(7.5, 1.2 + STRIP_ROW_HEIGHT * len(schemes)), layout="constrained")
    for row, (scheme, masks) in enumerate(judged.items()):
        x = per_scheme(load, scheme).values.ravel()
        for cases, (label, kind) in zip(masks, _verdict_kinds(ds), strict=True):
            cases = cases.ravel()
            if cases.any():
                ax.scatter(x[cases], np.full(cases.sum(), row), label=label, **kind)
    if radioss:
        ax.axvline(
            RADIOSS_STEP_ANGLE,
            color="0.35",
            linestyle=":",
            linewidth=1,
            label=f"OpenRadioss aborts past dt |w| = {RADIOSS_STEP_ANGLE:g}",
        )
    ax.set_yticks(range(len(schemes)), schemes)
    ax.set_ylim(len(schemes) - 0.5, -0.5)  # the first scheme on top
    ax.set_xscale("log")
    ax.set_xlabel("dt |w0| (rad)")
    ax.grid(True, axis="x", alpha=0.3)
    return fig, [ax]


def _map_panels(ds, load, judged, radioss):
    """One panel per scheme: dt |w0| against the swept parameter, the largest accurate
    value at each of its values joined."""
    parameter = _parameter(ds)
    fig, axes = _grid(len(judged), width=3.4, height=2.9, columns=4)
    for ax, (scheme, masks) in zip(axes, judged.items(), strict=True):
        good = masks[0].ravel()
        y = per_scheme(load, scheme).values.ravel()
        if parameter:
            _, values, label = parameter
            x = per_scheme(values, scheme).values.ravel()
            ax.set_xlabel(label)
            named = x.dtype.kind not in "iuf"
            if named:  # names or flags: one column each
                names, x = np.unique(x, return_inverse=True)
                ax.set_xticks(range(len(names)), [str(name) for name in names])
                ax.set_xlim(-0.5, len(names) - 0.5)
            elif np.all(x > 0) and x.max() / x.min() > LOG_AXIS_RATIO:
                ax.set_xscale("log")
        else:
            x = np.zeros(y.size)
            ax.set_xticks([])
        for cases, (label, kind) in zip(masks, _verdict_kinds(ds), strict=True):
            cases = cases.ravel()
            if cases.any():  # the legend lists what occurs, nothing else
                ax.scatter(x[cases], y[cases], label=label, **kind)
        if parameter:
            xs = np.unique(x)
            largest = [y[good & (x == v)].max() if (good & (x == v)).any() else np.nan for v in xs]
            # a bar at each value, so that one accurate value alone still shows; joined
            # only along a numeric axis (names or flags have nothing between them)
            ax.plot(
                xs,
                largest,
                color="tab:green",
                linewidth=0 if named else 1,
                marker="_",
                markersize=12,
                label="largest accurate",
            )
        if radioss:
            ax.axhline(
                RADIOSS_STEP_ANGLE,
                color="0.35",
                linestyle=":",
                linewidth=1,
                label=f"OpenRadioss aborts past dt |w| = {RADIOSS_STEP_ANGLE:g}",
            )
        ax.set_yscale("log")
        ax.set_ylabel("dt |w0| (rad)")
        ax.set_title(scheme)
        ax.grid(True, alpha=0.3)
    return fig, axes


def stability_map(ds, folder, formats=FORMATS):
    """Every case's verdict (accurate, finished but inaccurate, failed) by its ``dt |w0|``:
    a strip chart, a row per scheme, when each scheme's cases lie along one axis; else one
    panel per scheme against the swept parameter. Not drawn when every case is accurate."""
    figures = Figures()
    if "dt" not in ds.coords:
        return figures
    load = step_load(ds)
    judged = {scheme: verdicts(ds, scheme) for scheme in schemes_of(ds)}
    if all(masks[0].all() for masks in judged.values()):
        figures.absent["stability_map"] = (
            f"every case is accurate (dt |w0| up to {float(load.max()):.3g} rad): no "
            "stability or accuracy boundary to show"
        )
        return figures
    # the limit is drawn where some case passed it and it lies among the plotted dt |w0|: a
    # case flagged for the spin it reached later must not stretch a map of small dt |w0|
    radioss = bool((ds["radioss_dt_limit"] == 1).any()) and bool((load >= RADIOSS_STEP_ANGLE).any())
    strip = _is_strip(ds, load)
    what = "stability and accuracy: every case by its dt |w0|"
    if not strip:  # a panel of nothing but accurate cases shows no boundary: named instead
        accurate = [scheme for scheme, masks in judged.items() if masks[0].all()]
        judged = {scheme: masks for scheme, masks in judged.items() if scheme not in accurate}
        what += f"; accurate in every case: {', '.join(accurate)}" if accurate else ""
    with plt.rc_context(_RC):
        fig, axes = (_strip_chart if strip else _map_panels)(ds, load, judged, radioss)
        handles = {}
        for ax in axes:  # every category that occurs in some panel, once
            for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
                handles[label] = handle
        kinds = [label for label, _ in _verdict_kinds(ds)]
        handles = dict(
            sorted(handles.items(), key=lambda item: kinds.index(item[0]) if item[0] in kinds else len(kinds))
        )
        fig.legend(
            list(handles.values()),
            list(handles),
            loc="outside lower center",
            ncols=min(len(handles), 2 if strip else 4),
        )
        _title(fig, ds, what)
        figures.written.append(_save(fig, folder, ds, "stability_map", formats))
    return figures


# The error measure of each invariant-drift panel's variable: its round-off floor.
_DRIFT_MEASURES = {"energy_error": "energy", "momentum_error": "momentum_vector"}


def _drift_case(ds, scheme):
    """The case of ``scheme`` the drift figure shows and its dt (None when dt is not swept):
    the first value of every axis but dt, and the largest dt with a stable case (by value);
    no case when none is stable."""
    case = per_scheme(ds, scheme)
    for dim in [d for d in _case_dims(case) if d != "dt"]:
        case = case.isel({dim: 0})
    if "dt" not in case.dims:
        return case, float(case["dt"]) if "dt" in case.coords else None
    stable = case["dt"].values[case["status"].values == OK]
    if stable.size == 0:
        return None, None
    return case.sel(dt=stable.max()), float(stable.max())


def _drift_title(ds, steps):
    """Which case the drift figure shows and how it was chosen, once: the first value of
    each other swept axis; the largest stable dt (``steps``: scheme -> dt, or None), named
    here when the schemes share it."""
    others = [d for d in _case_dims(ds) if d not in ("scheme", "dt")]
    chosen = [_value_text(dim, ds[dim].values[0]) for dim in others]
    how = ["the first value of each swept axis"] if others else []
    dts = set(steps.values()) - {None}
    swept = "dt" in _case_dims(ds)
    if len(dts) == 1:
        chosen.append(f"dt = {dts.pop():g} s")
        how += ["the largest dt at which every scheme ran stable"] if swept else []
    elif dts:
        how.append("the largest dt at which each scheme ran stable, in the legend")
    how = how or ["the study's one case per scheme"]
    return f"{', '.join(chosen)} ({'; '.join(how)})" if chosen else "; ".join(how)


def invariant_drift(ds, folder, formats=FORMATS, styles=None):
    """|energy error| and |L - L0| / |L0| against time, one case per scheme; ``styles``: the
    schemes' registered styles (`line_styles`)."""
    figures = Figures()
    panels = [
        (name, label)
        for name, label in (
            ("energy_error", "|relative energy error|"),
            ("momentum_error", "relative |L - L0| (vector)"),
        )
        if name in ds
    ]
    if not panels:
        return figures
    cases = [(scheme, *_drift_case(ds, scheme)) for scheme in schemes_of(ds)]
    cases = [(scheme, case, dt) for scheme, case, dt in cases if case is not None]
    if not cases:
        figures.absent["invariant_drift"] = "every case failed"
        return figures
    steps = {scheme: dt for scheme, _, dt in cases}
    schemes = line_styles(schemes_of(ds), styles)
    several_dts = len(set(steps.values())) > 1
    times = ds["time"].values[1:]  # at t = 0 every error is zero by definition
    series = [[np.abs(case[name].values[1:]) for _, case, _ in cases] for name, _ in panels]
    names = [f"{scheme} (dt = {dt:g} s)" if several_dts else scheme for scheme, _, dt in cases]
    with plt.rc_context(_RC):
        fig, axes = _grid(len(panels), width=5.4, legend_width=LEGEND_WIDTH / 2)
        reserved = LEGEND_WIDTH / 2
        floors = []
        for ax, (name, label), values in zip(axes, panels, series, strict=True):
            ax.set_yscale("log")
            floor = zero_floor(np.concatenate(values))
            floors.append(floor)
            # lines on top of each other in this panel (hht's and midpoint's zero energy
            # error) drawn in turn, dashed over solid, and named over it
            groups = coincident(values, ERROR_MEASURES[_DRIFT_MEASURES[name]].floor)
            for group in groups:
                for rank, k in enumerate(group):
                    style = _style(cases[k][0], schemes)
                    style = _coincident_style(style, rank, len(group)) if len(group) > 1 else style
                    plot_with_zeros(ax, times, values[k], floor, None, style, markers=False)
            overlaps = [
                together(
                    [names[k] for k in group],
                    [values[k] for k in group],
                    ERROR_MEASURES[_DRIFT_MEASURES[name]].floor,
                )
                for group in groups
                if len(group) > 1
            ]
            _mark_floor(ax, floor)
            overlaps += near_lines(
                ax,
                [names[group[0]] for group in groups],
                [(times, _on_floor(values[group[0]], floor)) for group in groups],
            )
            ax.set_title(_overlap_title(ax, fig, "", overlaps))
            ax.set_xlabel("time (s)")
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
        entries = [
            ([Line2D([], [], **{**_style(scheme, schemes), "marker": ""})], names[k])
            for k, (scheme, _, _) in enumerate(cases)
        ]
        _figure_legend(fig, entries + zero_entry(fig), reserved)
        zeros = f"; on the dotted floor: {ZERO_LABEL}" if any(f is not None for f in floors) else ""
        _title(fig, ds, f"invariant drift, bounded or secular; case: {_drift_title(ds, steps)}{zeros}")
        figures.written.append(_save(fig, folder, ds, "invariant_drift", formats))
    return figures


def benchmark_case(ds):
    """The case the benchmark figures show (`BENCHMARK_PICKS`, the largest dt) and its name
    (``hht, inertia_ratio = 2``)."""
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


_BENCHMARK_NEEDS = (
    "precession_frequency",
    "node_offset",
    "node_displacement",
    "omega_space",
    "omega_body",
    "quaternion",
)


def benchmark(ds, folder, formats=FORMATS, styles=None):
    """The Abaqus benchmark figures of a symmetric body with nodes, exact solution overlaid;
    the case's line in its scheme's style (``styles``: `line_styles`)."""
    figures = Figures()
    if any(name not in ds for name in _BENCHMARK_NEEDS):
        return figures
    case, what = benchmark_case(ds)
    color = _style(str(case["scheme"].values), line_styles(schemes_of(ds), styles))["color"]
    if int(case["status"]) != OK:
        figures.absent["benchmark"] = f"the benchmark case ({what}) failed"
        return figures
    times = ds["time"].values
    q_exact, w_exact = symmetric_top(
        case["inertia"].values, case["quaternion"].values[0], case["omega_body"].values[0], times
    )
    w_space = np.einsum("tij,tj->ti", quat_to_matrix(q_exact), w_exact)
    with plt.rc_context(_RC):
        fig, axes = _grid(3, width=4.2, height=3.0)
        for k, ax in enumerate(axes):
            ax.plot(times, case["omega_space"].values[:, k], color=color, label=what)
            ax.plot(times, w_space[:, k], linestyle="--", color="k", linewidth=1, label="exact")
            ax.set_xlabel("time (s)")
            ax.set_ylabel(f"global w_{'xyz'[k]} (rad/s)")
            ax.grid(True, alpha=0.3)
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2)
        fig.suptitle("global angular velocity against time (benchmark figures 2-4)")
        figures.written.append(_save(fig, folder, ds, "benchmark_omega_time", formats))

        fig, ax = plt.subplots(figsize=(5.0, 5.2), layout="constrained")
        ax.plot(case["omega_space"].values[:, 0], case["omega_space"].values[:, 1], color=color, label=what)
        ax.plot(w_space[:, 0], w_space[:, 1], linestyle="--", color="k", linewidth=1, label="exact")
        ax.set_aspect("equal")
        ax.set_xlabel("global w_x (rad/s)")
        ax.set_ylabel("global w_y (rad/s)")
        fig.legend(loc="outside lower center", ncols=2)
        ax.grid(True, alpha=0.3)
        ax.set_title("w_x against w_y (benchmark figure 5)")
        figures.written.append(_save(fig, folder, ds, "benchmark_omega_xy", formats))

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
        figures.written.append(_save(fig, folder, ds, "benchmark_node_path", formats))
    return figures


def _unreferenced(ds):
    """Per case: it had no reference (its DOP853 reference passed its step budget), so its
    errors against a reference are NaN without having failed."""
    if "reference" not in ds:
        return np.zeros(1, dtype=bool)
    return ds["reference"].values == _NO_REFERENCE


# What each figure shows, for the report (keyed by figure name without the measure suffix).
CAPTIONS = {
    "convergence": "Error against the time step, log-log, one line per scheme (or per value "
    "of the swept axis in a one-scheme study); the legend gives the order "
    "fitted on the circled points, the asymptotic range (see the table), and "
    "the local slope of the finest fitted pair, and names together the lines "
    "that agree to 3 digits (over a panel, those that agree in it only); dotted "
    "lines are slopes 1, 2 and 4, placed clear of the data; a gap is a failed "
    "case (or one without a reference); a point marked 0 on the dotted floor is "
    "exactly 0.",
    "work_precision": "Cost per case against the final orientation error, one point per dt: "
    "the cheapest scheme for a given accuracy is the lowest line. The cost is the one the "
    "findings rank by: a case's steps at its scheme's seconds a step, calibrated once on the "
    "machine that ran it (an archive from before rbstudy calibrated: the CPU time of the "
    "compiled batch call divided among its cases). The dash-dotted line is the study's "
    "accuracy bound, the star the findings' recommendation. Lines whose errors and costs agree "
    "to 3 digits are named together: in the legend, or over the panel where they agree only.",
    "stability_map": "Every case by its dt |w0|, a row per scheme (or, with more than one "
    "swept axis, a panel per scheme against the swept parameter, where the "
    "line joins the largest accurate value): green accurate, orange "
    "triangles finished but inaccurate (orientation error at a sample or "
    "energy or |L| drift past the study's accuracy bound), red crosses "
    "failed, grey squares finished without a reference (unjudged).",
    "invariant_drift": "Energy and angular-momentum (vector) errors against time for one "
    "case per scheme, the case named in the title (the largest stable dt "
    "when dt is swept; a failed case ends where it failed): bounded "
    "oscillation or secular growth; a stretch on the dotted floor, marked "
    "0, is exactly 0; lines drawn on top of each other are named over "
    "their panel.",
    "benchmark": "The Abaqus benchmark figures for the case named in the legend (HHT on the "
    "flat disk at the largest dt where the study has it), with the closed-form "
    "solution dashed.",
}


# The drawings of `all_figures`, each a figure function and its keyword arguments: one per
# convergence measure (a figure each, the most of the work) and one per other kind.
_DRAWINGS = [(convergence, {"measures": (key,)}) for key in ERROR_MEASURES] + [
    (figure, {}) for figure in (work_precision, stability_map, invariant_drift, benchmark)
]
# The drawing whose lines are not schemes: it takes no styles.
_UNSTYLED = (stability_map,)
# What the drawing processes of `all_figures` inherit (dataset, folder, formats, styles):
# forked, they share the loaded dataset instead of receiving a copy.
_INHERITED = None


def _draw(index):
    figure, options = _DRAWINGS[index]
    ds, folder, formats, styles = _INHERITED
    if figure not in _UNSTYLED:
        options = {**options, "styles": styles}
    return figure(ds, folder, formats, **options)


def _manifest(folder, ds):
    """The file beside a study's figures that records, per drawing, what the figures were
    drawn from (a digest) and what each drawing gave (`all_figures` with ``digest``)."""
    return inside(folder, f".{figure_name(ds, 'figures')}.json")


def _recorded(manifest, digest, formats):
    """Drawing index -> its recorded `Figures`, for the drawings of ``manifest`` drawn from
    ``digest`` in every one of ``formats`` whose files all exist: those need no redrawing."""
    try:
        record = json.loads(manifest.read_text())
        if record["digest"] != digest or len(record["drawings"]) != len(_DRAWINGS):
            return {}
        reused = {}
        for index, entry in enumerate(record["drawings"]):
            files = [manifest.parent / f"{stem}.{suffix}" for stem in entry["written"] for suffix in formats]
            if set(formats) <= set(entry["formats"]) and all(path.is_file() for path in files):
                reused[index] = Figures(
                    [manifest.parent / f"{stem}.{formats[0]}" for stem in entry["written"]],
                    dict(entry["absent"]),
                )
    except (OSError, ValueError, LookupError, TypeError):  # none yet, or not ours: draw all
        return {}
    return reused


def _copied(figures, folder, formats):
    """``figures`` (`Figures`, recorded in another folder) copied into ``folder`` in each of
    ``formats``, as the `Figures` of the copies."""
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for path in figures.written:
        for suffix in formats:
            shutil.copyfile(path.with_suffix(f".{suffix}"), inside(folder, f"{path.stem}.{suffix}"))
        written.append(folder / f"{path.stem}.{formats[0]}")
    return Figures(written, dict(figures.absent))


def all_figures(
    ds, folder, formats=FORMATS, processes=1, digest=None, progress=SILENT, styles=None, drawn=()
):
    """Every figure the dataset supports, as a `Figures` (files written in the first of
    ``formats``, absent with why), in the same order however drawn.

    ``processes`` > 1 draws them in that many forked processes (where the system forks:
    not on Windows), which share the loaded dataset. matplotlib draws in Python, one core a
    process: the 13 figures of the default study took 10.8 s in one. Fork only from a
    process without threads of its own (the command line), as a forked child holds only the
    forking thread.

    ``digest`` (a text naming what the figures are drawn from: the report's digest of the
    dataset and the sources that draw it) keeps the figures recorded beside them under the
    same digest and draws only the others; without it every figure is drawn and the record
    removed. ``progress`` (`rbstudy.pipeline.progress.Progress`) counts the drawings as they
    are done, and its end line tells the figures drawn and reused. ``styles``: the schemes'
    registered styles (name -> (colour, marker, line style); `rbstudy.schemes.scheme_styles`),
    which the digest must cover; a scheme without one is given one (`line_styles`).
    ``drawn``: other folders whose figures, recorded there under the same digest, are copied
    rather than drawn again (the report takes those that ``rbstudy plot`` drew beside the
    archive: 15-69 s of drawing for a copy).
    """
    global _INHERITED
    folder = pathlib.Path(folder)
    inside(folder, figure_name(ds, "*"))  # earlier drawings are deleted: only inside it
    manifest = _manifest(folder, ds)
    reused = {} if digest is None else _recorded(manifest, digest, formats)
    if not reused:
        for old in folder.glob(f"{figure_name(ds, '*')}.*"):  # an earlier drawing of this study
            if old.suffix.lstrip(".") in ALL_FORMATS:
                old.unlink()
        manifest.unlink(missing_ok=True)
    others = [pathlib.Path(other) for other in drawn if pathlib.Path(other).resolve() != folder.resolve()]
    for other in others if digest is not None else ():
        for index, figures in _recorded(_manifest(other, ds), digest, formats).items():
            if index not in reused:
                reused[index] = _copied(figures, folder, formats)
    todo = [index for index in range(len(_DRAWINGS)) if index not in reused]
    processes = min(processes, len(todo))
    _INHERITED = (ds, folder, formats, styles)
    done = dict(reused)
    progress.phase(f"{ds.attrs['study']}: drawing figures", len(todo), "drawings")
    try:
        with contextlib.ExitStack() as stack:
            if processes > 1 and "fork" in multiprocessing.get_all_start_methods():
                pool = stack.enter_context(multiprocessing.get_context("fork").Pool(processes))
                drawings = pool.imap(_draw, todo, chunksize=1)
            else:
                drawings = map(_draw, todo)
            for index in todo:
                done[index] = next(drawings)
                progress.advance()
    finally:
        _INHERITED = None
    figures = Figures()
    for index in range(len(_DRAWINGS)):
        figures += done[index]
    kept = sum(len(done[index].written) for index in reused)
    drawn = len(figures.written) - kept
    progress.end = f"{counted(drawn, 'figure')} drawn, {kept} reused"
    if digest is not None:
        record = {
            "digest": digest,
            "drawings": [
                {
                    "written": [path.stem for path in done[index].written],
                    "formats": [
                        suffix
                        for suffix in ALL_FORMATS
                        if all(path.with_suffix(f".{suffix}").is_file() for path in done[index].written)
                    ],
                    "absent": done[index].absent,
                }
                for index in range(len(_DRAWINGS))
            ],
        }
        write_text_atomic(json.dumps(record, indent=1), manifest)
    return figures
