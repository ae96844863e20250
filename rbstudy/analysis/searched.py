"""The words of a step search (``rbstudy sweep --find-step``, `rbstudy.pipeline.step_search`):
the largest step that meets the accuracy bound, beside the grid's best.

The search keeps its probes and answers in the archive, as its netCDF group ``search``
(`rbstudy.archive.layout.SEARCH_GROUP`, sealed with the archive's checksums); `read_search`
reads them back for the sweep that ran it and for ``summary`` and ``report``, here in the
analysis layer, which never loads the kernels. Costs are those the findings rank the grid
by (steps times the calibrated seconds a step, mean over the other axes' values), and costs
within their calibration's uncertainty are one answer.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
import xarray as xr

from rbstudy.analysis.findings import study_wide
from rbstudy.archive.layout import SEARCH_GROUP, CommonStep
from rbstudy.archive.load import read_group

__all__ = ["SearchRecord", "read_search", "search_lines", "search_document"]


@dataclass(frozen=True)
class SearchRecord:
    """A step search as its file keeps it, per group (g,) (a scheme at one value of the
    other axes): ``scheme``, ``found_dt`` (s; NaN: not searched) and ``failing_dt`` (s; NaN:
    none up to the duration); ``axes`` the other swept axes' names; ``common`` scheme ->
    its `CommonStep`, the step met at every value;
    ``tolerance``; ``probes``, how many it ran; ``adaptive``, the schemes not searched
    because they choose their own steps."""

    scheme: np.ndarray
    found_dt: np.ndarray
    failing_dt: np.ndarray
    axes: tuple[str, ...]
    common: dict[str, CommonStep]
    tolerance: float
    probes: int
    adaptive: tuple[str, ...] = ()


def read_search(path: str | os.PathLike[str], ds: xr.Dataset) -> SearchRecord | str | None:
    """The `SearchRecord` kept in the archive at ``path`` (read as ``ds``); None where it
    holds none, or a line saying why it cannot be told (another version of its study)."""
    try:
        kept = read_group(path, SEARCH_GROUP)
    except (OSError, ValueError) as error:
        return f"{path}: its step search is not readable ({error}); sweep --find-step again"
    if kept is None:
        return None
    if "found_dt" not in kept or kept.attrs.get("batches") != ds.attrs.get("batches"):
        return f"{path}: its step search is of another version of this study; sweep --find-step again"
    names = [str(name) for name in kept["study_scheme"].values] if "study_scheme" in kept else []
    return SearchRecord(
        scheme=np.array([str(name) for name in kept["group_scheme"].values], dtype=object),
        found_dt=kept["found_dt"].values,
        failing_dt=kept["failing_dt"].values,
        axes=tuple(kept.attrs.get("other_axes", "").split()),
        common={
            name: CommonStep(float(dt), float(seconds), float(spread))
            for name, dt, seconds, spread in zip(
                names,
                kept["study_dt"].values,
                kept["study_seconds"].values,
                kept["study_uncertainty"].values,
                strict=True,
            )
        }
        if names
        else {},
        tolerance=float(kept.attrs["tolerance"]),
        probes=int(kept.sizes.get("probe", 0)),
        adaptive=tuple(kept.attrs.get("adaptive_schemes", "").split()),
    )


def _g(value, digits=3):
    return f"{value:.{digits}g}"


def _share(tolerance):
    """A share as a percentage to 3 figures: ``5%``, ``0.1%``, ``1e-07%`` (not ``0%``)."""
    return f"{100 * tolerance:.3g}%"


def _axes_text(search):
    """``every inertia_ratio`` (the other swept axes), or empty with none."""
    return f"every {', '.join(search.axes)}" if search.axes else ""


def _cheapest(common):
    """The cheapest scheme of ``common`` (name -> `CommonStep`) and the others whose costs'
    ranges overlap its own, cheapest first."""
    ranked = sorted(common, key=lambda name: (common[name].seconds, name))
    least, spread = common[ranked[0]].seconds, common[ranked[0]].uncertainty
    spread = 0.0 if math.isnan(spread) else spread
    reach = least * (1.0 + spread)
    tied = [name for name in ranked[1:] if common[name].seconds * (1.0 - common[name].uncertainty) <= reach]
    return ranked[0], tied


def _answer_line(search, ds, bound, axes):
    """The study-wide answer: the cheapest scheme at its least found step."""
    scope = f"searched to {_share(search.tolerance)}" + (f", {axes}" if axes else "")
    if not search.common:
        return f"step search ({scope}): no scheme meets the bound {_g(bound)} at one step in every case"
    best, tied = _cheapest(search.common)
    dt, seconds = search.common[best].dt, search.common[best].seconds
    named = best if not tied else ", ".join([best, *tied[:-1]]) + f" or {tied[-1]}, equal cost,"
    steps = {search.common[name].dt for name in (best, *tied)}
    at = f"at dt={_g(dt)} s" if len(steps) == 1 else "each at its step"
    text = f"largest step meeting the bound {_g(bound)} ({scope}): {named} {at}, {_g(seconds, 2)} s a case"
    grid = study_wide(ds)
    if grid is None:
        return text + "; the grid has no one answer for every case to compare"
    ratio = grid.seconds / seconds
    compared = f"{ratio:.1f}x cheaper than" if ratio >= 1.05 else "as costly as"
    named = [grid.scheme, *(name for name, step in grid.tied if step == grid.dt)]
    schemes = named[0] if len(named) == 1 else ", ".join(named[:-1]) + f" or {named[-1]}"
    best = f"{schemes} at dt={_g(grid.dt)} s, {_g(grid.seconds, 2)} s a case"
    return f"{text}, {compared} the grid's best ({best})"


def _scheme_texts(search):
    """Each searched scheme's found steps, ``rk4 0.0833`` or ``euler 0.0004-0.0008`` (least
    to most over the other axes' values), cheapest at its least first, with what bounds them
    where a step within the tolerance above does not fail (`_bracket_note`); then the schemes
    that met the bound nowhere on the grid (adaptive ones aside: they are not searched)."""
    texts, nowhere = [], []
    names = sorted(
        set(search.scheme), key=lambda n: (search.common[n].seconds if n in search.common else math.inf, n)
    )
    for name in names:
        mine = search.scheme == name
        found = search.found_dt[mine]
        if not np.isfinite(found).any():
            if name not in search.adaptive:
                nowhere.append(name)
            continue
        least, most = float(np.nanmin(found)), float(np.nanmax(found))
        span = _g(least) if _g(least) == _g(most) else f"{_g(least)}-{_g(most)}"
        everywhere = name in search.common
        notes = [_bracket_note(found, search.failing_dt[mine], search.tolerance)]
        notes += [] if everywhere else ["not at every value"]
        notes = [note for note in notes if note]
        texts.append(f"{name} {span}" + (f" ({', '.join(notes)})" if notes else ""))
    return texts, nowhere


def _bracket_note(found, failing, tolerance):
    """What ends a scheme's search where no step within ``tolerance`` above its found one
    fails: the whole run in one step met the bound, or the next whole division of the
    duration (``+33%``) is the nearest larger step."""
    searched = np.isfinite(found)
    if np.isnan(failing[searched]).all():
        return "the whole run in one step"
    with np.errstate(invalid="ignore"):
        widest = np.nanmax(failing[searched] / found[searched]) - 1.0
    return f"next larger step +{widest:.0%}" if widest > tolerance * (1 + 1e-9) else ""


def search_lines(search: SearchRecord, ds: xr.Dataset) -> list[str]:
    """The lines that tell a `SearchRecord` ``search`` of the study of archive ``ds``."""
    bound = ds.attrs.get("accuracy_bound")
    axes = _axes_text(search)
    lines = [_answer_line(search, ds, bound, axes)]
    texts, nowhere = _scheme_texts(search)
    if texts:
        over = f", least-most over {axes.removeprefix('every ')}" if axes else ""
        head = f"largest steps found (s{over}, {_share(search.tolerance)} larger fails): "
        lines.append(head + ", ".join(texts))
    if nowhere:
        lines.append(f"not searched (no swept step meets the bound): {', '.join(nowhere)}")
    if search.adaptive:
        lines.append(f"not searched (adaptive: each chooses its own steps): {', '.join(search.adaptive)}")
    return lines


def search_document(search: SearchRecord, ds: xr.Dataset) -> dict[str, Any]:
    """The JSON form of a `SearchRecord` (``summary --format json``'s ``step_search``):
    the tolerance, each scheme's step met at every value of the other axes with its cost
    (cheapest first), each scheme's least and most found step over those values, and the
    lines `search_lines` tells."""
    names = sorted(search.common, key=lambda name: (search.common[name].seconds, name))
    found = {}
    for name in sorted(set(search.scheme)):
        steps = search.found_dt[search.scheme == name]
        steps = steps[np.isfinite(steps)]
        found[name] = {
            "least_dt_s": float(steps.min()) if steps.size else None,
            "most_dt_s": float(steps.max()) if steps.size else None,
        }
    return {
        "tolerance": search.tolerance,
        "probes": search.probes,
        "every_value": [
            {"scheme": name, "dt_s": search.common[name].dt, "seconds_per_case": search.common[name].seconds}
            for name in names
        ],
        "found": found,
        "lines": search_lines(search, ds),
    }
