"""The per-scheme table of a study, defined once and rendered in every form.

`table_columns` gives a `Column` per value of the rows (`rbstudy.analysis.summary.scheme_rows`):
its header and units, its cell text, whether the default table shows it, its footnotes and
the words a cell may hold instead of a number (`Column.marks`). `format_table` renders them
by tabulate as text, Markdown, CSV or HTML; the default text keeps to `TERMINAL_WIDTH`
columns for every shipped study, its footnotes to six lines. The findings tell a row's
order and floor in the table's words (`order_text`, `FLOOR_WORDS`).
"""

from __future__ import annotations

import csv
import html
import io
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from tabulate import tabulate

from rbstudy.analysis.measures import KEPT_TOLERANCE, UNCERTAINTY_FACTOR
from rbstudy.numerics.state import OK, STATUSES

__all__ = [
    "Row",
    "FLOOR_WORDS",
    "NONE",
    "TABLE_FORMATS",
    "TERMINAL_WIDTH",
    "Column",
    "floor_reason",
    "format_table",
    "order_text",
    "span",
    "table_columns",
    "table_notes",
    "wrap_clauses",
]

# A row of `rbstudy.analysis.summary.scheme_rows`: its fields by name.
Row = dict[str, Any]


# The words a cell shows where it has no number, each explained under the table where used
# (`Column.marks`): a "-" said "no reference", "no accurate step" and "none kept" alike.
NOT_APPLICABLE = "n/a"
NONE = "none"
NO_REFERENCE = "no ref"
FAILED = "failed"
ROUND_OFF = "round-off"
REFERENCE_FLOOR = "ref floor"
# What the findings say for a row whose every value was at the floor (`at_floor`'s reason).
FLOOR_WORDS = {
    "round-off": "at the floor (round-off)",
    "reference": f"at the floor ({UNCERTAINTY_FACTOR:g}x the reference's uncertainty)",
}


def floor_reason(row: Row) -> str | None:
    """``"round-off"`` or ``"reference"`` (`at_floor`) when no value of the other axes had a
    fit and every one of them was at the floor (round-off where any was), else None."""
    floored = row.get("floored", {})
    if row["order"] is not None or not row["tries"] or sum(floored.values()) < row["tries"]:
        return None
    return "round-off" if floored.get("round-off") else "reference"


def order_text(row: Row) -> str:
    """``2.00`` or ``1.98-2.01`` (the range over the other swept axes), with ``(3/4)`` when
    some values of the other axes had no asymptotic range; without any, why: `ROUND_OFF` or
    `REFERENCE_FLOOR` (every value at the floor, `floor_reason`), `NONE` (no asymptotic
    range, ``(0/4)``) or `NOT_APPLICABLE` (dt not swept)."""
    if row["order"] is not None:
        text = span(row["order"])
    elif not row["tries"]:
        return NOT_APPLICABLE
    else:
        reason = floor_reason(row)
        if reason is not None:
            return ROUND_OFF if reason == "round-off" else REFERENCE_FLOOR
        text = NONE
    whole = row["fits"] == row["tries"] or row["tries"] == 1  # (0/1) says nothing more
    return text if whole else f"{text} ({row['fits']}/{row['tries']})"


def _error(value: float | None) -> str:
    if value is None:
        return NO_REFERENCE
    return FAILED if not np.isfinite(value) else f"{value:.1e}"


def _number(value: float | None, spec: str, missing: str = NONE) -> str:
    return missing if value is None or not np.isfinite(value) else f"{value:{spec}}"


def _step_load(row: Row, key: str) -> str:
    """The ``dt |w0|`` cell ``key`` of ``row``, or why it has none: `NOT_APPLICABLE` (no
    physical body), `NO_REFERENCE` (none of them judged), `NONE` (no such case)."""
    if not row["physical"]:
        return _number(row[key], ".3g", NOT_APPLICABLE)
    if key != "unstable_hw" and not row["judged_physical"]:
        return _number(row[key], ".3g", NO_REFERENCE)
    return _number(row[key], ".3g")


def _kept_text(row: Row) -> str:
    if row["kept"]:
        return ", ".join(row["kept"])
    return NONE if row["invariants_measured"] else NOT_APPLICABLE


def span(values: Sequence[float]) -> str:
    """``2.00``, or ``1.98-2.01`` when the ``values`` (orders, slopes) differ at two decimals."""
    low, high = min(values), max(values)
    return f"{low:.2f}" if high - low < 0.005 else f"{low:.2f}-{high:.2f}"


# The terminal's width the default table and its footnotes keep to (characters).
TERMINAL_WIDTH = 100
TABLE_FORMATS = ("text", "markdown", "csv", "html")


@dataclass(frozen=True)
class Column:
    """A column of the per-scheme table: its ``key``, its ``header`` (the name, then its
    units; the terminal shows each line of it on a line of its own, the other formats one
    line), the ``cell`` text of a row, whether the default ``narrow`` table shows it, its
    footnotes ``notes`` (none when the header says it all), and ``marks``: (word, footnote)
    pairs, each word a cell may hold instead of a number with what it means there, noted
    only under a table whose cells of the column use it."""

    key: str
    header: str
    cell: Callable[[Row], str]
    narrow: bool
    notes: tuple[str, ...] = ()
    left: bool = False
    marks: tuple[tuple[str, str], ...] = ()


def table_columns(rows: Sequence[Row]) -> list[Column]:
    """Every `Column` of the per-scheme table, shared by the terminal, the report, Markdown
    and CSV; a column with nothing to show in these ``rows`` is left out."""
    return [
        *_order_columns(),
        *_error_columns(rows),
        *_stability_columns(),
        *_case_columns(rows),
        Column(
            "kept",
            "kept",
            _kept_text,
            True,
            (f"kept: drift < {KEPT_TOLERANCE:g} in every stable case (L at the samples)",),
            left=True,
            marks=(
                (NONE, f'kept "{NONE}": no invariant kept'),
                (NOT_APPLICABLE, f'kept "{NOT_APPLICABLE}": none measured (a moment acts)'),
            ),
        ),
    ]


def _order_columns() -> list[Column]:
    """The scheme, its nominal order and what the fits over ``dt`` observed."""
    return [
        Column("scheme", "scheme", lambda row: row["scheme"], True, left=True),
        Column(
            "nominal",
            "nominal\norder",
            lambda row: NOT_APPLICABLE if row["nominal"] is None else str(row["nominal"]),
            True,
            marks=((NOT_APPLICABLE, f'nominal "{NOT_APPLICABLE}": not in the archive'),),
        ),
        Column(
            "order",
            "observed\norder",
            order_text,
            True,
            ("observed order: per value of the other axes, (k/n): k of n fitted",),
            marks=(
                (ROUND_OFF, f'"{ROUND_OFF}": errors at round-off'),
                (REFERENCE_FLOOR, f'"{REFERENCE_FLOOR}": under {UNCERTAINTY_FACTOR:g}x its uncertainty'),
                (NONE, f'order "{NONE}": no asymptotic range'),
                (NOT_APPLICABLE, f'order "{NOT_APPLICABLE}": dt not swept'),
            ),
        ),
        Column(
            "finest",
            "finest\npair",
            lambda row: NONE if row["finest"] is None else span(row["finest"]),
            False,
            ("finest pair: slope of the two finest fitted steps",),
        ),
        Column(
            "fit_dt",
            "fit over\ndt (s)",
            lambda row: NONE if not row["fit_dt"] else f"{row['fit_dt'][0]:.3g}..{row['fit_dt'][1]:.3g}",
            False,
            marks=((NONE, f'finest pair, fit over "{NONE}": no order fitted'),),
        ),
    ]


def _error_columns(rows: Sequence[Row]) -> list[Column]:
    """The worst error at the largest ``dt`` of the rows, and at their smallest where it
    differs."""
    large = next((row["error_dt"] for row in rows if "error_dt" in row), None)
    small = next((row["error_small_dt"] for row in rows if "error_small_dt" in row), None)

    def error_at(dt):
        return "error\n(rad)" if dt is None else f"error at\ndt={dt:g} s\n(rad)"

    errors = (
        (FAILED, f'"{FAILED}": a case blew up'),
        (NO_REFERENCE, f'error "{NO_REFERENCE}": a case had no reference'),
    )
    columns = [
        Column(
            "error",
            error_at(large),
            lambda row: _error(row["error"]),
            True,
            ("error: final orientation error, worst case",),
            marks=errors,
        ),
    ]
    if small is not None and small != large:
        columns.append(
            Column(
                "error_small",
                error_at(small),
                lambda row: _error(row.get("error_small")),
                False,
                marks=errors,
            )
        )
    return columns


def _stability_columns() -> list[Column]:
    """The cost of a step, and how far in ``dt |w0|`` the scheme stays accurate and stable."""
    load_marks = (
        (NONE, f'dt|w0| "{NONE}": no such case'),
        (NOT_APPLICABLE, f'dt|w0| "{NOT_APPLICABLE}": no physical body'),
        (NO_REFERENCE, f'dt|w0| "{NO_REFERENCE}": none had a reference'),
    )
    return [
        Column(
            "ns_per_step",
            "ns per\nstep",
            lambda row: _number(row["ns_per_step"], ".0f", NOT_APPLICABLE),
            True,
            ("ns: kernel time a step, as the findings cost it",),
            marks=((NOT_APPLICABLE, f'ns "{NOT_APPLICABLE}": no step timed'),),
        ),
        Column(
            "accurate_hw",
            "accurate\nto dt|w0|\n(rad)",
            lambda row: _step_load(row, "accurate_hw"),
            True,
            (
                "accurate to: largest accurate dt|w0| below any inaccurate or failed",
                "dt|w0|: physical bodies only",
            ),
            marks=load_marks,
        ),
        Column(
            "inaccurate_hw",
            "first\ninaccurate\ndt|w0| (rad)",
            lambda row: _step_load(row, "inaccurate_hw"),
            False,
            marks=load_marks,
        ),
        Column(
            "unstable_hw",
            "first\nfailed\ndt|w0| (rad)",
            lambda row: _step_load(row, "unstable_hw"),
            False,
            marks=load_marks,
        ),
    ]


def _case_columns(rows: Sequence[Row]) -> list[Column]:
    """How many cases were inaccurate, failed or past the Radioss limit (the last only where
    any row passed it)."""
    columns = [
        Column(
            "inaccurate",
            "inaccurate\ncases",
            lambda row: (
                NOT_APPLICABLE
                if row["inaccurate"] is None
                else f"{row['inaccurate']}/{row['cases']}"
                + (f" ({row['unjudged']} unjudged)" if row["unjudged"] else "")
            ),
            False,
            ("inaccurate: past the accuracy bound (unjudged: no reference)",),
            marks=((NOT_APPLICABLE, f'inaccurate "{NOT_APPLICABLE}": the archive has no verdict'),),
        ),
        Column(
            "failed",
            "failed\ncases",
            lambda row: f"{row['unstable']}/{row['cases']}",
            True,
            # what each means and what to try: the findings (`status_text`)
            (f"failed: {' or '.join(status.name for status in STATUSES[OK + 1 :])}",),
        ),
    ]
    if any(row["radioss"] for row in rows):  # only where the limit was passed
        columns.append(
            Column(
                "radioss",
                "past\nRadioss\nlimit",
                lambda row: f"{row['radioss']}/{row['cases']}",
                False,
                ("past Radioss limit: dt|w| > 1, where OpenRadioss aborts",),
            )
        )
    return columns


def table_notes(columns: Sequence[Column], rows: Sequence[Row], width: int = TERMINAL_WIDTH) -> list[str]:
    """The footnotes of ``columns`` over ``rows``, as lines of at most ``width`` characters:
    each column's notes, then what each of its `Column.marks` means, of those its cells of
    ``rows`` hold (a mark's note said once, where columns share it)."""
    notes: list[str] = []
    for column in columns:
        notes += column.notes
        used = {column.cell(row) for row in rows}
        notes += [note for mark, note in column.marks if any(cell.startswith(mark) for cell in used)]
    return wrap_clauses("; ".join(dict.fromkeys(notes)), width)


def wrap_clauses(line: str, width: int = TERMINAL_WIDTH, indent: str = "") -> list[str]:
    """``line`` as lines of at most ``width`` characters: broken after a "; " where it can,
    else between words (a word longer than ``width``, a path, stays whole); the lines after
    the first start with ``indent``."""
    clauses = line.split("; ")
    lines: list[str] = []
    for clause in [f"{clause};" for clause in clauses[:-1]] + clauses[-1:]:
        if lines and len(lines[-1]) + len(" ") + len(clause) <= width:
            lines[-1] += " " + clause
        else:
            lines.append((indent if lines else "") + clause)
    return [
        short
        for long in lines
        for short in textwrap.wrap(
            long, width, subsequent_indent=indent, break_long_words=False, break_on_hyphens=False
        )
    ]


def format_table(rows: Sequence[Row], wide: bool = False, fmt: str = "text") -> str:
    """The per-scheme table of ``rows`` (`scheme_rows`) as ``fmt`` (one of `TABLE_FORMATS`):
    the columns that answer how accurate, how stable and at what cost (each line within
    `TERMINAL_WIDTH` for the shipped studies), or every column when ``wide``; under it its
    footnotes (not in CSV, which holds the values alone)."""
    columns = [c for c in table_columns(rows) if wide or c.narrow]
    cells = [[column.cell(row) for column in columns] for row in rows]
    align = ["left" if column.left else "right" for column in columns]
    if fmt == "text":  # the headers as rows: tabulate pads a header row by two more spaces
        lines = [
            line.rstrip()
            for line in tabulate(
                [[c.header for c in columns], *cells], tablefmt="plain", colalign=align, disable_numparse=True
            ).splitlines()
        ]
        # the footnotes of a wide table as wide as it
        return "\n".join(lines + table_notes(columns, rows, max(TERMINAL_WIDTH, *map(len, lines))))
    headers = [_one_line(c.header) for c in columns]
    if fmt == "csv":
        text = io.StringIO()
        csv.writer(text, lineterminator="\n").writerows([headers, *cells])
        return text.getvalue()
    notes = table_notes(columns, rows)
    if fmt == "markdown":  # a | inside a cell (|L|, dt|w0|) would end it
        table = tabulate(
            [[_pipes(text) for text in line] for line in cells],
            [_pipes(text) for text in headers],
            tablefmt="github",
            colalign=align,
            disable_numparse=True,
        )
        return "\n\n".join([table, "\n".join(notes)])
    if fmt == "html":
        table = tabulate(cells, headers, tablefmt="html", colalign=align, disable_numparse=True)
        return f"{table}\n<p>" + "<br>\n".join(html.escape(note) for note in notes) + "</p>"
    raise ValueError(f"format_table: no format {fmt!r}; one of {', '.join(TABLE_FORMATS)}")


def _one_line(header: str) -> str:
    return header.replace("\n", " ")


def _pipes(text: str) -> str:
    return text.replace("|", "\\|")
