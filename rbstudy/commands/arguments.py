"""The options of every verb of the command line, declared: `build_parser` (`rbstudy.cli`)
adds each verb's parser in turn and sets the function that runs it. Choices and defaults
are named here, not read from the modules that use them, so that parsing loads nothing heavy
(no dask, matplotlib or numba).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

__all__ = [
    "add_bench",
    "add_conformance",
    "add_plot",
    "add_report",
    "add_schemes",
    "add_summary",
    "add_sweep",
    "add_validate",
    "add_verify",
]

# The object `add_subparsers` returns, to which each verb's parser is added.
Verbs = argparse._SubParsersAction


def add_sweep(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``sweep`` verb to ``commands``: its parser."""
    sweep = commands.add_parser("sweep", help="run study configs and archive the results")
    sweep.add_argument("files", nargs="+", metavar="FILE", help="study YAML files")
    sweep.add_argument(
        "-o", "--out", metavar="DIR", default="results", help="results root (default: results/)"
    )
    _cluster_arguments(sweep)
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
    return sweep


def _cluster_arguments(sweep: argparse.ArgumentParser) -> None:
    """Where a sweep runs (here, a scheduler, local workers or a cluster file), who writes
    its parts there, and how long it waits for a worker."""
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


def add_validate(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``validate`` verb to ``commands``: its parser."""
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
    return validate


def add_schemes(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``schemes`` verb to ``commands``: its parser."""
    schemes = commands.add_parser("schemes", help="list the registered schemes")
    schemes.add_argument(
        "-q", "--quiet", action="store_true", help="the names alone, one a line (for scripts)"
    )
    return schemes


def add_plot(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``plot`` verb to ``commands``: its parser."""
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
    return plot


def add_report(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``report`` verb to ``commands``: its parser."""
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
    return report


def add_summary(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``summary`` verb to ``commands``: its parser."""
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
    return summary


def add_verify(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``verify`` verb to ``commands``: its parser."""
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
    return verify


def add_bench(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``bench`` verb to ``commands``: its parser."""
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
        "--repeat",
        type=_whole_number,
        metavar="N",
        help="each figure the best of N rounds of the whole table (default 1; other programs only "
        "slow a run, so the best of many is nearest the code's own figure)",
    )
    bench.add_argument(
        "--option",
        action="append",
        metavar="NAME=VALUE",
        help="a scheme option for the schemes that offer it, such as compensated=1 "
        "(repeatable); their rows name it",
    )
    bench.add_argument("-q", "--quiet", action="store_true", help="no progress")
    return bench


def add_conformance(commands: Verbs) -> argparse.ArgumentParser:
    """Add the ``conformance`` verb to ``commands``: its parser."""
    conformance = commands.add_parser(
        "conformance", help="judge schemes on the golden set: a pass/fail scorecard"
    )
    _list_argument(
        conformance,
        "--schemes",
        metavar="SCHEME",
        help="schemes to judge, or groups: builtin (rbstudy's fixed-step schemes), published "
        "(rotation steps engines and papers publish), engines, or one engine (mujoco, drake, "
        "...); default: builtin,published,engines",
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
    return conformance


def _step_tolerance(text: str) -> float:
    """A share between 0 and 1 (``0.05``: 5%)."""
    try:
        share = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share such as 0.05, got {text!r}") from None
    if not 0 < share < 1:
        raise argparse.ArgumentTypeError(f"expected a share between 0 and 1 such as 0.05, got {text!r}")
    return share


def _whole_number(text: str) -> int:
    """A whole number written as digits or as ``1e7``, as the help gives it."""
    try:
        number = float(text) if "e" in text.lower() or "." in text else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if not math.isfinite(number) or number != round(number):
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}")
    return int(number)


def _list_argument(
    parser: argparse.ArgumentParser,
    option: str,
    metavar: str,
    help: str,
    choices: Sequence[str] | None = None,
) -> None:
    """``option`` taking one value or a comma list per use, the uses added up (``--format
    png,svg`` or ``--format png --format svg``): never a following positional, as nargs="+"
    took ``plot --format svg X.nc``'s file for a format."""

    def names(text: str) -> list[str]:
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


def _no_verify_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--no-verify",
        action="store_true",
        help="read the archive without proving it intact by its checksums "
        "(rbstudy verify): for one known to be damaged",
    )


def _set_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a config value before it is checked: KEY a dotted path "
        "(sweep.dt.count), VALUE as YAML would read it (3, -0.1, [1, 2], "
        "hht); repeatable; applies to every FILE (docs/config.md)",
    )


def _limit_arguments(parser: argparse.ArgumentParser) -> None:
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
