"""The forms of `rbstudy summary` beyond its terminal table: the findings as lines of a
terminal (`finding_lines`), the JSON document for scripts (`summary_document`,
docs/outputs.md), Markdown (`markdown_summary`) and the CSV rows of the table (`csv_rows`),
each read from the study's dataset through the findings and the per-scheme rows.
"""

from __future__ import annotations

import dataclasses
import math
import textwrap
from collections.abc import Sequence
from typing import Any

import xarray as xr

from rbstudy.analysis.findings import MAX_LINE, Finding, findings
from rbstudy.analysis.places import cases_of, plain
from rbstudy.analysis.recommend import recommendations
from rbstudy.analysis.summary import NONE, format_table, scheme_rows

__all__ = [
    "MAX_FINDING_LINES",
    "table_records",
    "summary_document",
    "finding_lines",
    "markdown_summary",
    "csv_rows",
]

# The findings a terminal shows before the table (text and md); the JSON form has them all.
MAX_FINDING_LINES = 12


# The table's fields for scripts: (JSON/CSV name, row key). Units are in the names.
_RECORD_FIELDS = (
    ("scheme", "scheme"),
    ("nominal_order", "nominal"),
    ("cases", "cases"),
    ("failed_cases", "unstable"),
    ("inaccurate_cases", "inaccurate"),
    ("unjudged_cases", "unjudged"),
    ("past_radioss_limit_cases", "radioss"),
    ("order_low", None),
    ("order_high", None),
    ("fits", "fits"),
    ("fit_tries", "tries"),
    ("error_rad", "error"),
    ("error_dt_s", "error_dt"),
    ("error_small_dt_rad", "error_small"),
    ("small_dt_s", "error_small_dt"),
    ("ns_per_body_step", "ns_per_step"),
    ("accurate_up_to_dt_w0", "accurate_hw"),
    ("first_inaccurate_dt_w0", "inaccurate_hw"),
    ("first_failed_dt_w0", "unstable_hw"),
    ("kept", "kept"),
)


def _json_value(value: Any) -> Any:
    """``value`` with every non-finite number as None (JSON has no NaN), tuples as lists and
    numpy scalars as Python's."""
    if isinstance(value, dict):
        return {str(k): _json_value(v) for k, v in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, str | bytes):  # tuples, a finding's cases
        return [_json_value(v) for v in value]
    value = plain(value)
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def table_records(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The per-scheme rows (`scheme_rows`) as flat records of named fields, units in the
    names; a value the row lacks or that is not finite (a failed case) is None."""
    records = []
    for row in rows:
        record: dict[str, Any] = {}
        for name, key in _RECORD_FIELDS:
            if key is None:  # the fitted order's range
                order = row["order"]
                value = None if order is None else order[0 if name == "order_low" else 1]
            else:
                value = row.get(key)
            record[name] = _json_value(value)
        records.append(record)
    return records


def summary_document(ds: xr.Dataset) -> dict[str, Any]:
    """The JSON form of `rbstudy summary` (docs/outputs.md): study, findings, recommended
    (one record per value of the other swept axes; scheme and dt None where no case there
    meets the bound) and schemes (`table_records`)."""
    recommended = []
    for (labels, _), pick in zip(cases_of(ds), recommendations(ds), strict=True):
        fields = (
            dict.fromkeys(("scheme", "dt", "error", "seconds_per_case"))
            if pick is None
            else {
                "scheme": pick.scheme,
                "dt": pick.dt,
                "error": pick.error,
                "seconds_per_case": pick.seconds_per_case,
            }
        )
        recommended.append({**fields, **labels})
    rows = scheme_rows(ds)
    return _json_value(
        {
            "study": str(ds.attrs["study"]),
            "findings": [
                {field.name: getattr(finding, field.name) for field in dataclasses.fields(finding)}
                for finding in findings(ds, rows)
            ],
            "recommended": recommended,
            "schemes": table_records(rows),
        }
    )


def finding_lines(found: Sequence[Finding]) -> list[str]:
    """The texts of ``found``, each wrapped at `MAX_LINE` (later lines indented), at most
    `MAX_FINDING_LINES` lines: the last says how many more the JSON form holds."""
    lines = [
        textwrap.wrap(finding.text, MAX_LINE, subsequent_indent="  ", break_on_hyphens=False)
        for finding in found
    ]
    if sum(map(len, lines)) <= MAX_FINDING_LINES:
        return [line for wrapped in lines for line in wrapped]
    shown: list[str] = []
    for count, wrapped in enumerate(lines):
        if len(shown) + len(wrapped) > MAX_FINDING_LINES - 1:
            more = len(lines) - count
            return shown + [f"({more} more findings: --format json lists them all)"]
        shown += wrapped
    return shown


def _cell(value: list[Any]) -> str:
    """A list of a record (the invariants kept) as one CSV cell: "none" when empty, as the
    table says it (a missing number is an empty cell)."""
    return ", ".join(map(str, value)) or NONE


def markdown_summary(ds: xr.Dataset) -> str:
    """The findings as a list, then the table (every column) as Markdown, rendered from the
    table's one definition (`rbstudy.analysis.summary.format_table`)."""
    rows = scheme_rows(ds)
    return "\n".join(
        [f"## {ds.attrs['study']}", ""]
        + [f"- {finding.text}" for finding in findings(ds, rows)]
        + ["", format_table(rows, wide=True, fmt="markdown")]
    )


def csv_rows(ds: xr.Dataset) -> list[dict[str, Any]]:
    """The table's records with the study's name first, as rows for `csv.DictWriter`."""
    return [
        {
            "study": str(ds.attrs["study"]),
            **{name: _cell(value) if isinstance(value, list) else value for name, value in record.items()},
        }
        for record in table_records(scheme_rows(ds))
    ]
