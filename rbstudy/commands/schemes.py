"""The verbs about the schemes themselves rather than a study: ``schemes`` lists the
registered ones, ``bench`` measures their body-steps per second, ``conformance`` judges them
on the golden set and writes the pass/fail scorecard.
"""

from __future__ import annotations

import argparse
import functools
import pathlib
import textwrap
from typing import TYPE_CHECKING

from rbstudy.commands.common import check_out, say, version
from rbstudy.errors import RbstudyError, counted, did_you_mean

if TYPE_CHECKING:  # for the hints alone: running a verb imports what it needs then
    from rbstudy.analysis.card_page import CaseView
    from rbstudy.analysis.conformance import Cell
    from rbstudy.pipeline.golden import Figure, GoldenCase

__all__ = ["MAX_GOLDEN_STEPS", "bench", "conformance", "list_schemes"]

# `rbstudy conformance --steps`: 8 halvings take the golden set's work 32 times past the
# default 4, which is long even for the builtin schemes on a small machine.
MAX_GOLDEN_STEPS = 8


def list_schemes(args: argparse.Namespace) -> int:
    """``rbstudy schemes``: the registered schemes, each with its order, kind, invariants
    kept, options and summary, then those unavailable here and why, then the groups a config
    may name; the names alone with ``--quiet``."""
    from rbstudy.analysis.summary import TERMINAL_WIDTH
    from rbstudy.schemes import COMPOSITION_ORDERS, INVARIANTS, SCHEMES, scheme_groups, unavailable_schemes

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
    groups = scheme_groups()
    print("\ngroups (scheme: <group> in a config; all = builtin):")
    for group, members in groups.items():
        print(
            textwrap.fill(
                ", ".join(members),
                width=TERMINAL_WIDTH,
                initial_indent=f"  {group}: ",
                subsequent_indent=" " * (len(group) + 4),
            )
        )
    return 0


def bench(args: argparse.Namespace) -> int:
    """``rbstudy bench``: the body-steps per second of each chosen scheme."""
    from rbstudy.pipeline.bench import BODY_STEPS, MAX_BODY_STEPS, MAX_REPEAT, option_settings, run_bench
    from rbstudy.schemes import expand_groups

    if args.body_steps is not None and not 1 <= args.body_steps <= MAX_BODY_STEPS:
        raise RbstudyError(f"--body-steps: need 1 to {MAX_BODY_STEPS:.0e}, got {args.body_steps:.3g}")
    if args.repeat is not None and not 1 <= args.repeat <= MAX_REPEAT:
        raise RbstudyError(f"--repeat: need 1 to {MAX_REPEAT}, got {args.repeat}")
    # groups as conformance takes them: `bench builtin`, `bench --schemes mujoco,rk4`
    run_bench(
        schemes=expand_groups([*args.scheme_names, *(args.schemes or ())]) or None,
        body_steps=args.body_steps or BODY_STEPS,
        repeat=args.repeat or 1,
        progress=not args.quiet,
        options=option_settings(args.option or ()),
    )
    return 0


def conformance(args: argparse.Namespace) -> int:
    """``rbstudy conformance``: the chosen schemes run on the chosen golden cases, scored
    against each case's rules; the scorecard printed and written as netCDF and HTML."""
    import time

    from rbstudy.analysis.card_page import scorecard_html
    from rbstudy.analysis.conformance import format_scorecard, scorecard_dataset
    from rbstudy.archive.files import write_dataset_atomic, write_text_atomic
    from rbstudy.archive.provenance import source_text

    started = time.perf_counter()
    check_out(args.out)
    schemes, cases = _golden_choice(args)
    out = pathlib.Path(args.out)
    cells, failed, views = _scored(args, out, schemes, cases)
    names = [case.name for case in cases]
    seconds = time.perf_counter() - started
    figures = {case.name: case.figure for case in cases if case.figure is not None}
    header = _scorecard_header(args, out, schemes, cases, seconds, figures, failed)
    print(format_scorecard(cells, names))
    say("\n".join(header))
    attrs = {
        "title": "rbstudy conformance scorecard",
        "wall_seconds": seconds,
        "steps": args.steps,
        "source": source_text(version()),
    }
    write_dataset_atomic(scorecard_dataset(cells, names, attrs), out / "conformance.nc")
    write_text_atomic(
        scorecard_html(
            cells, names, {case.name: case.title for case in cases}, header, figures, views, schemes
        ),
        out / "conformance.html",
    )
    say(f"scorecard: {out / 'conformance.nc'} and {out / 'conformance.html'}")
    return 0


def _golden_choice(args: argparse.Namespace) -> tuple[list[str], list[GoldenCase]]:
    """The schemes (groups expanded) and the golden cases ``args`` choose, each name
    checked: an unknown case, a bad ``--steps``, a name given twice or a scheme that
    chooses its own steps refused in one line."""
    from rbstudy.pipeline.golden import GOLDEN
    from rbstudy.schemes import expand_groups, get_scheme

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
    schemes = expand_groups(args.schemes or ["builtin", "published", "engines"])
    for name in schemes:
        if get_scheme(name).adaptive:  # unknown and unavailable names fail here too
            raise RbstudyError(
                f"--schemes: {name} chooses its own steps: it has no order in dt to judge; leave it out"
            )
    return schemes, [known[name] for name in args.cases] if args.cases else list(GOLDEN)


def _scored(
    args: argparse.Namespace, out: pathlib.Path, schemes: list[str], cases: list[GoldenCase]
) -> tuple[dict[str, dict[str, Cell]], dict[int, dict[str, int]], dict[str, CaseView]]:
    """The golden studies of ``cases`` written under ``out`` and run (a rerun reuses the
    archives it finds), then each scored: the scorecard's cells per case, the failed cases
    per status and scheme (`rbstudy.analysis.conformance.tally_statuses`), and each case's
    answer and work-precision figure (`rbstudy.analysis.card_page.case_view`, into
    ``out/figures``)."""
    from rbstudy.analysis.card_page import case_view
    from rbstudy.analysis.conformance import score_case, tally_statuses
    from rbstudy.archive.reader import open_archive
    from rbstudy.pipeline.golden import run_golden, write_golden
    from rbstudy.pipeline.progress import Progress
    from rbstudy.schemes import get_scheme, scheme_styles

    paths = write_golden(out / "golden", schemes, cases, args.steps)
    cells: dict[str, dict[str, Cell]] = {}
    failed: dict[int, dict[str, int]] = {}
    views: dict[str, CaseView] = {}
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
            drawn = dataset["scheme"].values.tolist()
            views[case.name] = case_view(dataset, out / "figures", scheme_styles(drawn))
            progress.advance()
    return cells, failed, views


def _scorecard_header(
    args: argparse.Namespace,
    out: pathlib.Path,
    schemes: list[str],
    cases: list[GoldenCase],
    seconds: float,
    figures: dict[str, Figure],
    failed: dict[int, dict[str, int]],
) -> list[str]:
    """The lines under the scorecard: what was run and how long it took, where the archives
    are, the failure rule's baseline, what the figure column asserts and the failed cases."""
    from rbstudy.analysis.conformance import status_lines
    from rbstudy.pipeline.golden import baseline

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
    if figures:
        header.append(
            f"figure yes/no: the scheme reproduces what the source of "
            f"{', '.join(figures)} asserts (docs/results.md)"
        )
    return header + status_lines(failed)
