"""Command line: ``rbstudy sweep | validate | schemes | plot | report | summary | bench |
verify | conformance``.

``sweep`` runs each study config and writes ``OUT/<study>/<study>.nc``, then prints the
study's findings and per-scheme summary; ``summary`` prints them again from archives;
``validate`` checks configs without running anything.

Exit codes, as the command-line tools users know have them: 0 success; 1 a user's mistake
(`RbstudyError`), told in one line naming the file, the key and the fix; 2 bad usage (from
argparse); 70 a bug in rbstudy (`EX_SOFTWARE`), the only case with a traceback, and a line
asking for a report; 141 (as for a broken pipe) without a word when the reader of the output
has gone (``| head -1``): the command stops there.
"""

import argparse
import contextlib
import dataclasses
import functools
import gc
import logging
import math
import os
import pathlib
import re
import shutil
import sys
import tempfile
import textwrap
import threading
import traceback

from rbstudy.errors import ConfigError, InputError, RbstudyError, counted, did_you_mean, printable

__all__ = ["main", "command", "EXIT_OK", "EXIT_USER_ERROR", "EXIT_USAGE", "EXIT_BUG", "EXIT_PIPE"]

EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE = 0, 1, 2
EXIT_BUG = 70  # EX_SOFTWARE of sysexits.h: an internal error
EXIT_PIPE = 141  # 128 + SIGPIPE, as other tools end when their reader has gone

# `--select dt=0.0003125` finds the stored dt although decimal text and binary floats differ.
_SELECT_RTOL = 1e-12
# `rbstudy conformance --steps`: 8 halvings take the golden set's work 32 times past the
# default 4 (~20 minutes for 13 schemes on 2 cores).
MAX_GOLDEN_STEPS = 8


def _schemes(args):
    from rbstudy.analysis.summary import TERMINAL_WIDTH
    from rbstudy.schemes import COMPOSITION_ORDERS, INVARIANTS, SCHEMES, unavailable_schemes

    if args.quiet:  # for scripts, as `docker ps -q` lists ids: `rbstudy bench $(...)`
        print("\n".join(SCHEMES))
        return 0
    missing = unavailable_schemes()
    width = max(map(len, [*SCHEMES, *missing]))
    kinds = max(len(scheme.kind) for scheme in SCHEMES.values())  # "linearly implicit"
    # the summaries wrap within the terminal, under their column (at least 30 wide)
    column = width + 1 + 7 + 1 + kinds + 1 + 16 + 1  # " {order:>7} {kind} {keeps:16} "
    text = functools.partial(
        textwrap.fill,
        width=max(TERMINAL_WIDTH, column + 30),
        subsequent_indent=" " * column,
        break_on_hyphens=False,
    )
    print(f"{'scheme':{width}s} {'order':>7s} {'kind':{kinds}s} {'keeps':16s} options / summary")
    for name, scheme in SCHEMES.items():
        keeps = ", ".join(INVARIANTS[name] for name in scheme.keeps) or "-"
        options = ", ".join(f"{o.name}={o.default}" for o in scheme.options)
        # a composition's orders: "2,4,6,8"
        orders = next(
            (",".join(map(str, COMPOSITION_ORDERS)) for o in scheme.options if o.sets_order),
            str(scheme.order),
        )
        # "rbstudy's adapter of mujoco 4.0.0" (`rbstudy.engines`), or a plug-in's package
        origin = (
            ""
            if scheme.origin == "rbstudy"
            else f" ({scheme.origin})"
            if scheme.origin.startswith("rbstudy's ")
            else f" (plug-in: {scheme.origin})"
        )
        print(
            text(
                scheme.summary + (f" [{options}]" if options else "") + origin,
                initial_indent=f"{name:{width}s} {orders:>7s} {scheme.kind:{kinds}s} {keeps:16s} ",
            )
        )
    for name, why in missing.items():
        print(
            text(
                f"{why.reason}; fix: {why.fix} ({why.origin})",
                initial_indent=f"{name:{width}s} {'-':>7s} {'unavailable':{kinds + 17}s} ",
            )
        )
    return 0


def _bench(args):
    from rbstudy.pipeline.bench import BODY_STEPS, MAX_BODY_STEPS, option_settings, run_bench
    from rbstudy.schemes import expand_groups

    if args.body_steps is not None and not 1 <= args.body_steps <= MAX_BODY_STEPS:
        raise RbstudyError(f"--body-steps: need 1 to {MAX_BODY_STEPS:.0e}, got {args.body_steps:.3g}")
    # groups as conformance takes them: `bench builtin`, `bench --schemes mujoco,rk4`
    run_bench(
        schemes=expand_groups([*args.scheme_names, *(args.schemes or ())]) or None,
        body_steps=args.body_steps or BODY_STEPS,
        progress=not args.quiet,
        options=option_settings(args.option or ()),
    )
    return 0


def _costed(study, args, disk):
    """The study's one-line estimate (and a line per note and warning of the study), after refusing
    it past the limits of ``args`` (and past the free disk under ``args.out`` when ``disk``:
    a sweep checks it once it knows which parts are already there)."""
    from rbstudy.pipeline.estimate import (
        check_disk,
        check_limits,
        describe,
        estimate,
        forecast_disk,
        zarr_advice,
    )

    for option, value in (("--max-body-steps", args.max_body_steps), ("--max-memory", args.max_memory)):
        if value is not None and not value > 0:
            raise RbstudyError(f"{option} takes a number above 0, got {value:g}")
    cost = estimate(study)
    max_memory = None if args.max_memory is None else args.max_memory * 2**20
    check_limits(study, cost, args.max_body_steps, max_memory)
    if disk:
        check_disk(study, forecast_disk(study, args.out), args.out)
    notes = [f"{study.path}: note: {note}" for note in study.notes]
    advice = zarr_advice(study, cost)
    lines = [describe(study, cost), *([advice] if advice else []), *notes, *_warning_lines(study)]
    return "\n".join(lines)


def _warning_lines(study):
    """What the reading accepted but a user should know (a regularised body, a knot
    mid-step), a line each."""
    return [f"{study.path}: warning: {warning}" for warning in study.warnings]


def _check_out(folder, given=True):
    """Refuse an output folder rbstudy could not write (a file, a path under one, /proc, a
    read-only or immutable folder) in one line, before a command prints or computes anything;
    ``given``: the folder is the user's --out (else a command's default folder)."""
    from rbstudy.archive.files import check_output_folder

    check_output_folder(folder, "--out " if given else "")


def _check_root(root):
    """Refuse the results root ``root`` (--out) in one line when it is no folder (a file, a
    device, a path under a file); return the `UnwritableFolder` error of a folder rbstudy
    cannot write (read-only), which a rerun whose archives are up to date needs no write
    of, or None."""
    from rbstudy.archive.files import UnwritableFolder

    try:
        _check_out(root)
    except UnwritableFolder as error:
        if not pathlib.Path(root).is_dir():  # a file, under a file: no archive to find there
            raise
        return error
    return None


def _study_folders(studies, args):
    """Check --out and each study's folder in it before a sweep prints anything, and return
    the names of the studies whose folder cannot be written but holds an archive: a rerun
    may still find it up to date, which needs no write (`run_study` tells, or refuses in
    one line naming the folder). A folder that cannot be written is refused at once under
    --force, and where it holds no archive."""
    from rbstudy.archive.files import UnwritableFolder
    from rbstudy.archive.folder import StudyFolder

    root = pathlib.Path(args.out)
    refused = _check_root(root)
    read_only = set()
    for study in studies:
        folder = root / study.name
        try:
            _check_out(folder, given=False)
        except UnwritableFolder as error:
            if args.force or not StudyFolder.of(root, study).archive.exists():
                raise (refused or error) from None
            read_only.add(study.name)
    return read_only


def _styles_of(dataset):
    """The registered style of each scheme of ``dataset`` that has one, read from the registry
    here: the analysis layer, which draws them, never loads the schemes (nor numba)."""
    from rbstudy.analysis.summary import schemes_of
    from rbstudy.schemes import scheme_styles

    return scheme_styles(schemes_of(dataset))


def _say(text):
    """Print ``text`` with each line within the summary table's width, the lines that
    continue one indented (`_wrapped`)."""
    print(_wrapped(text.splitlines()))


def _wrapped(lines):
    """``lines`` each within the summary table's width, the lines that continue one indented
    (`rbstudy.analysis.summary.wrap_clauses`), as one text."""
    from rbstudy.analysis.summary import wrap_clauses

    return "\n".join(short for line in lines for short in wrap_clauses(line, indent="  "))


def _each_file(paths, say):
    """Print ``say(path)`` (nothing when it is empty) for every path; a file that fails gets
    its one-line error and the others are still done; exit 1 if any failed."""
    failures = 0
    for path in paths:
        try:
            text = say(path)
            if text:
                _say(text)
        except RbstudyError as error:
            print(f"rbstudy: error: {error}", file=sys.stderr)
            failures += 1
    return EXIT_USER_ERROR if failures else EXIT_OK


def _validate(args):
    from rbstudy.pipeline.config import load_study

    _check_root(args.out)  # what the sweep would refuse before any study: --out no folder

    def checked(path):
        study = load_study(path, args.set)
        line = _costed(study, args, disk=True)  # the limits are checked even when quiet
        return "\n".join(_warning_lines(study)) if args.quiet else f"{path}: ok: {line}"

    return _each_file(args.files, checked)


def _sweep(args):
    if args.workers is not None and args.workers < 1:
        raise RbstudyError(f"--workers: need at least 1, got {args.workers}")
    if not args.worker_wait > 0:
        raise RbstudyError(f"--worker-wait: need a number of seconds above 0, got {args.worker_wait}")
    if args.step_tolerance is not None and not args.find_step:
        raise RbstudyError("--step-tolerance is the step search's: add --find-step, or drop it")
    cluster = None
    if args.cluster:
        from rbstudy.pipeline.cluster import read_cluster_file

        cluster = read_cluster_file(args.cluster)
    if args.scheduler:
        from rbstudy.pipeline.cluster import check_scheduler

        check_scheduler(args.scheduler)  # before the forecast: a typo waited for it
    if not args.scheduler and (args.workers or (cluster and cluster.kind == "local")):
        # the local workers' forkserver imports rbstudy while this process reads the studies
        from rbstudy.pipeline.cluster import start_forkserver

        start_forkserver()
    from rbstudy.analysis.findings import FINDINGS_REDUCED, FINDINGS_VARIABLES
    from rbstudy.archive.folder import StudyFolder
    from rbstudy.archive.reader import open_archive
    from rbstudy.numerics.machine import return_free_memory
    from rbstudy.pipeline.cluster import Where
    from rbstudy.pipeline.config import load_study
    from rbstudy.pipeline.execute import run_study, study_progress

    # all configs checked before any run, each with every --set
    studies = [load_study(path, args.set) for path in args.files]
    if args.format is not None:
        studies = [dataclasses.replace(study, output_format=args.format) for study in studies]
    if args.find_step and any(study.output_format == "zarr" for study in studies):
        raise RbstudyError(
            "--find-step keeps its search in a netCDF archive: drop it, or sweep with --format netcdf"
        )
    return_free_memory()  # the reading's transients: 258 MiB of a study of 1e6 cases
    names = [study.name for study in studies]
    for study in studies:
        if names.count(study.name) > 1:
            raise ConfigError(
                f"{study.name!r} is also the name of another config of this command",
                "study names pick the results folder: rename one",
                source=study.path,
                key="name",
            )
    read_only = _study_folders(studies, args)
    where = Where(
        scheduler=args.scheduler,
        workers=args.workers,
        cluster=cluster,
        writer=args.writer,
        worker_wait=args.worker_wait,
    )
    # a folder of another config of the same name is refused before any study runs
    replaces = [StudyFolder.of(args.out, study).check_claim(args.force) for study in studies]
    lines = [_costed(study, args, disk=False) for study in studies]  # before any run
    for study, line, replaced in zip(studies, lines, replaces, strict=True):
        if not args.quiet and study.name not in read_only:  # nothing to forecast there
            _say(line)
        if replaced:  # even when quiet: it says whose results the run deletes
            _say(replaced)
        with study_progress(study, args.quiet) as progress:
            done = run_study(
                study, args.out, where=where, force=args.force, keep_parts=args.keep_parts, progress=progress
            )
            progress.phase(f"{study.name}: reading its findings")
            return_free_memory()  # what the run's threads freed, before the reading's peak
            # proven by this run: sealed as written, or verified before it was reused
            dataset = open_archive(done.path, FINDINGS_VARIABLES, verify=False, reduced=FINDINGS_REDUCED)
            return_free_memory()  # what the run and the reading left, before the findings
            summary = _summary_text(dataset, wide=args.wide)
            searched, refused = [], None
            if args.find_step:
                try:
                    searched = _find_step(study, dataset, done.path, args, progress)
                except RbstudyError as error:  # a read-only folder: the findings still told
                    refused = error
        if done.archive_problems:
            _say(f"{study.name}: the archive was damaged ({done.archive_problems[0]}); rebuilt it")
        if done.damaged_parts:
            _say(
                f"{study.name}: {counted(done.damaged_parts, 'damaged part')} (their bytes no longer "
                "match their checksums) recomputed"
            )
        if done.removed_parts:
            _say(
                f"{study.name}: removed {counted(done.removed_parts, 'part file')} left beside its "
                "current archive, which holds "
                "them (--keep-parts keeps them)"
            )
        if done.up_to_date:
            _say(f"{study.name}: {done.path} is up to date (the same config and code); --force recomputes it")
        else:
            _say(
                f"{study.name}: {counted(done.computed, 'batch', 'batches')} run, {done.reused} reused, "
                f"{done.wall_seconds:.1f} s; wrote {done.path}"
            )
        if done.returned:
            _say(
                f"{study.name}: {counted(done.returned, 'part')} written here from the values the "
                "workers sent back (they do not see the results folder)"
            )
        print(summary)
        if refused is not None:
            raise refused
        if searched:
            print()
            _say("\n".join(searched))
    return 0


def _find_step(study, dataset, archive, args, progress):
    """The lines of the step search of ``study`` (`rbstudy.pipeline.step_search`), from its
    archive's ``dataset``, its probes kept in the ``archive``."""
    from rbstudy.pipeline.step_search import SEARCH_TOLERANCE, search_steps

    folder = pathlib.Path(archive).parent
    tolerance = SEARCH_TOLERANCE if args.step_tolerance is None else args.step_tolerance
    search = search_steps(study, dataset, folder, tolerance, args.force, progress)
    probes = f"{counted(search.probes.sizes['probe'], 'probe')} ({search.reused} reused)"
    return [*_searched(archive, dataset), f"{probes}; kept in {archive}, group search"]


def _searched(path, dataset, said_where=False):
    """The lines that tell the step search kept in the archive at ``path``, read as
    ``dataset`` (none where there is none), and where it is kept when ``said_where``."""
    from rbstudy.analysis.searched import read_search, search_lines

    search = read_search(path, dataset)
    if search is None or isinstance(search, str):
        return [] if search is None else [search]
    return search_lines(search, dataset) + [f"(the step search kept in {path}, group search)"] * said_where


def _with_search(document, path, dataset):
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


def _summary_text(dataset, wide=False, table_only=False):
    """The findings (unless ``table_only``), then the per-scheme table (every column when
    ``wide``)."""
    from rbstudy.analysis.findings import findings
    from rbstudy.analysis.summary import format_table, scheme_rows
    from rbstudy.analysis.summary_forms import finding_lines

    rows = scheme_rows(dataset)
    table = format_table(rows, wide=wide)
    return table if table_only else "\n".join(finding_lines(findings(dataset, rows)) + ["", table])


def _summary(args):
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
                    else _summary_text(dataset, wide=args.wide, table_only=args.quiet)
                )
                searched = [] if args.quiet else _searched(path, dataset, said_where=True)
                if not searched:
                    return text
                if args.format == "md":
                    return "\n\n".join([text, "\n".join(f"- {line}" for line in searched)])
                return "\n\n".join([text, _wrapped(searched)])

            text = "\n\n".join(
                render(path, dataset)
                if len(datasets) == 1 or args.format == "md"
                else f"== {path}\n{render(path, dataset)}"
                for path, dataset in zip(args.files, datasets, strict=True)
            )
    print(text)  # once the phases are erased
    return 0


def _plot(args):
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
        _check_out(folder, given=bool(args.out))
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
            dataset = _select(opened(path), args.select, path)
            styles = _styles_of(dataset)
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
                _say(f"  not drawn: {name}: {reason}")
    return 0


def _studies(paths, args, select=None):
    """The study of each archive of ``paths``, every one read before any is drawn (only its
    bookkeeping, one at a time; proven intact unless --no-verify; narrowed by ``select``, so
    that a bad choice fails first), and how to open each in full then (not verified again)."""
    from rbstudy.archive.reader import open_archive
    from rbstudy.archive.variables import BOOKKEEPING

    studies = [
        str(_select(open_archive(path, BOOKKEEPING, verify=not args.no_verify), select, path).attrs["study"])
        for path in paths
    ]
    return studies, functools.partial(open_archive, verify=False)


def _conformance(args):
    import time

    from rbstudy.pipeline.golden import GOLDEN
    from rbstudy.schemes import expand_groups, get_scheme

    started = time.perf_counter()
    _check_out(args.out)
    known = {case.name: case for case in GOLDEN}
    unknown = [name for name in args.cases or () if name not in known]
    if unknown:
        raise RbstudyError(
            f"--cases: no golden case {unknown[0]!r}"
            f"{did_you_mean(unknown[0], known)}; the cases: {', '.join(known)}"
        )
    if not 3 <= args.steps <= MAX_GOLDEN_STEPS:
        raise RbstudyError(
            f"--steps: give 3 to {MAX_GOLDEN_STEPS} time steps (an order needs "
            f"3; each more doubles the work), got {args.steps}"
        )
    for option, given in (("--cases", args.cases), ("--schemes", args.schemes)):
        twice = [name for name in given or () if given.count(name) > 1]
        if twice:
            raise RbstudyError(f"{option}: {twice[0]} is given twice; name it once")
    schemes = expand_groups(args.schemes or ["builtin", "engines"])
    for name in schemes:
        if get_scheme(name).adaptive:  # unknown and unavailable names fail here too
            raise RbstudyError(
                f"--schemes: {name} chooses its own steps: it has no order in dt to judge; leave it out"
            )
    cases = [known[name] for name in args.cases] if args.cases else list(GOLDEN)
    from rbstudy.analysis.conformance import (
        format_scorecard,
        score_case,
        scorecard_dataset,
        scorecard_html,
        status_lines,
        tally_statuses,
    )
    from rbstudy.archive.files import write_dataset_atomic, write_text_atomic
    from rbstudy.archive.provenance import source_text
    from rbstudy.archive.reader import open_archive
    from rbstudy.pipeline.golden import baseline, run_golden, write_golden
    from rbstudy.pipeline.progress import Progress

    out = pathlib.Path(args.out)
    paths = write_golden(out / "golden", schemes, cases, args.steps)
    cells, failed = {}, {}
    with Progress(
        "conformance",
        f"{counted(len(schemes), 'scheme')} x {counted(len(cases), 'golden case')}",
        quiet=args.quiet,
    ) as progress:
        archives = run_golden(paths, out, progress)
        progress.phase("conformance: scoring", len(cases), "cases")
        for case, archive in zip(cases, archives, strict=True):
            dataset = open_archive(archive)
            held = () if case.moment_free else [s for s in schemes if get_scheme(s).loads_held]
            cells[case.name] = score_case(dataset, case.rules, schemes, case.figure, held)
            tally_statuses(failed, dataset, schemes)
            progress.advance()
    names = [case.name for case in cases]
    seconds = time.perf_counter() - started
    fixed = "".join(f" ({case.name}: {case.steps})" for case in cases if case.steps)
    header = [
        f"{counted(len(schemes), 'scheme')} x {counted(len(cases), 'golden case')} x "
        f"{counted(args.steps, 'time step')}"
        f"{fixed}; "
        f"this run took {seconds:.0f} s of wall time (a rerun reuses the golden "
        "archives it finds)",
        f"studies and archives: {out}",
        "the failure rule's baseline (rbstudy's own schemes of these orders, swept too): "
        f"{', '.join(baseline(schemes))}",
    ]
    figures = {case.name: case.figure for case in cases if case.figure is not None}
    if figures:
        header.append(
            f"figure yes/no: the scheme reproduces what the source of "
            f"{', '.join(figures)} asserts (docs/results.md)"
        )
    header += status_lines(failed)
    print(format_scorecard(cells, names))
    _say("\n".join(header))
    attrs = {
        "title": "rbstudy conformance scorecard",
        "wall_seconds": seconds,
        "steps": args.steps,
        "source": source_text(_version()),
    }
    write_dataset_atomic(scorecard_dataset(cells, names, attrs), out / "conformance.nc")
    write_text_atomic(
        scorecard_html(cells, names, {case.name: case.title for case in cases}, header, figures),
        out / "conformance.html",
    )
    _say(f"scorecard: {out / 'conformance.nc'} and {out / 'conformance.html'}")
    return 0


def _select(dataset, choices, path):
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
            if v == value or (coordinate.dtype.kind == "f" and abs(v - value) <= _SELECT_RTOL * abs(value))
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


def _verify(args):
    from rbstudy.archive.reader import verify_file

    def proven(path):
        said = verify_file(path)
        return "" if args.quiet else f"{path}: {said}"

    return _each_file(args.files, proven)


def _report(args):
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
        _check_out(folder, given=bool(args.out))
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
                styles=_styles_of(dataset),
                drawn=[pathlib.Path(path).parent / "figures"],  # `rbstudy plot`'s, to copy
                searched=_searched(path, dataset),
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


class _Parser(argparse.ArgumentParser):
    """argparse's parser whose usage errors offer the verb or option a slip was meant for
    (``--wokers``: did you mean '--workers'?), and name the verb they belong to."""

    def error(self, message):
        super().error(message + _meant(self, message))

    def parse_args(self, args=None, namespace=None):
        """argparse's, except that an unknown argument after a verb is told with that verb's
        usage and options (argparse itself shows the top-level usage)."""
        parsed, unknown = self.parse_known_args(args, namespace)
        if unknown:
            verbs = {
                name: sub
                for action in self._actions
                if isinstance(action, argparse._SubParsersAction)
                for name, sub in action.choices.items()
            }
            verbs.get(getattr(parsed, "command", None), self).error(
                f"unrecognized arguments: {' '.join(unknown)}"
            )
        return parsed


def _meant(parser, message):
    """`did_you_mean` for the first unknown verb or option that argparse's ``message`` names."""
    choice = re.match(r"argument \S+: invalid choice: '([^']*)' \(choose from (.*)\)", message)
    if choice:
        return did_you_mean(choice[1], re.findall(r"'([^']*)'", choice[2]))
    if not message.startswith("unrecognized arguments: "):
        return ""
    parsers = [parser] + [
        sub
        for action in parser._actions  # the verbs' parsers too
        if isinstance(action, argparse._SubParsersAction)
        for sub in action.choices.values()
    ]
    options = {option for each in parsers for option in each._option_string_actions}
    for word in message.split(": ", 1)[1].split():
        option = word.partition("=")[0]  # --wokers=2
        if option.startswith("--") and did_you_mean(option, options):
            return did_you_mean(option, options)
    return ""


def build_parser():
    parser = _Parser(prog="rbstudy", description="Parameter studies of rigid-body rotation integrators.")
    parser.add_argument("--version", action="version", version=f"rbstudy {_version()}")
    commands = parser.add_subparsers(dest="command", required=True)
    sweep = commands.add_parser("sweep", help="run study configs and archive the results")
    sweep.add_argument("files", nargs="+", metavar="FILE", help="study YAML files")
    sweep.add_argument(
        "-o", "--out", metavar="DIR", default="results", help="results root (default: results/)"
    )
    where = sweep.add_mutually_exclusive_group()
    where.add_argument(
        "--scheduler", metavar="ADDRESS", help="run on a running dask.distributed scheduler (tcp://host:8786)"
    )
    where.add_argument(
        "--workers",
        type=_whole_number,
        metavar="N",
        help="start a local dask.distributed cluster of N worker processes",
    )
    where.add_argument(
        "--cluster",
        metavar="FILE",
        help="start the cluster a cluster file describes (local, SLURM or PBS; docs/cluster.md)",
    )
    # choices and default named here so that parsing loads no dask (rbstudy.pipeline.cluster)
    sweep.add_argument(
        "--writer",
        choices=("auto", "workers", "client"),
        default="auto",
        help="on a cluster, who writes the part files: the workers, this "
        "process (from values the workers send back), or auto (the "
        "workers where they see the results folder; the default)",
    )
    sweep.add_argument(
        "--worker-wait",
        type=float,
        default=600.0,
        metavar="SECONDS",
        help="end the run when a cluster has had no worker this long (default 600: batch jobs may queue)",
    )
    sweep.add_argument(
        "--force", action="store_true", help="recompute every batch, even those already stored"
    )
    sweep.add_argument(
        "--keep-parts",
        action="store_true",
        help="keep parts/ after the archive is written (a changed config then reuses the batches it shares)",
    )
    sweep.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress bar or forecast line (the findings and the table stay)",
    )
    sweep.add_argument(
        "--wide",
        action="store_true",
        help="print every column of the summary table (default: the columns that fit 100 characters)",
    )
    sweep.add_argument(
        "--format",
        choices=("netcdf", "zarr"),
        help="the archive's format, over the config's output.format: netcdf (<study>.nc, the "
        "default) or zarr (the store <study>.zarr, for cluster-scale studies)",
    )
    sweep.add_argument(
        "--find-step",
        action="store_true",
        help="then search, per scheme and value of the other axes, the largest step meeting the "
        "accuracy bound (kept in the archive, its group search)",
    )
    sweep.add_argument(
        "--step-tolerance",
        type=_step_tolerance,
        metavar="SHARE",
        help="--find-step ends where a step this share larger fails (default 0.05)",
    )
    _limit_arguments(sweep)
    _set_argument(sweep)
    sweep.set_defaults(run=_sweep)
    validate = commands.add_parser(
        "validate", help="check study configs and forecast their cost without running"
    )
    validate.add_argument("files", nargs="+", metavar="FILE", help="study YAML files")
    validate.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        default="results",
        help="results root the sweep would write (its free space is checked)",
    )
    validate.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no 'ok' line and forecast: only warnings and errors (the exit status tells)",
    )
    _limit_arguments(validate)
    _set_argument(validate)
    validate.set_defaults(run=_validate)
    schemes = commands.add_parser("schemes", help="list the registered schemes")
    schemes.add_argument(
        "-q", "--quiet", action="store_true", help="the names alone, one a line (for scripts)"
    )
    schemes.set_defaults(run=_schemes)
    plot = commands.add_parser("plot", help="draw the figures of results files")
    plot.add_argument("files", nargs="+", metavar="RESULTS.nc", help="results of rbstudy sweep")
    plot.add_argument("-o", "--out", metavar="DIR", help="figure folder (default: figures/ beside each file)")
    plot.add_argument(
        "--select",
        action="append",
        metavar="DIM=VALUE",
        help="only these cases, e.g. --select inertia_ratio=2 --select dt=0.01 (repeatable)",
    )
    # the formats of rbstudy.analysis.plots, named here so that parsing loads no matplotlib
    _list_argument(
        plot,
        "--format",
        choices=("png", "svg"),
        metavar="FORMAT",
        help="file formats: png, svg (default: png; an SVG takes as long again)",
    )
    plot.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no progress and no note of the figures not drawn: a line per file",
    )
    _no_verify_argument(plot)
    plot.set_defaults(run=_plot)
    report = commands.add_parser("report", help="write an HTML report of each results file")
    report.add_argument("files", nargs="+", metavar="RESULTS.nc", help="results of rbstudy sweep")
    report.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        help="report folder (default: report/ beside each file); with several "
        "files, a folder per study inside it",
    )
    report.add_argument(
        "--svg",
        action="store_true",
        help="also write each figure as SVG in the report's figures/ folder and "
        "link it (the report itself embeds the PNGs either way)",
    )
    report.add_argument("-q", "--quiet", action="store_true", help="no progress")
    _no_verify_argument(report)
    report.set_defaults(run=_report)
    summary = commands.add_parser(
        "summary", help="print the findings and the per-scheme table of results files (no rerun)"
    )
    summary.add_argument("files", nargs="+", metavar="RESULTS.nc", help="results of rbstudy sweep")
    summary.add_argument(
        "--format",
        choices=("text", "md", "csv", "json"),
        default="text",
        help="text (default), Markdown, CSV (the table) or JSON (everything, for scripts: docs/outputs.md)",
    )
    summary.add_argument(
        "--wide",
        action="store_true",
        help="every column of the table in the text form (default: those that fit 100 columns)",
    )
    summary.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="the table without the findings (text form; the others are unchanged), and no progress",
    )
    _no_verify_argument(summary)
    summary.set_defaults(run=_summary)
    verify = commands.add_parser("verify", help="prove results files intact by their checksums")
    verify.add_argument(
        "files", nargs="+", metavar="RESULTS.nc", help="archives (or part files) written by rbstudy sweep"
    )
    verify.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="no line for an intact file: only the damaged (the exit status tells)",
    )
    verify.set_defaults(run=_verify)
    bench = commands.add_parser("bench", help="print body-steps per second per scheme")
    bench.add_argument(
        "scheme_names",
        nargs="*",
        metavar="SCHEME",
        help="schemes to measure, as --schemes takes them (default: all)",
    )
    _list_argument(bench, "--schemes", metavar="SCHEME", help="schemes to measure")
    bench.add_argument(
        "--body-steps",
        type=_whole_number,
        metavar="N",
        help="body-steps per figure (default 1e7, at most 1e9; fewer for a quick look)",
    )
    bench.add_argument(
        "--option",
        action="append",
        metavar="NAME=VALUE",
        help="a scheme option for the schemes that offer it, such as compensated=1 "
        "(repeatable); their rows name it",
    )
    bench.add_argument("-q", "--quiet", action="store_true", help="no progress")
    bench.set_defaults(run=_bench)
    conformance = commands.add_parser(
        "conformance", help="judge schemes on the golden set: a pass/fail scorecard"
    )
    _list_argument(
        conformance,
        "--schemes",
        metavar="SCHEME",
        help="schemes to judge, or groups: builtin (rbstudy's fixed-step schemes), "
        "engines, or one engine (mujoco, drake, ...); default: builtin,engines",
    )
    _list_argument(conformance, "--cases", metavar="CASE", help="golden cases to run (default: all)")
    conformance.add_argument(
        "--steps",
        type=_whole_number,
        default=4,
        metavar="N",
        help="time steps per case, each half the one before (default 4; at least 3)",
    )
    conformance.add_argument(
        "-o",
        "--out",
        metavar="DIR",
        default="conformance",
        help="folder of the golden studies, their archives and the scorecard (default: conformance/)",
    )
    conformance.add_argument("-q", "--quiet", action="store_true", help="no progress")
    conformance.set_defaults(run=_conformance)
    return parser


def _step_tolerance(text):
    """A share between 0 and 1 (``0.05``: 5%)."""
    try:
        share = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share such as 0.05, got {text!r}") from None
    if not 0 < share < 1:
        raise argparse.ArgumentTypeError(f"expected a share between 0 and 1 such as 0.05, got {text!r}")
    return share


def _whole_number(text):
    """A whole number written as digits or as ``1e7``, as the help gives it."""
    try:
        number = float(text) if "e" in text.lower() or "." in text else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if not math.isfinite(number) or number != round(number):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
    return int(number)


def _list_argument(parser, option, metavar, help, choices=None):
    """``option`` taking one value or a comma list per use, the uses added up (``--format
    png,svg`` or ``--format png --format svg``): never a following positional, as nargs="+"
    took ``plot --format svg X.nc``'s file for a format."""

    def names(text):
        listed = [name.strip() for name in text.split(",")]
        for name in listed:
            if not name:
                raise argparse.ArgumentTypeError(f"an empty name in {text!r}")
            if choices and name not in choices:  # worded as argparse's own, for `_meant`
                raise argparse.ArgumentTypeError(
                    f"invalid choice: {name!r} (choose from {', '.join(map(repr, choices))})"
                )
        return listed

    parser.add_argument(
        option,
        action="extend",
        type=names,
        metavar=f"{metavar},...",
        help=f"{help}; a comma list, or the option again",
    )


def _no_verify_argument(parser):
    parser.add_argument(
        "--no-verify",
        action="store_true",
        help="read the archive without proving it intact by its checksums "
        "(rbstudy verify): for one known to be damaged",
    )


def _set_argument(parser):
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value before it is checked: KEY a dotted path "
        "(sweep.dt.count), VALUE as YAML would read it (3, -0.1, [1, 2], "
        "hht); repeatable; applies to every FILE (docs/config.md)",
    )


def _limit_arguments(parser):
    # defaults named here so that parsing loads nothing heavy (rbstudy.pipeline.estimate)
    parser.add_argument(
        "--max-body-steps",
        type=float,
        default=1e11,
        metavar="N",
        help="refuse a study forecast to take more body-steps (default 1e11: "
        "hours of kernels for the compiled schemes)",
    )
    parser.add_argument(
        "--max-memory",
        type=float,
        metavar="MIB",
        help="refuse a study forecast to need more memory, in MiB (default: half of this machine's)",
    )


def _version():
    from importlib import metadata

    try:
        return metadata.version("rbstudy")
    except metadata.PackageNotFoundError:
        return "(not installed)"


def _quiet_stdout():
    """Point stdout at /dev/null: its reader is gone, and Python's own flush at exit would
    otherwise report the broken pipe once more."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


class _FirstLine:
    """The line a verb shows at once on a terminal: before any verb can say a word, Python
    imports numpy, xarray, numba, dask or matplotlib, 2-8 s on a loaded machine. It is
    written without a newline and erased before the verb's first output on either stream
    (`_Stream`), as the progress bar erases itself; never shown when stderr is no terminal,
    in CI or with --quiet (as `rbstudy.pipeline.progress.live_wanted` decides, which would
    import rich first)."""

    def __init__(self, args, stream):
        self.stream = stream
        self.shown = False
        self._lock = threading.Lock()
        if not getattr(args, "quiet", False) and stream.isatty() and not os.environ.get("CI"):
            # one row of the terminal, so that erasing its row erases it all
            width = shutil.get_terminal_size().columns - 1
            stream.write(f"rbstudy {args.command}: starting (loading its libraries) ..."[:width])
            stream.flush()
            self.shown = True

    def erase(self):
        if self.shown:  # checked again under the lock: rich's drawing thread writes too
            with self._lock:
                if self.shown:
                    self.shown = False
                    self.stream.write("\r\x1b[K")  # to the row's start, then erase the row
                    self.stream.flush()


class _Stream:
    """A text stream whose writes first erase the `_FirstLine`, each made `printable`
    when ``printable``; all else is the stream's."""

    def __init__(self, stream, first_line, printable):
        self.stream, self.first_line, self.printable = stream, first_line, printable

    def write(self, text):
        self.first_line.erase()
        return self.stream.write(printable(text) if self.printable else text)

    def __getattr__(self, name):
        return getattr(self.stream, name)


@contextlib.contextmanager
def _streams(args):
    """stdout and stderr for the verb's run, after its `_FirstLine`. stdout shows the
    control characters of the text it prints (a scheme's name, an archive's attribute, a
    path) rather than letting a terminal obey them: no printing code has to remember it.
    stderr's lines are each made printable where they are written (the errors, the progress
    display), as rich draws its bar there with control sequences of its own."""
    plain = sys.stdout, sys.stderr
    first_line = _FirstLine(args, sys.stderr)
    sys.stdout = _Stream(plain[0], first_line, printable=True)
    sys.stderr = _Stream(plain[1], first_line, printable=False)
    try:
        yield
    finally:
        sys.stdout, sys.stderr = plain
        first_line.erase()  # a verb that printed nothing (verify -q of intact files)


def main(argv=None):
    args = build_parser().parse_args(argv)  # bad usage: argparse exits with EXIT_USAGE
    with _streams(args):
        return _run(args)


def _run(args):
    """The verb of ``args``, run; its exit code."""
    try:
        code = args.run(args)
        sys.stdout.flush()  # a closed pipe shows here, after the work is done
        return code
    except RbstudyError as error:
        print(f"rbstudy: error: {error}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:  # the reader left (| head -1): what was not yet done is not done
        _quiet_stdout()
        return EXIT_PIPE
    except KeyboardInterrupt:
        print(
            "\nrbstudy: interrupted; finished batches are kept: rerun the same command to resume",
            file=sys.stderr,
        )
        return 130
    except Exception:  # noqa: BLE001 (a bug: shown whole, once, with where to report it)
        sys.stderr.write(printable(traceback.format_exc()))
        print(
            "rbstudy: this is a bug in rbstudy, not in your input; please report it with "
            "the command, the config and the lines above",
            file=sys.stderr,
        )
        return EXIT_BUG


def _scratch_folder():
    """The folder for every temporary file made while the command runs, its child
    processes' too (the forkserver and workers of ``--workers``): multiprocessing's own
    (``pymp-*``), which holds the forkserver's socket, so that the socket's path (of about
    100 bytes at most) is no longer than before; dask's ``dask-scratch-space``, which dask
    keeps by design, goes into it. multiprocessing removes it at the interpreter's exit, which `command`
    skips: `command` removes it then."""
    from multiprocessing.util import get_temp_dir

    folder = get_temp_dir()
    tempfile.tempdir = folder
    os.environ["TMPDIR"] = folder  # the processes this one starts
    return folder


def command():
    """The ``rbstudy`` command: `main`, then the process ends at once with its exit code.

    Python's own shutdown would then spend 0.3-0.6 s tearing down the modules of numba,
    scipy, xarray and dask (measured: docs/performance.md). Nothing is lost by skipping it:
    every file rbstudy writes is closed and synced, and every thread pool and cluster shut
    down, before `main` returns; the output streams are flushed and the temporary files
    removed here (`_scratch_folder`). argparse's own exits (``--help``, bad usage) end the
    usual way.
    """
    scratch = _scratch_folder()
    code = main()
    if code:
        # what failed may have left objects to the cycle collector, among them the queues of
        # a local cluster's workers that did not start: collected, they release their named
        # semaphores, which Python's resource tracker would report as leaked (two lines)
        gc.collect()
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError):  # a reader gone: main has said so already
            stream.flush()
    shutil.rmtree(scratch, ignore_errors=True)
    os._exit(code)


if __name__ == "__main__":
    command()
