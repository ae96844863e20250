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
values becomes one panel per value; any other axis is reduced to a band
(`rbstudy.analysis.figure_marks.band`): the line is its worst case over the cases that gave
a value, a thin dotted line its best, the legend counts the cases that gave none (failed or
unjudged) and gives the orders fitted value by value; the panel title says so.

This module draws them all (`all_figures`) and names them for the report (`CAPTIONS`); each
kind of figure is drawn in a module of its own (`rbstudy.analysis.convergence_figure`,
`~.work_precision_figure`, `~.stability_figure`, `~.drift_figure`, `~.benchmark_figure`),
from what they share: the frame, legend and files (`~.figure_frame`), the words
(`~.figure_text`), the lines, panels and styles (`~.figure_lines`), and the marks
(`~.figure_marks`, `~.slope_guides`, `~.convergence_legend`). The figure functions are
importable from here.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import pathlib
import shutil
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple

import xarray as xr

from rbstudy.analysis.benchmark_figure import BENCHMARK_NODE, BENCHMARK_PICKS, benchmark, benchmark_case
from rbstudy.analysis.convergence_figure import convergence
from rbstudy.analysis.drift_figure import invariant_drift
from rbstudy.analysis.figure_frame import ALL_FORMATS, FORMATS, Figures, figure_name
from rbstudy.analysis.figure_lines import MAX_FACETS, MAX_LINES, figure_layout, line_styles
from rbstudy.analysis.figure_marks import ZERO_LABEL, plot_with_zeros, zero_floor
from rbstudy.analysis.stability_figure import stability_map
from rbstudy.analysis.summary import ERROR_MEASURES
from rbstudy.analysis.work_precision_figure import work_precision
from rbstudy.archive.files import inside, write_text_atomic
from rbstudy.errors import counted
from rbstudy.pipeline.progress import SILENT, Progress

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
    "BENCHMARK_PICKS",
    "BENCHMARK_NODE",
    "zero_floor",
    "plot_with_zeros",
]


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
_DRAWINGS: list[tuple[Callable[..., Figures], dict[str, Any]]] = [
    (convergence, {"measures": (key,)}) for key in ERROR_MEASURES
] + [(figure, {}) for figure in (work_precision, stability_map, invariant_drift, benchmark)]
# The drawing whose lines are not schemes: it takes no styles.
_UNSTYLED = (stability_map,)


class _Inherited(NamedTuple):
    """What the drawing processes of `all_figures` inherit: forked, they share the loaded
    dataset instead of receiving a copy."""

    ds: xr.Dataset
    folder: pathlib.Path
    formats: Sequence[str]
    styles: Mapping[str, Sequence[str]] | None


_INHERITED: _Inherited | None = None


def _draw(index: int) -> Figures:
    """The `Figures` of the drawing ``index`` of `_DRAWINGS`, of what `_INHERITED` holds."""
    figure, options = _DRAWINGS[index]
    assert _INHERITED is not None, "set by all_figures before it draws"
    if figure not in _UNSTYLED:
        options = {**options, "styles": _INHERITED.styles}
    return figure(_INHERITED.ds, _INHERITED.folder, _INHERITED.formats, **options)


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


def _record(manifest, digest, done):
    """Write ``manifest``: the ``digest`` the drawings ``done`` (index -> `Figures`) were
    drawn from, and per drawing its files (by stem), the formats they all exist in, and the
    figures it left out with why."""
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


def _reusable(ds, folder, formats, digest, drawn):
    """Drawing index -> `Figures` of the drawings that need no drawing: recorded in
    ``folder`` under ``digest``, or in one of the folders ``drawn`` (then copied into
    ``folder``). Without a record here, the study's earlier figures and record are removed."""
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
    return reused


def all_figures(
    ds: xr.Dataset,
    folder: str | os.PathLike[str],
    formats: Sequence[str] = FORMATS,
    processes: int = 1,
    digest: str | None = None,
    progress: Progress = SILENT,
    styles: Mapping[str, Sequence[str]] | None = None,
    drawn: Iterable[str | os.PathLike[str]] = (),
) -> Figures:
    """Every figure the dataset supports, as a `Figures` (files written in the first of
    ``formats``, absent with why), in the same order however drawn.

    ``processes`` > 1 draws them in that many forked processes (where the system forks:
    not on Windows), which share the loaded dataset. matplotlib draws in Python, one core a
    process. Fork only from a process without threads of its own (the command line), as a
    forked child holds only the forking thread.

    ``digest`` (a text naming what the figures are drawn from: the report's digest of the
    dataset and the sources that draw it) keeps the figures recorded beside them under the
    same digest and draws only the others; without it every figure is drawn and the record
    removed. ``progress`` (`rbstudy.pipeline.progress.Progress`) counts the drawings as they
    are done, and its end line tells the figures drawn and reused. ``styles``: the schemes'
    registered styles (name -> (colour, marker, line style); `rbstudy.schemes.scheme_styles`),
    which the digest must cover; a scheme without one is given one (`line_styles`).
    ``drawn``: other folders whose figures, recorded there under the same digest, are copied
    rather than drawn again (the report takes those that ``rbstudy plot`` drew beside the
    archive: a copy instead of a drawing).
    """
    global _INHERITED
    folder = pathlib.Path(folder)
    inside(folder, figure_name(ds, "*"))  # earlier drawings are deleted: only inside it
    reused = _reusable(ds, folder, formats, digest, drawn)
    todo = [index for index in range(len(_DRAWINGS)) if index not in reused]
    processes = min(processes, len(todo))
    _INHERITED = _Inherited(ds, folder, formats, styles)
    done = dict(reused)
    progress.phase(f"{ds.attrs['study']}: drawing figures", len(todo), "drawings")
    try:
        with contextlib.ExitStack() as stack:
            drawings: Iterator[Figures]
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
    progress.end = f"{counted(len(figures.written) - kept, 'figure')} drawn, {kept} reused"
    if digest is not None:
        _record(_manifest(folder, ds), digest, done)
    return figures
