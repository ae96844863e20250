"""`rbstudy report`: one self-contained HTML file per study, from its dataset only.

``<out>/report.html`` is the file to send: the study's findings first, a table of contents,
the per-scheme table with its footnotes, every figure of `rbstudy.analysis.plots` embedded as
a PNG data URI with a caption built from this study's numbers (which schemes, which swept
axis, the fitted orders, which lines coincide), the figures the study could not show and why,
and at the end the provenance and the config recorded in the dataset. It needs no other file:
the PNGs in ``<out>/figures/`` are kept only so that a later report of the same dataset reuses
them (their digest is recorded beside them, as ``rbstudy plot`` records it beside its own,
which a report copies rather than draws again); SVG files are written there, and linked, only on
request. A report folder belongs to one study (``.rbstudy-report`` names it): writing
another study's report there is refused. The page is the template ``report.html.j2``
(`rbstudy.analysis.pages`).
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import os
import pathlib
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import markupsafe
import numpy as np
import xarray as xr

from rbstudy.analysis.benchmark_figure import BENCHMARK_NODE, benchmark_case
from rbstudy.analysis.figure_frame import FORMATS
from rbstudy.analysis.figure_lines import figure_layout
from rbstudy.analysis.findings import calibrated, findings
from rbstudy.analysis.overlaps import coinciding_lines
from rbstudy.analysis.pages import data_uri, render
from rbstudy.analysis.plots import CAPTIONS, all_figures
from rbstudy.analysis.summary import (
    COINCIDENT_DIGITS,
    ERROR_MEASURES,
    FLOOR_WORDS,
    ROUND_OFF_ULPS,
    UNCERTAINTY_FACTOR,
    error_measure,
    floor_reason,
    format_table,
    order_text,
    per_scheme,
    scheme_rows,
    schemes_of,
    step_load,
    verdicts,
)
from rbstudy.archive.files import write_text_atomic
from rbstudy.errors import InputError
from rbstudy.inputs.reader import MAX_TITLE_CHARACTERS, Reader
from rbstudy.numerics.sources import SOURCE_DIGEST
from rbstudy.physics.metrics import (
    MAX_SLOPE_DRIFT,
    MIN_ASYMPTOTIC_POINTS,
    MIN_CONVERGENCE_ORDER,
    ORDER_SPREAD,
)
from rbstudy.pipeline.progress import SILENT, Progress

__all__ = ["write_report", "figures_digest", "captions", "MARKER", "REPORT_NAME"]

# The file that names the study a report folder belongs to.
MARKER = ".rbstudy-report"
REPORT_NAME = "report.html"
# The global attributes shown as provenance, in this order (the config has its own section).
_PROVENANCE = ("source", "versions", "history", "config_path", "batches", "platform", "python")
_ANALYSIS = pathlib.Path(__file__).resolve().parent


def _claim(out, study):
    """Make ``out`` this study's report folder, or refuse one that belongs to another."""
    marker = out / MARKER
    owner = marker.read_text().strip() if marker.is_file() else None
    if owner is not None and owner != study:
        raise InputError(
            f"holds the report of study {owner!r}, not {study!r}", "give --out another folder", str(out)
        )
    if owner is None and out.is_dir() and any(out.iterdir()):
        raise InputError(
            "is not empty and holds no rbstudy report", "give --out a new or empty folder", str(out)
        )
    write_text_atomic(study + "\n", marker)


def figures_digest(ds: xr.Dataset, styles: Mapping[str, Sequence[str]] | None = None) -> str:
    """What the figures of ``ds`` are drawn from, as one SHA-256: every variable's and
    coordinate's name, dimensions, type and values, the global attributes, the schemes'
    registered ``styles`` (a plug-in's, or an engine's that is installed here or not, are
    not in rbstudy's sources), and the sources that draw (the analysis layer and what
    computes, `SOURCE_DIGEST`) with matplotlib's version. The values themselves, not the
    archive's checksums attribute: with --no-verify an edited value must redraw too (and
    hashing the values is quick beside drawing)."""
    digest = hashlib.sha256()
    digest.update(f"{SOURCE_DIGEST} matplotlib {importlib.metadata.version('matplotlib')}".encode())
    for path in sorted(_ANALYSIS.rglob("*")):
        if path.is_file() and path.suffix in (".py", ".j2"):
            digest.update(path.read_bytes())
    for name, variable in sorted({**ds.coords, **ds.data_vars}.items()):
        values = np.asarray(variable.values)
        digest.update(f"{name} {variable.dims} {values.dtype} {sorted(variable.attrs.items())}".encode())
        digest.update(
            values.tobytes() if values.dtype.kind != "O" else "\0".join(map(str, values.ravel())).encode()
        )
    digest.update(repr(sorted(ds.attrs.items())).encode())
    digest.update(repr(sorted((name, tuple(style)) for name, style in (styles or {}).items())).encode())
    return digest.hexdigest()


def _listing(items):
    """``a, b and c``."""
    items = list(items)
    return items[0] if len(items) == 1 else f"{', '.join(items[:-1])} and {items[-1]}"


def _value(value):
    return f"{value:g}" if isinstance(value, float | np.floating) else str(value)


def _values(ds, dim):
    return _listing(map(_value, ds[dim].values))


def _lines_and_panels(ds, first):
    """What a figure along dt draws as lines, panels and worst cases, in words; after the
    ``first`` figure that said so, a pointer to it."""
    if first is not None:
        return f"lines and panels as in {first}"
    line, facet, reduced = figure_layout(ds)
    if line == "scheme":
        words = [f"a line per scheme ({_listing(schemes_of(ds))})"]
    elif line is not None:
        words = [f"a line per {line} ({_values(ds, line)})"]
    else:
        words = ["one line"]
    if facet is not None:
        words.append(f"a panel per {facet} ({_values(ds, facet)})")
    if reduced:
        words.append(
            f"a band over {_listing(reduced)} (the line the worst of the cases that gave a "
            "value, thin dots the best)"
        )
    return ", ".join(words)


def _convergence_caption(ds, rows, key, first):
    label, units = ERROR_MEASURES[key].label, ERROR_MEASURES[key].units
    errors = error_measure(ds, key)
    dts = ds["dt"].values
    line = figure_layout(ds).line
    text = (
        f"The {label}{'' if units == '1' else f' ({units})'} against dt from {dts.min():g} "
        f"to {dts.max():g} s, {_lines_and_panels(ds, first)}."
    )
    if key == "orientation":  # the table's fits: the words cannot disagree with it
        fitted = [f"{row['scheme']} {order_text(row)}" for row in rows if row["order"]]
        floored = {
            reason: [row["scheme"] for row in rows if floor_reason(row) == reason] for reason in FLOOR_WORDS
        }
        unfitted = [row["scheme"] for row in rows if not row["order"] and floor_reason(row) is None]
        if fitted:
            text += f" Fitted orders: {_listing(fitted)}."
        for reason, schemes in floored.items():
            if schemes:  # no order is fitted through errors at the floor
                text += f" {FLOOR_WORDS[reason].capitalize()}: {_listing(schemes)}."
        if unfitted:
            text += f" No asymptotic range: {_listing(unfitted)}."
    elif line in errors.dims:  # the finest step's error of each line, as the figure draws it
        finest = errors.sel(dt=dts.min())
        named = "" if line == "scheme" else f"{line} "
        words = []
        for value in ds[line].values:
            cases = np.ravel(finest.sel({line: value}).values)
            missing = int(np.isnan(cases).sum())
            if missing == cases.size:
                words.append(f"{named}{_value(value)} failed")
                continue
            lost = f" ({missing} of {cases.size} cases failed)" if missing else ""
            words.append(f"{named}{_value(value)} {np.nanmax(cases):.1e}{lost}")
        text += f" At the smallest dt ({dts.min():g} s) the worst errors: {_listing(words)}."
    pairs = [f"{first} = {second}" for first, second in coinciding_lines(ds, key)]
    if pairs:
        text += f" Coinciding to {COINCIDENT_DIGITS} digits: {_listing(pairs)}."
    return text


def _work_precision_caption(ds, rows, found, first):
    text = (
        f"{'Calibrated cost' if calibrated(ds) else 'Kernel time'} per case against the final "
        f"orientation error, a point per dt ({ds.sizes['dt']} values), {_lines_and_panels(ds, first)}."
    )
    # a step's cost as the figure draws it: the calibrated figure where the archive has one
    step_ns = {
        row["scheme"]: float(per_scheme(ds["step_seconds"], row["scheme"]).median()) * 1e9
        if calibrated(ds)
        else row["ns_per_step"]
        for row in rows
    }
    cost = sorted(step_ns, key=step_ns.get)
    if len(cost) > 1:
        text += (
            f" Cheapest step: {cost[0]} ({step_ns[cost[0]]:.0f} ns); "
            f"dearest: {cost[-1]} ({step_ns[cost[-1]]:.0f} ns)."
        )
    answer = next((f.text for f in found if f.kind in ("recommendation", "no_recommendation")), None)
    return text + (f" The study's answer: {answer}." if answer else "")


def _stability_caption(ds, rows):
    """The map's numbers in words: each scheme's cases by the verdicts the map draws
    (`verdicts`), so that no scheme is called accurate in every case where the map shows
    one failing; then the table's dt |w0| limits, which count physical bodies only."""
    load = step_load(ds).values
    text = (
        f"Each of the {load.size} cases by its dt |w0|, from {np.nanmin(load):.3g} to "
        f"{np.nanmax(load):.3g} rad."
    )
    counts = {scheme: [int(mask.sum()) for mask in verdicts(ds, scheme)] for scheme in schemes_of(ds)}
    always = [scheme for scheme, (good, *rest) in counts.items() if not any(rest)]
    if always:
        text += f" Accurate in every case: {_listing(always)}."
    kinds = ("inaccurate", "failed", "unjudged")
    others = [
        f"{scheme} {good} of {sum(count)} accurate, "
        + ", ".join(f"{n} {kind}" for n, kind in zip(rest, kinds, strict=True) if n)
        for scheme, count in counts.items()
        if scheme not in always
        for good, *rest in [count]
    ]
    if others:
        text += f" Not accurate in every case: {'; '.join(others)}."
    physical = "physical_body" in ds and not bool((ds["physical_body"] == 1).all())
    among = " (physical bodies, physical_body = 1)" if physical else ""
    limited = [
        f"{row['scheme']} to {row['accurate_hw']:.3g}"
        for row in rows
        if row["scheme"] not in always and np.isfinite(row["accurate_hw"])
    ]
    failing = [
        f"{row['scheme']} from {row['unstable_hw']:.3g}" for row in rows if np.isfinite(row["unstable_hw"])
    ]
    if limited:
        text += f" By dt |w0|{among}, accurate up to: {_listing(limited)}."
    if failing:
        text += f" Failing{among}: {_listing(failing)}."
    return text


def _drift_caption(ds, rows):
    end = float(ds["time"].values[-1]) if "time" in ds.coords else None
    text = (
        "Energy and angular-momentum errors against time"
        + (f" over {end:g} s" if end else "")
        + ", one case per scheme."
    )
    for invariant in ("energy", "|L|", "L"):
        keeping = [row["scheme"] for row in rows if invariant in row["kept"]]
        if keeping:
            text += f" Keep {invariant} to round-off: {_listing(keeping)}."
    drifting = [row["scheme"] for row in rows if row["invariants_measured"] and not row["kept"]]
    if drifting:
        text += f" Keep none: {_listing(drifting)}."
    return text


# The three benchmark figures, each what it plots.
_BENCHMARK_LEADS = {
    "benchmark_omega_time": "The global angular velocity components against time",
    "benchmark_omega_xy": "w_x against w_y in global axes, the tip of w circling the momentum axis",
    "benchmark_node_path": f"The path of node {BENCHMARK_NODE} seen down global z",
}


def captions(
    ds: xr.Dataset, names: Iterable[str], rows: list[dict[str, Any]], found: list[Any]
) -> dict[str, tuple[str, str | None]]:
    """Figure name (without the study) -> (caption from this study's numbers, ``rows`` (its
    `scheme_rows`) and ``found`` (its `findings`), how to read the kind of figure or None):
    the reading is given with the first figure of each kind, the lines and panels of the
    figures along dt with the first of them."""
    result, read, along_dt = {}, set(), None
    for name in names:
        kind = next((k for k in CAPTIONS if name.startswith(k)), None)
        if kind == "convergence":
            text = _convergence_caption(ds, rows, name.removeprefix("convergence_"), along_dt)
        elif kind == "work_precision":
            text = _work_precision_caption(ds, rows, found, along_dt)
        elif kind == "stability_map":
            text = _stability_caption(ds, rows)
        elif kind == "invariant_drift":
            text = _drift_caption(ds, rows)
        else:
            text = f"{_BENCHMARK_LEADS.get(name, name)}, for {benchmark_case(ds)[1]}."
        if kind in ("convergence", "work_precision") and along_dt is None:
            along_dt = name
        result[name] = (text, None if kind is None or kind in read else CAPTIONS[kind])
        read.add(kind)
    return result


def _page_title(ds, study):
    """The archive's title as the page heads it (its ``<title>`` and ``<h1>``): white space
    one space, at most `MAX_TITLE_CHARACTERS` (a config's bound; an archive made elsewhere
    may carry megabytes), cut with an ellipsis."""
    title = " ".join(str(ds.attrs.get("title", study)).split())
    if len(title) <= MAX_TITLE_CHARACTERS:
        return title
    return title[: MAX_TITLE_CHARACTERS - 1].rstrip() + "\u2026"


def _table_intro(ds):
    floor, ceiling = ERROR_MEASURES["orientation"].floor, ERROR_MEASURES["orientation"].ceiling
    return (
        "The table rbstudy sweep --wide prints, its footnotes under it. No order is fitted "
        f"through an error at the floor: below {UNCERTAINTY_FACTOR:g}x its integrated reference's "
        "uncertainty (reference_uncertainty), or at round-off, which is "
        f"{floor:g} rad or {ROUND_OFF_ULPS:g} ulps of the steps plus the largest angle the "
        "motion sweeps (|w| T times the largest over the smallest moment of inertia), whichever "
        "is larger. "
        f"The asymptotic range: the longest run of at least {MIN_ASYMPTOTIC_POINTS} "
        f"neighbouring steps with errors above the floor and below {ceiling:g} rad whose local "
        f"slopes agree within {ORDER_SPREAD:g} of the fitted "
        f"order (itself at least {MIN_CONVERGENCE_ORDER:g}) and do not drift by more than "
        f"{MAX_SLOPE_DRIFT:g} in their trend; among equally long runs, the finest. Accuracy "
        f"bound of this study: {ds.attrs.get('accuracy_bound', '-')} (rad for the "
        "orientation error at any sample, relative for energy and |L|)."
    )


def write_report(
    ds: xr.Dataset,
    out: str | os.PathLike[str],
    processes: int = 1,
    svg: bool = False,
    progress: Progress = SILENT,
    styles: Mapping[str, Sequence[str]] | None = None,
    drawn: Iterable[str | os.PathLike[str]] = (),
    searched: Sequence[str] = (),
) -> pathlib.Path:
    """Write ``out/report.html`` for dataset ``ds`` (its figures drawn, or reused, in
    ``out/figures/`` in ``processes`` processes, its schemes in their registered ``styles``
    (`rbstudy.analysis.plots.all_figures`), with SVG files linked when ``svg``; shown by
    ``progress``, a `rbstudy.pipeline.progress.Progress`); returns its path. The figures
    recorded in the folders ``drawn`` (``rbstudy plot``'s) under the same digest are copied
    from there rather than drawn. ``searched``: the lines of its step search
    (`rbstudy.analysis.searched.search_lines`), told after the findings."""
    out = pathlib.Path(out)
    # before the folder is claimed: the study names the figure files
    study = Reader(str(out)).folder_name(str(ds.attrs.get("study", "results")), "study")
    _claim(out, study)
    formats = FORMATS + ("svg",) if svg else FORMATS
    figures = all_figures(
        ds,
        out / "figures",
        formats,
        processes,
        digest=figures_digest(ds, styles),
        progress=progress,
        styles=styles,
        drawn=drawn,
    )
    progress.phase(f"{study}: writing {REPORT_NAME}")
    names = [png.stem.removeprefix(f"{study}_") for png in figures.written]
    rows = scheme_rows(ds)
    found = findings(ds, rows)
    texts = captions(ds, names, rows, found)
    shown = [
        {
            "name": name,
            "anchor": f"figure-{name}",
            "source": data_uri(png),
            "caption": texts[name][0],
            "reading": texts[name][1],
            "svg": png.with_suffix(".svg").relative_to(out).as_posix() if svg else None,
        }
        for name, png in zip(names, figures.written, strict=True)
    ]
    dims = ", ".join(f"{d} ({ds.sizes[d]})" for d in ds["status"].dims) or "one case"
    provenance = [(key, str(ds.attrs[key])) for key in _PROVENANCE if key in ds.attrs]
    page = render(
        "report.html.j2",
        title=_page_title(ds, study),
        study=study,
        cases=int(ds["status"].size),
        dims=dims,
        findings=found,
        searched=searched,
        table_intro=_table_intro(ds),
        # tabulate escapes the cells, format_table the footnotes
        table=markupsafe.Markup(format_table(rows, wide=True, fmt="html")),
        figures=shown,
        absent=figures.absent,
        provenance=provenance,
        config=ds.attrs.get("config", ""),
    )
    report = out / REPORT_NAME
    write_text_atomic(page, report)
    return report
