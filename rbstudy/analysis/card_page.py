"""What the conformance page says beyond the scorecard's cells: per golden case the cheapest
scheme and step meeting the accuracy bound (the study's own recommendation) and its
work-precision figure, and per scheme that is not rbstudy's own what goes wrong across the
cases, in words, each number read from the cells and the golden archives."""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import xarray as xr

from rbstudy.analysis.conformance import RULES, Cell, held_note
from rbstudy.analysis.findings import BUSY_CLAUSE, findings
from rbstudy.analysis.pages import data_uri, render
from rbstudy.analysis.work_precision_figure import work_precision
from rbstudy.archive.variables import BUSY_UNCERTAINTY

if TYPE_CHECKING:
    from rbstudy.pipeline.golden import Figure

__all__ = ["TROUBLE", "CaseView", "case_view", "scheme_troubles", "scorecard_html"]

# What each failed rule means in the page's words.
TROUBLE = {
    "order": "no nominal order",
    "invariants": "a claimed invariant lost",
    "energy": "energy gained",
    "flip": "the flip's interval missed",
    "failure": "blow-ups where rbstudy's own schemes finished",
}


@dataclasses.dataclass(frozen=True)
class CaseView:
    """A golden case on the page: its ``answer`` (the recommendation's words, without what
    ``busy`` says: its costs were measured on a busy machine, which the page says once) and
    its work-precision figure (``figure``: a PNG, None where none was drawn, ``why`` says why)."""

    answer: str
    figure: pathlib.Path | None
    why: str = ""
    busy: bool = False


def case_view(
    ds: xr.Dataset, folder: pathlib.Path, styles: Mapping[str, Sequence[str]] | None = None
) -> CaseView:
    """The `CaseView` of the golden study ``ds``, its figure drawn into ``folder`` in the
    schemes' registered ``styles`` (`rbstudy.schemes.scheme_styles`)."""
    answer = next(
        (f.text for f in findings(ds) if f.kind in ("recommendation", "no_recommendation")),
        "no recommendation: no case finished",
    )
    answer, busy, _ = answer.partition(BUSY_CLAUSE)
    drawn = work_precision(ds, folder, formats=("png",), styles=styles)
    png = next((path for path in drawn.written if path.suffix == ".png"), None)
    return CaseView(answer, png, "; ".join(drawn.absent.values()), bool(busy))


def scheme_troubles(
    cells: Mapping[str, Mapping[str, Cell]], cases: Sequence[str], schemes: Sequence[str]
) -> list[str]:
    """A sentence per scheme of ``schemes`` that failed a case: each failed rule with the
    cases it failed in (``jolt: energy gained in asymmetric, t_handle; no nominal order in
    high_spin``), in the order of `TROUBLE`; none for a scheme that passed every case."""
    lines = []
    for scheme in schemes:
        failed: dict[str, list[str]] = {}
        for case in cases:
            cell = cells[case].get(scheme)
            for rule, verdict in cell.verdicts.items() if cell is not None else ():
                if verdict.passed is False:
                    failed.setdefault(rule, []).append(case)
        if failed:
            parts = [
                f"{TROUBLE.get(rule, rule)} in {', '.join(failed[rule])}"
                for rule in sorted(failed, key=lambda r: list(TROUBLE).index(r) if r in TROUBLE else 99)
            ]
            passed = sum(1 for case in cases if (cell := cells[case].get(scheme)) and cell.passed)
            lines.append(f"{scheme} ({passed}/{len(cases)}): " + "; ".join(parts))
    return lines


def scorecard_html(
    cells: Mapping[str, Mapping[str, Cell]],
    cases: Sequence[str],
    titles: Mapping[str, str],
    header: Sequence[str],
    figures: Mapping[str, Figure] | None = None,
    views: Mapping[str, CaseView] | None = None,
    judged: Sequence[str] = (),
) -> str:
    """The scorecard as one self-contained HTML page (`rbstudy.analysis.pages`, the report's
    base page): first the findings in words (per case its answer, `CaseView.answer`; per
    scheme of ``judged`` that is not rbstudy's own what goes wrong, `scheme_troubles`), then
    a row per scheme with the cases it passed and a cell per case, green or red, every
    rule's measurement in it, each linking to its case's work-precision figure (embedded,
    ``views``), the table sortable by any column; ``titles`` (case -> title), ``header``
    (lines said above the table) and ``figures`` (case -> `rbstudy.pipeline.golden.Figure`,
    for the cases whose source asserts one)."""
    from rbstudy.schemes import scheme_groups

    schemes = list(dict.fromkeys(s for case in cases for s in cells[case]))
    passed = {
        s: sum(1 for c in cases if (cell := cells[c].get(s)) is not None and cell.passed) for s in schemes
    }
    rows = [(s, passed[s], [cells[c].get(s) for c in cases]) for s in schemes]
    own = set(scheme_groups()["builtin"])
    views = views or {}
    return render(
        "conformance.html.j2",
        title="rbstudy conformance scorecard",
        header=header,
        rules=RULES,
        cases=cases,
        titles=titles,
        rows=rows,
        total=len(cases),
        figures=figures or {},
        answers={case: views[case].answer for case in cases if case in views},
        busy=f"{BUSY_UNCERTAINTY:.0%}" if any(view.busy for view in views.values()) else None,
        troubles=scheme_troubles(cells, cases, [s for s in (judged or schemes) if s not in own]),
        plots={
            case: (data_uri(view.figure) if view.figure is not None else None, view.why)
            for case, view in views.items()
        },
        held_load_note=held_note(cells, cases),
    )
