"""Which lines and panels a figure along dt draws, and how each line looks.

Lines are the schemes (or, in a one-scheme study, the values of a swept axis with at most
`MAX_LINES` values); a further axis with at most `MAX_FACETS` values becomes one panel per
value; any other axis is reduced to a band (`rbstudy.analysis.figure_marks.band`). Every
scheme keeps one colour, marker and line style in every figure (`line_styles`); lines drawn
on top of each other differ in marker and dash (`group_styles`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import numpy as np
import xarray as xr
from matplotlib.axes import Axes

from rbstudy.analysis.figure_marks import Band
from rbstudy.analysis.figure_text import value_text
from rbstudy.analysis.summary import per_scheme, schemes_of

__all__ = [
    "MAX_FACETS",
    "MAX_LINES",
    "Line",
    "LineStyle",
    "Layout",
    "case_dims",
    "figure_layout",
    "lines_of",
    "line_styles",
    "style_of",
    "group_styles",
    "draw_band",
    "missing_text",
]

MAX_FACETS = 4
MAX_LINES = 8
_CASE_DIMS_EXCLUDED = ("time", "node", "axis", "component")


class LineStyle(NamedTuple):
    """How a line is drawn: a matplotlib ``color``, ``marker`` and line style (``dash``),
    as a scheme registers it (`rbstudy.schemes.Style`)."""

    color: str
    marker: str
    dash: str


# The styles of lines that are not schemes (the values of a swept axis), in turn; a scheme
# that registers no style takes the first of them no registered line of the study wears,
# then the same colours with `_MORE_MARKERS`.
_OTHER_STYLES = [
    LineStyle("tab:blue", "o", "-"),
    LineStyle("tab:orange", "s", "--"),
    LineStyle("tab:green", "^", "-."),
    LineStyle("tab:red", "D", ":"),
    LineStyle("tab:purple", "v", "-"),
    LineStyle("tab:brown", "P", "--"),
    LineStyle("tab:pink", "X", "-."),
    LineStyle("tab:gray", "*", ":"),
]
_MORE_MARKERS = ("<", ">", "h", "d", "p", "8", "H", "x")


class Line(NamedTuple):
    """One line of a panel: its legend ``label``, the key of its style (a scheme, or the
    line's index) and its ``data``."""

    label: str
    key: str | int
    data: xr.DataArray


class Layout(NamedTuple):
    """What a figure along dt draws: a ``line`` per value of that dimension (None: one
    line), a panel per value of the ``facet`` (None: one panel), and a band over the
    ``reduced`` dimensions."""

    line: str | None
    facet: str | None
    reduced: list[str]


def case_dims(ds: xr.Dataset | xr.DataArray) -> list[str]:
    """The dimensions of ``ds`` that tell its cases apart (not time, nodes or axes)."""
    return [str(d) for d in ds["status"].dims if d not in _CASE_DIMS_EXCLUDED]


def figure_layout(ds: xr.Dataset) -> Layout:
    """The `Layout` (line dim, facet dim, reduced dims) of a figure along dt.

    Lines are the schemes; a one-scheme study draws one line per value of its first other
    axis instead (if short enough). Then panels, then worst cases.
    """
    others = [d for d in case_dims(ds) if d not in ("scheme", "dt")]
    line: str | None
    if "scheme" in case_dims(ds):
        line = "scheme"
    else:
        line = next((d for d in others if ds.sizes[d] <= MAX_LINES), None)
    others = [d for d in others if d != line]
    facet = next((d for d in others if ds.sizes[d] <= MAX_FACETS), None)
    return Layout(line, facet, [d for d in others if d != facet])


def lines_of(da: xr.DataArray, line: str | None) -> list[Line]:
    """The `Line` of each line of a panel ``da`` along the dimension ``line`` (None: one
    line)."""
    if line is None:
        return [Line("", 0, da)]
    if line == "scheme":
        return [Line(scheme, scheme, per_scheme(da, scheme)) for scheme in schemes_of(da)]
    return [Line(value_text(line, v), k, da.sel({line: v})) for k, v in enumerate(da[line].values)]


def line_styles(
    schemes: Sequence[str], styles: Mapping[str, Sequence[str]] | None = None
) -> dict[str, LineStyle]:
    """scheme name -> `LineStyle` (colour, marker, line style) for the lines of ``schemes``
    (the study's scheme names): the registered style of each scheme in ``styles`` (name ->
    style, as `rbstudy.schemes.scheme_styles` gives), and for each other scheme, in turn, one
    that no line of the study wears, so that every line stays told apart."""
    styles = styles or {}
    chosen = {name: LineStyle(*styles[name]) for name in schemes if name in styles}
    colours = {style.color for style in chosen.values()}
    # the colours no registered line wears first; then every colour with other markers
    candidates = (
        [style for style in _OTHER_STYLES if style.color not in colours]
        + [style for style in _OTHER_STYLES if style.color in colours]
        + [LineStyle(other.color, marker, other.dash) for marker in _MORE_MARKERS for other in _OTHER_STYLES]
    )
    worn = {(style.color, style.marker) for style in chosen.values()}
    free = (style for style in candidates if (style.color, style.marker) not in worn)
    for name in schemes:
        if name not in chosen:
            chosen[name] = next(free, _OTHER_STYLES[0])
            worn.add((chosen[name].color, chosen[name].marker))
    return chosen


def style_of(key: str | int, schemes: Mapping[str, LineStyle]) -> dict[str, Any]:
    """Keyword arguments that draw the line ``key``: a scheme name, in its style of
    ``schemes`` (`line_styles`), or the number of a line of other values."""
    color, marker, dash = schemes[key] if isinstance(key, str) else _OTHER_STYLES[key % len(_OTHER_STYLES)]
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


def _coincident_style(style: dict[str, Any], rank: int, count: int) -> dict[str, Any]:
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


def group_styles(
    groups: list[list[int]], keys: Sequence[str | int], schemes: Mapping[str, LineStyle]
) -> dict[int, dict[str, Any]]:
    """Line index -> the keyword arguments that draw it: the style of its key in ``keys``
    (`style_of`), and where its group of ``groups`` (lines drawn on top of each other,
    `rbstudy.analysis.overlaps.coincident`) holds others, its turn among them."""
    return {
        j: (
            _coincident_style(style_of(keys[j], schemes), rank, len(group))
            if len(group) > 1
            else style_of(keys[j], schemes)
        )
        for group in groups
        for rank, j in enumerate(group)
    }


def draw_band(
    ax: Axes, x: np.ndarray, best: np.ndarray, worst: np.ndarray, floor: float | None, style: dict[str, Any]
) -> None:
    """The band from a line's ``best`` to its ``worst`` value
    (`rbstudy.analysis.figure_marks.band`), faint, its best edge a thin dotted line in the
    line's colour, zeros on the ``floor``."""
    low = np.where(best > 0, best, floor if floor is not None else np.nan)
    ax.fill_between(x, low, worst, color=style["color"], alpha=0.05, linewidth=0, zorder=1)
    ax.plot(x, low, color=style["color"], linestyle=(0, (1, 2)), linewidth=0.9, zorder=1)


def missing_text(bands: list[Band], line_dim: str | None, index: int, behind: int) -> str:
    """``no value in 17 of 68 cases`` for the line ``index`` of a figure whose points each
    stand for ``behind`` cases (`band`, per panel: more than one where an axis is reduced),
    where some of them failed or had no reference; else nothing."""
    if behind == 1:
        return ""
    counts = [lines_of(panel.missing, line_dim)[index].data.values for panel in bands]
    missing, cases = sum(int(c.sum()) for c in counts), sum(c.size for c in counts) * behind
    return f"no value in {missing} of {cases} cases" if missing else ""
