"""Command line: ``rbstudy sweep | validate | schemes | plot | report | summary | bench |
verify | conformance``.

``sweep`` runs each study config and writes ``OUT/<study>/<study>.nc``, then prints the
study's findings and per-scheme summary; ``summary`` prints them again from archives;
``validate`` checks configs without running anything. The verbs themselves are the modules
of `rbstudy.commands` (their options: `rbstudy.commands.arguments`); this module parses the
command, runs its verb and ends the process.

Exit codes, as the command-line tools users know have them: 0 success; 1 a user's mistake
(`RbstudyError`), told in one line naming the file, the key and the fix; 2 bad usage (from
argparse); 70 a bug in rbstudy (`EX_SOFTWARE`), the only case with a traceback, and a line
asking for a report; 141 (as for a broken pipe) without a word when the reader of the output
has gone (``| head -1``): the command stops there.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import os
import re
import shutil
import sys
import tempfile
import threading
import traceback
from collections.abc import Iterator, Sequence
from typing import Any, NoReturn, TextIO

from rbstudy.commands import arguments, results, schemes, study
from rbstudy.commands.common import EXIT_BUG, EXIT_OK, EXIT_PIPE, EXIT_USAGE, EXIT_USER_ERROR, version
from rbstudy.errors import RbstudyError, did_you_mean, printable

__all__ = [
    "main",
    "command",
    "build_parser",
    "EXIT_OK",
    "EXIT_USER_ERROR",
    "EXIT_USAGE",
    "EXIT_BUG",
    "EXIT_PIPE",
]


def build_parser() -> argparse.ArgumentParser:
    """The parser of the ``rbstudy`` command: each verb's options (`rbstudy.commands.arguments`)
    and, as ``run``, the function of `rbstudy.commands` that runs it (read when the parser is
    built)."""
    parser = _Parser(prog="rbstudy", description="Parameter studies of rigid-body rotation integrators.")
    parser.add_argument("--version", action="version", version=f"rbstudy {version()}")
    commands = parser.add_subparsers(dest="command", required=True)
    verbs = (
        (arguments.add_sweep, study.sweep),
        (arguments.add_validate, study.validate),
        (arguments.add_schemes, schemes.list_schemes),
        (arguments.add_plot, results.plot),
        (arguments.add_report, results.report),
        (arguments.add_summary, results.summary),
        (arguments.add_verify, results.verify),
        (arguments.add_bench, schemes.bench),
        (arguments.add_conformance, schemes.conformance),
    )
    for add, run in verbs:
        add(commands).set_defaults(run=run)
    return parser


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


def _meant(parser: argparse.ArgumentParser, message: str) -> str:
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


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv`` (default: the process's arguments), run its verb and return its exit
    code; bad usage exits through argparse with `EXIT_USAGE`."""
    args = build_parser().parse_args(argv)  # bad usage: argparse exits with EXIT_USAGE
    with _streams(args):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
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


def _quiet_stdout() -> None:
    """Point stdout at /dev/null: its reader is gone, and Python's own flush at exit would
    otherwise report the broken pipe once more."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


class _FirstLine:
    """The line a verb shows at once on a terminal: before any verb can say a word, Python
    imports numpy, xarray, numba, dask or matplotlib, seconds on a loaded machine. It is
    written without a newline and erased before the verb's first output on either stream
    (`_Stream`), as the progress bar erases itself; never shown when stderr is no terminal,
    in CI or with --quiet (as `rbstudy.pipeline.progress.live_wanted` decides, which would
    import rich first)."""

    def __init__(self, args: argparse.Namespace, stream: TextIO) -> None:
        self.stream = stream
        self.shown = False
        self._lock = threading.Lock()
        if not getattr(args, "quiet", False) and stream.isatty() and not os.environ.get("CI"):
            # one row of the terminal, so that erasing its row erases it all
            width = shutil.get_terminal_size().columns - 1
            stream.write(f"rbstudy {args.command}: starting (loading its libraries) ..."[:width])
            stream.flush()
            self.shown = True

    def erase(self) -> None:
        if self.shown:  # checked again under the lock: rich's drawing thread writes too
            with self._lock:
                if self.shown:
                    self.shown = False
                    self.stream.write("\r\x1b[K")  # to the row's start, then erase the row
                    self.stream.flush()


class _Stream:
    """A text stream whose writes first erase the `_FirstLine`, each made `printable`
    when ``printable``; all else is the stream's."""

    def __init__(self, stream: TextIO, first_line: _FirstLine, printable: bool) -> None:
        self.stream, self.first_line, self.printable = stream, first_line, printable

    def write(self, text: str) -> int:
        self.first_line.erase()
        return self.stream.write(printable(text) if self.printable else text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.stream, name)


@contextlib.contextmanager
def _streams(args: argparse.Namespace) -> Iterator[None]:
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


def _scratch_folder() -> str:
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


def command() -> NoReturn:
    """The ``rbstudy`` command: `main`, then the process ends at once with its exit code.

    Python's own shutdown would then spend a noticeable time tearing down the modules of numba,
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
