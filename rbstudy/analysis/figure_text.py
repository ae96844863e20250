"""The words on a figure: its title, the panels' titles, and text wrapped to the room it has.

Text is measured by an estimate of each character's width (`em_width`), not by matplotlib:
its own wrapping measures the text word by word at every draw, a noticeable share of a
figure's drawing time.
"""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties

__all__ = [
    "TITLE_LINES",
    "em_width",
    "wrapped",
    "title",
    "value_text",
    "panel_title",
    "overlap_title",
    "aside",
]

# Widths of DejaVu Sans characters in em, rounded up (`em_width`).
_NARROW, _WIDE = set(" .,;:'|!()[]ijlft-"), set("MWmw")
_NARROWEST_EM = 0.35
# The study's title heads every figure in at most this many lines, its end cut with an
# ellipsis: an archive made elsewhere may carry a title of any length (a megabyte of one held
# `plot` up, and its lines covered every panel).
TITLE_LINES = 2
_ELLIPSIS = "\u2026"


def em_width(text: str) -> float:
    """The width of ``text`` in em of its font, estimated character by character."""
    return sum(
        _NARROWEST_EM if c in _NARROW else 1.0 if c in _WIDE else 0.75 if c.isupper() else 0.64 for c in text
    )


def wrapped(text: str, width_em: float) -> str:
    """``text`` broken at spaces into lines of at most ``width_em`` (by `em_width`)."""
    lines: list[str] = []
    for word in text.split(" "):
        if lines and em_width(f"{lines[-1]} {word}") <= width_em:
            lines[-1] = f"{lines[-1]} {word}"
        else:
            lines.append(word)
    return "\n".join(lines)


def _fitting(text: str, width_em: float) -> int:
    """How many of ``text``'s first characters fit in ``width_em`` (at least one)."""
    width = 0.0
    for count, character in enumerate(text):
        width += em_width(character)
        if width > width_em:
            return max(count, 1)
    return len(text)


def _shortened(text: str, width_em: float, lines: int) -> str:
    """``text`` wrapped to ``width_em`` in at most ``lines`` lines (a word wider than a line
    broken), its end cut with an ellipsis when it is longer. Only what could fit is measured,
    once runs of white space are one space (a run longer than the room would leave fewer
    lines than ``lines`` and the words after it unseen)."""
    text = " ".join(text.split())
    room = int(lines * width_em / _NARROWEST_EM) + 1
    words = []
    for word in text[:room].split():
        while len(word) > 1 and em_width(word) > width_em:
            cut = _fitting(word, width_em)
            words.append(word[:cut])
            word = word[cut:]
        words.append(word)
    shown = wrapped(" ".join(words), width_em).split("\n")
    if len(shown) <= lines and len(text) <= room:
        return "\n".join(shown)
    last = shown[lines - 1]
    last = last[: _fitting(last, width_em - em_width(_ELLIPSIS))].rstrip()
    return "\n".join([*shown[: lines - 1], last + _ELLIPSIS])


def title(fig: Figure, ds: xr.Dataset, what: str) -> None:
    """Head ``fig`` with the study's title (at most `TITLE_LINES` lines of it) and ``what``
    the figure shows, each wrapped to the figure's width."""
    size = FontProperties(size=plt.rcParams["figure.titlesize"]).get_size_in_points()
    width_em = 0.97 * fig.get_figwidth() * 72 / size
    study_title = _shortened(str(ds.attrs.get("title", "")), width_em, TITLE_LINES)
    fig.suptitle(f"{study_title}\n{wrapped(what, width_em)}")


def value_text(dim: str, value: Any) -> str:
    """``inertia_ratio = 0.5``: an axis at one of its values (a number in ``%g``)."""
    shown = f"{value:g}" if isinstance(value, (float, np.floating)) else str(value)
    return f"{dim} = {shown}"


def panel_title(
    dim: str | None, value: Any, reduced: list[str], lines: str = "line: worst, thin dots: best"
) -> str:
    """``inertia_ratio = 0.5; line: worst, thin dots: best, over spin``: which cases a
    panel shows (none named where ``dim`` is None), its ``lines`` over the ``reduced`` axes
    (`rbstudy.analysis.figure_marks.band`)."""
    parts = [] if dim is None else [value_text(dim, value)]
    if reduced:
        parts.append(f"{lines}, over {', '.join(reduced)}")
    return "; ".join(parts)


def overlap_title(ax: Axes, fig: Figure, text: str, notes: list[str]) -> str:
    """A panel's title ``text`` and, on lines of their own wrapped to the panel's width, the
    ``notes`` of the lines it draws on top of each other (`rbstudy.analysis.overlaps`): over
    the panel, never over its data."""
    if not notes:
        return text
    width_em = 0.9 * ax.get_position().width * fig.get_figwidth() * 72 / plt.rcParams["axes.titlesize"]
    note = wrapped(f"on top of each other: {'; '.join(notes)}", width_em)
    return f"{text}\n{note}" if text else note


def aside(text: str, form: str) -> str:
    """``text`` in ``form`` (``"; {}"``), or nothing when there is no text."""
    return form.format(text) if text else ""
