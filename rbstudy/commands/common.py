"""What every verb of the command line shares: its exit codes, printing within the summary
table's width, a verb run per file, the refusal of an output folder that cannot be written,
the schemes' styles and rbstudy's version.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable
from typing import Any

from rbstudy.errors import RbstudyError

__all__ = [
    "Dataset",
    "EXIT_OK",
    "EXIT_USER_ERROR",
    "EXIT_USAGE",
    "EXIT_BUG",
    "EXIT_PIPE",
    "check_out",
    "each_file",
    "say",
    "styles_of",
    "version",
    "wrapped",
]

EXIT_OK, EXIT_USER_ERROR, EXIT_USAGE = 0, 1, 2
EXIT_BUG = 70  # EX_SOFTWARE of sysexits.h: an internal error
EXIT_PIPE = 141  # 128 + SIGPIPE, as other tools end when their reader has gone
# A study's dataset, an xarray.Dataset: named so in the hints, as the command line imports
# no outside package (its verbs load xarray when they run).
Dataset = Any


def check_out(folder: str | os.PathLike[str], given: bool = True) -> None:
    """Refuse an output folder rbstudy could not write (a file, a path under one, /proc, a
    read-only or immutable folder) in one line, before a command prints or computes anything;
    ``given``: the folder is the user's --out (else a command's default folder)."""
    from rbstudy.archive.files import check_output_folder

    check_output_folder(folder, "--out " if given else "")


def styles_of(dataset: Dataset) -> dict[str, Any]:
    """The registered style of each scheme of ``dataset`` that has one, read from the registry
    here: the analysis layer, which draws them, never loads the schemes (nor numba)."""
    from rbstudy.analysis.summary import schemes_of
    from rbstudy.schemes import scheme_styles

    return scheme_styles(schemes_of(dataset))


def say(text: str) -> None:
    """Print ``text`` with each line within the summary table's width, the lines that
    continue one indented (`wrapped`)."""
    print(wrapped(text.splitlines()))


def wrapped(lines: Iterable[str]) -> str:
    """``lines`` each within the summary table's width, the lines that continue one indented
    (`rbstudy.analysis.summary.wrap_clauses`), as one text."""
    from rbstudy.analysis.summary import wrap_clauses

    return "\n".join(short for line in lines for short in wrap_clauses(line, indent="  "))


def each_file(paths: Iterable[str], text_of: Callable[[str], str]) -> int:
    """Print ``text_of(path)`` (nothing when it is empty) for every path; a file that fails gets
    its one-line error and the others are still done; exit 1 if any failed."""
    failures = 0
    for path in paths:
        try:
            text = text_of(path)
            if text:
                say(text)
        except RbstudyError as error:
            print(f"rbstudy: error: {error}", file=sys.stderr)
            failures += 1
    return EXIT_USER_ERROR if failures else EXIT_OK


def version() -> str:
    """rbstudy's version as installed, or ``(not installed)``."""
    from importlib import metadata

    try:
        return metadata.version("rbstudy")
    except metadata.PackageNotFoundError:
        return "(not installed)"
