"""The per-scheme table a sweep prints, from one definition: within 100 columns for every
shipped study (its footnotes too), every column with --wide, and the same values as text,
Markdown, CSV and HTML; the conformance scorecard within 100 columns, saying what its numbers
are."""

import contextlib
import csv
import html.parser
import io
import re

import numpy as np
import pytest
import yaml
from helpers import CONFIGS, copy_node_tables

from rbstudy.analysis.conformance import HELD_LOAD_NOTE, Cell, Verdict, format_scorecard
from rbstudy.analysis.summary import (
    SUMMARY_VARIABLES,
    TERMINAL_WIDTH,
    format_table,
    scheme_rows,
    table_columns,
    wrap_clauses,
)
from rbstudy.archive.reader import open_archive
from rbstudy.cli import main
from rbstudy.pipeline.golden import GOLDEN

CONFIG_FILES = sorted(CONFIGS.glob("*.yaml"))
# The most footnote lines under a table (issue 29).
MAX_NOTE_LINES = 6
# The columns every study's wide table has, and of them those the default narrow one shows
# (a study adds "error_small" where dt is swept, "radioss" where the limit was passed).
WIDE_COLUMNS = {
    "scheme",
    "nominal",
    "order",
    "finest",
    "fit_dt",
    "error",
    "ns_per_step",
    "accurate_hw",
    "inaccurate_hw",
    "unstable_hw",
    "inaccurate",
    "failed",
    "kept",
}
NARROW_COLUMNS = {"scheme", "nominal", "order", "error", "ns_per_step", "accurate_hw", "failed", "kept"}


def _sweep(folder, *options):
    """``rbstudy sweep`` of every shipped config in ``folder``: (stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with (
        pytest.MonkeyPatch.context() as patch,
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
    ):
        patch.chdir(folder)
        assert main(["sweep", *(path.name for path in CONFIG_FILES), *options]) == 0
    return out.getvalue(), err.getvalue()


@pytest.fixture(scope="module")
def shipped(tmp_path_factory):
    """Every shipped config, each case one output interval long (the same schemes and swept
    axes, so the same rows and columns), swept from a folder of its own into the default
    results/: the folder, the archives and what the first sweep printed."""
    folder = tmp_path_factory.mktemp("shipped")
    copy_node_tables(folder)
    for path in CONFIG_FILES:
        config = yaml.safe_load(path.read_text())
        config["scene"]["duration"] = config["output"]["interval"]
        (folder / path.name).write_text(yaml.safe_dump(config, sort_keys=False))
    printed = _sweep(folder)
    return (
        folder,
        {path.stem: folder / "results" / path.stem / f"{path.stem}.nc" for path in CONFIG_FILES},
        printed,
    )


@pytest.mark.slow
def test_every_shipped_study_prints_lines_within_100_columns(shipped):
    """Its forecast, its run or up-to-date line and its table. Measured on the full
    configs: 98 characters at most, 100 on a rerun (the up-to-date lines), the widest table
    96 (high_order, long_run_convergence); before, tables of up to 243 and a footnote of
    1,136."""
    folder, archives, first = shipped
    for out, err in (first, _sweep(folder)):
        # stderr off a terminal: each study's start and end line (a rerun's: none)
        widest = max([*out.splitlines(), *err.splitlines()], key=len)
        assert len(widest) <= TERMINAL_WIDTH, widest
    assert out.count("is up to date") == len(CONFIG_FILES)
    assert "finest pair" not in out and "fit over" not in out  # two of the wide columns
    wide, _ = _sweep(folder, "--wide")
    for name, path in archives.items():
        rows = scheme_rows(open_archive(path, SUMMARY_VARIABLES, verify=False))
        keys = {column.key for column in table_columns(rows)}
        assert WIDE_COLUMNS <= keys, name
        assert {c.key for c in table_columns(rows) if c.narrow} == NARROW_COLUMNS, name
        text = format_table(rows, wide=True)
        assert text in wide, name
        header = "\n".join(text.splitlines()[:3])
        for column in table_columns(rows):  # every column, each line of its header shown
            assert all(part in header for part in column.header.split("\n")), column.key


@pytest.mark.slow
def test_footnotes_are_at_most_six_lines_under_the_table(shipped):
    _, archives, _ = shipped
    for name, path in archives.items():
        rows = scheme_rows(open_archive(path, SUMMARY_VARIABLES, verify=False))
        for wide in (False, True):
            lines = format_table(rows, wide=wide).splitlines()
            table = len(rows) + max(c.header.count("\n") + 1 for c in table_columns(rows))
            notes = lines[table:]
            assert 0 < len(notes) <= MAX_NOTE_LINES, (name, notes)
            assert all(re.match(r'^[\w(/"-][^:]*: ', note) for note in notes), notes  # key: text


class _Cells(html.parser.HTMLParser):
    """The text of every cell of an HTML table, row by row."""

    def __init__(self):
        super().__init__()
        self.rows, self._cell = [], None

    def handle_starttag(self, tag, attrs):
        if tag == "tr":
            self.rows.append([])
        elif tag in ("td", "th"):
            self._cell = ""

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data

    def handle_endtag(self, tag):
        if tag in ("td", "th"):
            self.rows[-1].append(self._cell.strip())
            self._cell = None


def _markdown_cells(text):
    table = [line for line in text.splitlines() if line.startswith("|")]
    return [
        [cell.strip().replace("\\|", "|") for cell in re.split(r"(?<!\\)\|", line)[1:-1]]
        for k, line in enumerate(table)
        if k != 1
    ]  # not the rule under the header


@pytest.mark.slow
@pytest.mark.parametrize("wide", [False, True])
def test_markdown_csv_and_html_hold_the_values_of_the_text(shipped, wide):
    """radioss_spin_limit: the one table with the Radioss column, and "|" in its cells."""
    _, archives, _ = shipped
    rows = scheme_rows(open_archive(archives["radioss_spin_limit"], SUMMARY_VARIABLES, verify=False))
    values = list(csv.reader(io.StringIO(format_table(rows, wide=wide, fmt="csv"))))
    assert len(values) == len(rows) + 1 and any("|L|" in line[-1] for line in values)
    assert _markdown_cells(format_table(rows, wide=wide, fmt="markdown")) == values
    page = _Cells()
    page.feed(format_table(rows, wide=wide, fmt="html"))
    assert page.rows == values
    text = format_table(rows, wide=wide).splitlines()
    for line in values[1:]:  # each row's cells, in order, on the scheme's line of the text
        printed = next(printed for printed in text if printed.startswith(line[0] + " "))
        assert re.fullmatch(r"\s+".join(map(re.escape, line)), printed), printed
    header = [c.header.replace("\n", " ") for c in table_columns(rows) if wide or c.narrow]
    assert values[0] == header and ("past Radioss limit" in header) == wide


def test_the_scorecard_fits_100_columns_and_says_what_its_numbers_are():
    """Thirteen schemes on the golden cases, each failing cell as long as it gets, with the
    source's figure not reproduced and the adapter's held load marked (before: 211 columns,
    "pass 1.09"); the mark's footnote last."""
    cases = [case.name for case in GOLDEN]
    schemes = ["euler", "exact_split", "mujoco_implicitfast", *(f"scheme{k}" for k in range(10))]
    worst = Cell(
        False,
        np.nan,
        {rule: Verdict(False, np.nan, "") for rule in ("order", "energy", "failure")},
        Verdict(False, np.nan, ""),
        load_held=True,
    )
    order = Cell(True, 1.0937, {"order": Verdict(True, 1.0937, "")})
    exact = Cell(True, np.nan, {"order": Verdict(True, np.nan, "")})
    cells = {
        case: {scheme: {"euler": worst, "exact_split": exact}.get(scheme, order) for scheme in schemes}
        for case in cases
    }
    text = format_scorecard(cells, cases)
    lines = text.splitlines()
    assert max(map(len, lines)) <= TERMINAL_WIDTH
    assert all(case in text for case in cases)
    blocks, footnote = text.split("\n\n")[:-1], text.split("\n\n")[-1]
    assert footnote.startswith(HELD_LOAD_NOTE[:40])
    for block in blocks:  # each block: the header, then every scheme with its count
        assert [line.split()[:2] for line in block.splitlines()] == [
            ["scheme", "passed"],
            ["euler", f"0/{len(cases)}"],
            ["exact_split", f"{len(cases)}/{len(cases)}"],
            *([scheme, f"{len(cases)}/{len(cases)}"] for scheme in schemes[2:]),
        ]
    assert [case for block in blocks for case in block.splitlines()[0].split()[2:]] == cases
    euler = [line for line in lines if line.startswith("euler")]
    assert all(line.count("FAIL order, energy, failure, figure no *") >= 1 for line in euler)
    assert "order 1.09" in text and "pass 1.09" not in text and "exact" in text


def test_a_long_line_breaks_after_its_clauses_and_never_inside_a_path():
    path = "results/" + "a" * 120 + ".nc"
    line = f"{'x' * 60}; {'y' * 30}; z z; wrote {path}"
    assert wrap_clauses(line, indent="  ") == [f"{'x' * 60}; {'y' * 30}; z z;", "  wrote", f"  {path}"]
    assert wrap_clauses(f"{'x' * 60}; {'y' * 40}") == [f"{'x' * 60};", f"{'y' * 40}"]


def _row(scheme, **changes):
    """A row of `scheme_rows` of a scheme with an order, an error, an accurate range and
    kept invariants; ``changes`` take some away."""
    row = {
        "scheme": scheme,
        "nominal": 2,
        "cases": 4,
        "unstable": 0,
        "inaccurate": 0,
        "unjudged": 0,
        "radioss": 0,
        "order": (2.0, 2.0),
        "finest": (2.0, 2.0),
        "fits": 2,
        "tries": 2,
        "floored": {},
        "fit_dt": (0.001, 0.01),
        "error_dt": 0.01,
        "error": 1e-4,
        "error_small_dt": 0.001,
        "error_small": 1e-6,
        "ns_per_step": 100.0,
        "accurate_hw": 0.1,
        "inaccurate_hw": 0.2,
        "unstable_hw": 0.4,
        "physical": 4,
        "judged_physical": 4,
        "kept": ("energy",),
        "invariants_measured": True,
    }
    return {**row, **changes}


def test_each_missing_value_says_what_it_means_and_only_the_marks_used_are_noted():
    """A table with a scheme without a reference, one with no accurate step and one keeping
    nothing: each of those cells says which (no "-", which meant all three), and the
    footnotes explain exactly the words used, in text, Markdown, HTML and CSV alike."""
    rows = [
        _row("unreferenced", error=None, judged_physical=0, accurate_hw=float("nan")),
        _row("inaccurate", accurate_hw=float("nan")),
        _row("drifting", kept=()),
    ]
    expected = {
        ("unreferenced", "error"): "no ref",
        ("unreferenced", "accurate_hw"): "no ref",
        ("inaccurate", "accurate_hw"): "none",
        ("drifting", "kept"): "none",
    }
    notes = {'error "no ref"', 'dt|w0| "no ref"', 'dt|w0| "none"', 'kept "none"'}
    unused = ['"failed"', '"n/a"', '"round-off"', '"ref floor"', 'order "none"', 'error "none"']
    for wide in (False, True):
        columns = [c.key for c in table_columns(rows) if wide or c.narrow]
        values = list(csv.reader(io.StringIO(format_table(rows, wide=wide, fmt="csv"))))[1:]
        cells = {(row[0], key): cell for row in values for key, cell in zip(columns, row, strict=True)}
        assert all(cells[where] == word for where, word in expected.items()), cells
        assert "-" not in cells.values()
        for fmt in ("text", "markdown", "html"):
            text = format_table(rows, wide=wide, fmt=fmt).replace("&quot;", '"')
            assert all(note + ":" in text for note in notes), (fmt, text)
            assert not any(note in text for note in unused), (fmt, text)
        text = format_table(rows, wide=wide)
        assert max(map(len, text.splitlines())) <= TERMINAL_WIDTH or wide
