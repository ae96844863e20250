"""The verbs that read archives: ``summary`` prints the findings and the per-scheme table
again, ``plot`` draws the figures, ``report`` writes the HTML report, ``verify`` proves the
files intact by their checksums; each reads only what it needs, never reruns a study.
"""

from __future__ import annotations

import argparse
import functools
import os
import pathlib
from collections.abc import Sequence
from typing import Any

from rbstudy.commands.common import Dataset, check_out, each_file, say, styles_of, wrapped
from rbstudy.errors import InputError, RbstudyError, counted

__all__ = ["plot", "report", "searched_lines", "select_cases", "summary", "summary_text", "verify"]

# `--select dt=0.0003125` finds the stored dt although decimal text and binary floats differ.
_SELECT_RTOL = 1e-12


def summary_text(dataset: Dataset, wide: bool = False, table_only: bool = False) -> str:
    """The findings (unless ``table_only``), then the per-scheme table (every column when
    ``wide``)."""
    from rbstudy.analysis.findings import findings
    from rbstudy.analysis.summary import format_table, scheme_rows
    from rbstudy.analysis.summary_forms import finding_lines

    rows = scheme_rows(dataset)
    table = format_table(rows, wide=wide)
    return table if table_only else "\n".join(finding_lines(findings(dataset, rows)) + ["", table])


def summary(args: argparse.Namespace) -> int:
    """``rbstudy summary``: the findings and the table of each archive again, as text,
    Markdown, CSV or JSON (with the step search kept in it, where there is one)."""
    import csv
    import io
    import json

    from rbstudy.analysis.findings import FINDINGS_REDUCED, FINDINGS_VARIABLES
    from rbstudy.analysis.summary_forms import csv_rows, markdown_summary, summary_document
    from rbstudy.archive.reader import open_archive
    from rbstudy.numerics.machine import return_free_memory
    from rbstudy.pipeline.progress import Progress, live_wanted

    # its phases on a terminal only: elsewhere its stderr holds nothing but errors, for the
    # scripts that read its JSON or CSV
    with Progress("summary", "", quiet=not live_wanted(args.quiet), opening="starting") as progress:
        # the per-case scalars, not the trajectories: 1e6 cases read whole took 4.5 GB
        datasets = [
            open_archive(
                path,
                FINDINGS_VARIABLES,
                verify=not args.no_verify,
                reduced=FINDINGS_REDUCED,
                progress=progress,
            )
            for path in args.files
        ]
        return_free_memory()  # the reading's transients, before the findings
        progress.phase("summary: computing the findings")
        if args.format == "json":  # checked before anything is printed
            documents = [
                _with_search(summary_document(dataset), path, dataset)
                for path, dataset in zip(args.files, datasets, strict=True)
            ]
            text = json.dumps(documents[0] if len(documents) == 1 else documents, indent=1, allow_nan=False)
        elif args.format == "csv":
            rows = [row for dataset in datasets for row in csv_rows(dataset)]
            table = io.StringIO()
            writer = csv.DictWriter(table, fieldnames=list(rows[0]), lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
            text = table.getvalue().removesuffix("\n")
        else:

            def render(path, dataset):
                text = (
                    markdown_summary(dataset)
                    if args.format == "md"
                    else summary_text(dataset, wide=args.wide, table_only=args.quiet)
                )
                searched = [] if args.quiet else searched_lines(path, dataset, said_where=True)
                if not searched:
                    return text
                if args.format == "md":
                    return "\n\n".join([text, "\n".join(f"- {line}" for line in searched)])
                return "\n\n".join([text, wrapped(searched)])

            text = "\n\n".join(
                render(path, dataset)
                if len(datasets) == 1 or args.format == "md"
                else f"== {path}\n{render(path, dataset)}"
                for path, dataset in zip(args.files, datasets, strict=True)
            )
    print(text)  # once the phases are erased
    return 0


def searched_lines(path: str | os.PathLike[str], dataset: Dataset, said_where: bool = False) -> list[str]:
    """The lines that tell the step search kept in the archive at ``path``, read as
    ``dataset`` (none where there is none), and where it is kept when ``said_where``."""
    from rbstudy.analysis.searched import read_search, search_lines

    search = read_search(path, dataset)
    if search is None or isinstance(search, str):
        return [] if search is None else [search]
    return search_lines(search, dataset) + [f"(the step search kept in {path}, group search)"] * said_where


def _with_search(document: dict[str, Any], path: str, dataset: Dataset) -> dict[str, Any]:
    """``document`` (`summary_document`) with the step search kept in the archive at
    ``path``, read as ``dataset``, as its ``step_search`` (`search_document`; ``{"refused": why}``
    where it is another study's), where there is one."""
    from rbstudy.analysis.searched import read_search, search_document

    search = read_search(path, dataset)
    if search is None:
        return document
    return document | {
        "step_search": {"refused": search} if isinstance(search, str) else search_document(search, dataset)
    }


def plot(args: argparse.Namespace) -> int:
    """``rbstudy plot``: the figures of each archive (narrowed by ``--select``) drawn into
    its folder."""
    from rbstudy.analysis.plots import all_figures
    from rbstudy.analysis.report import figures_digest
    from rbstudy.archive.reader import open_archive
    from rbstudy.numerics.machine import default_threads
    from rbstudy.pipeline.progress import Progress

    if args.select and not args.out:
        raise RbstudyError(
            "--select needs --out: the selected figures would replace the study's full set beside the archive"
        )
    folders = {
        path: pathlib.Path(args.out) if args.out else pathlib.Path(path).parent / "figures"
        for path in args.files
    }
    for folder in dict.fromkeys(folders.values()):
        check_out(folder, given=bool(args.out))
    opened = functools.partial(open_archive, verify=not args.no_verify)
    if len(args.files) > 1:
        studies, opened = _studies(args.files, args, args.select)
        for path, study in zip(args.files, studies, strict=True):
            if args.out and studies.count(study) > 1:
                raise InputError(
                    f"another file of this command is also study {study!r}: "
                    "their figures would overwrite each other in --out",
                    "plot them one at a time, each with its own --out",
                    path,
                )
    formats = tuple(dict.fromkeys(args.format or ("png",)))  # `--format png,svg,png`: once
    for path in args.files:
        folder = folders[path]
        with Progress(
            path, f"drawing its figures into {folder}", quiet=args.quiet, opening="reading"
        ) as progress:
            dataset = select_cases(opened(path), args.select, path)
            styles = styles_of(dataset)
            # recorded beside them, for a report of the same archive to copy them
            figures = all_figures(
                dataset,
                folder,
                formats,
                processes=default_threads(),
                digest=figures_digest(dataset, styles),
                progress=progress,
                styles=styles,
            )
        kinds = " and ".join(kind.upper() for kind in formats)
        print(f"{path}: {counted(len(figures.written), 'figure')} ({kinds}) in {folder}")
        if not args.quiet:
            for name, reason in figures.absent.items():
                say(f"  not drawn: {name}: {reason}")
    return 0


def _studies(paths, args, select=None):
    """The study of each archive of ``paths``, every one read before any is drawn (only its
    bookkeeping, one at a time; proven intact unless --no-verify; narrowed by ``select``, so
    that a bad choice fails first), and how to open each in full then (not verified again)."""
    from rbstudy.archive.reader import open_archive
    from rbstudy.archive.variables import BOOKKEEPING

    studies = [
        str(
            select_cases(open_archive(path, BOOKKEEPING, verify=not args.no_verify), select, path).attrs[
                "study"
            ]
        )
        for path in paths
    ]
    return studies, functools.partial(open_archive, verify=False)


def select_cases(dataset: Dataset, choices: Sequence[str] | None, path: str) -> Dataset:
    """Narrow ``dataset`` to ``DIM=VALUE`` choices (each dimension kept, of length one)."""
    for choice in choices or ():
        dim, _, text = choice.partition("=")
        swept = list(dataset["status"].dims)
        if dim not in swept:
            raise InputError(
                f"{dim!r} is not a swept dimension here",
                f"use one of {', '.join(swept) or 'none'}",
                path,
                f"--select {choice}",
            )
        coordinate = dataset[dim].values
        try:
            value = text if coordinate.dtype.kind in "OUS" else float(text)
        except ValueError:
            raise InputError(f"{dim} takes a number", None, path, f"--select {choice}") from None
        match = [
            v
            for v in coordinate
            if v == value
            or (coordinate.dtype.kind == "f" and abs(v - value) <= _SELECT_RTOL * abs(float(value)))
        ]
        if not match:
            raise InputError(
                f"no {dim} = {text}",
                "the values are " + ", ".join(str(v) for v in coordinate),
                path,
                f"--select {choice}",
            )
        dataset = dataset.sel({dim: match})
    return dataset


def report(args: argparse.Namespace) -> int:
    """``rbstudy report``: the HTML report of each archive, with its figures."""
    from rbstudy.analysis.report import write_report
    from rbstudy.archive.reader import open_archive
    from rbstudy.numerics.machine import default_threads
    from rbstudy.pipeline.progress import Progress

    opened = functools.partial(open_archive, verify=not args.no_verify)
    if len(args.files) == 1:  # -o names the report folder itself, as cp's target names a copy
        folders = [pathlib.Path(args.out or pathlib.Path(args.files[0]).parent / "report")]
    else:
        studies, opened = _studies(args.files, args)
        folders = _report_folders(args.files, studies, args.out)
    for folder in dict.fromkeys(folders):
        check_out(folder, given=bool(args.out))
    for path, folder in zip(args.files, folders, strict=True):
        with Progress(
            path, f"writing its report into {folder}", quiet=args.quiet, opening="reading"
        ) as progress:
            dataset = opened(path)
            report = write_report(
                dataset,
                folder,
                processes=default_threads(),
                svg=args.svg,
                progress=progress,
                styles=styles_of(dataset),
                drawn=[pathlib.Path(path).parent / "figures"],  # `rbstudy plot`'s, to copy
                searched=searched_lines(path, dataset),
            )
        print(f"{path}: report in {report}")
    return 0


def _report_folders(paths, studies, out):
    """The report folder of each archive of several: ``out/<study>``, or else ``report/``
    beside each archive; two archives that would share one are refused."""
    folders = [
        pathlib.Path(out, study) if out else pathlib.Path(path).parent / "report"
        for path, study in zip(paths, studies, strict=True)
    ]
    places = [folder.resolve() for folder in folders]
    for path, study, place in zip(paths, studies, places, strict=True):
        if places.count(place) > 1 and out:
            raise InputError(
                f"another file of this command is also study {study!r}: their "
                f"reports would overwrite each other in {out}",
                "report them one at a time, each with its own -o",
                path,
            )
        if places.count(place) > 1:
            raise InputError(
                "another file of this command lies in the same folder: their "
                f"reports would both go to {place}",
                "give -o DIR (a folder per study inside it)",
                path,
            )
    return folders


def verify(args: argparse.Namespace) -> int:
    """``rbstudy verify``: each file proven intact by its checksums, or told damaged."""
    from rbstudy.archive.reader import verify_file

    def proven(path):
        said = verify_file(path)
        return "" if args.quiet else f"{path}: {said}"

    return each_file(args.files, proven)
