"""A failed case's status says what happened and what to try, from the one table
(`rbstudy.numerics.state.STATUSES`): in the archive's description, the findings the command
line prints, the report and the scorecard."""

import html

import pytest
import yaml
from helpers import parsed

from rbstudy.analysis.conformance import status_lines, tally_statuses
from rbstudy.analysis.findings import findings
from rbstudy.archive.reader import open_archive
from rbstudy.cli import main
from rbstudy.numerics.state import NOT_CONVERGED, STATUSES, UNSTABLE
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

# A fast spin about the middle axis at steps up to dt |w0| = 4: euler blows up at every step,
# the implicit midpoint and hht find no Newton solution at the largest.
FAILING = {
    "name": "failing",
    "scene": {
        "body": {"mass": 1.0, "inertia": [1.0, 2.0, 3.0]},
        "initial": {"angular_velocity": {"body": [1.0, 10.0, 1.0]}},
        "duration": 2.0,
    },
    "output": {"interval": 0.4},
    "run": {"scheme": "euler", "dt": 0.4},
    "sweep": {"scheme": ["euler", "hht", "midpoint"], "dt": [0.1, 0.2, 0.4]},
}


@pytest.fixture(scope="module")
def failing(tmp_path_factory):
    folder = tmp_path_factory.mktemp("failing")
    (folder / "failing.yaml").write_text(yaml.safe_dump(FAILING))
    return run_study(load_study(folder / "failing.yaml"), folder / "out", quiet=True).path


def _counted(ds, code):
    """scheme -> cases of status ``code``, counted here with numpy alone."""
    status = ds["status"].transpose("scheme", ...).values.reshape(ds.sizes["scheme"], -1)
    counts = (status == code).sum(axis=1)
    return {str(scheme): int(n) for scheme, n in zip(ds["scheme"].values, counts, strict=True) if n}


def test_each_status_of_failed_cases_is_a_finding_with_its_message_and_fix(failing):
    ds = open_archive(failing)
    unstable, unconverged = _counted(ds, UNSTABLE), _counted(ds, NOT_CONVERGED)
    assert unstable and unconverged  # the study shows both
    found = [finding for finding in findings(ds) if finding.kind == "failure"]
    assert [finding.numbers for finding in found] == [
        {"status": "unstable", "cases": sum(unstable.values())},
        {"status": "not_converged", "cases": sum(unconverged.values())},
    ]
    for finding, code, counted in zip(found, (UNSTABLE, NOT_CONVERGED), (unstable, unconverged), strict=True):
        name, message, fix = STATUSES[code]
        listed = ", ".join(f"{scheme} {count}" for scheme, count in counted.items())
        assert finding.text == (f"{name}: {sum(counted.values())} cases ({listed}): {message}; {fix}")
    # the archive describes the codes in the table's words
    description = ds["status"].attrs["description"]
    assert all(f"{name}: {message}" in description for name, message, _ in STATUSES[1:])


@pytest.mark.slow
def test_the_command_line_and_the_report_print_them(failing, tmp_path, capsys):
    assert main(["summary", str(failing)]) == 0
    printed = capsys.readouterr().out
    assert all(len(line) <= 100 for line in printed.splitlines())
    said = " ".join(line.strip() for line in printed.splitlines())
    for _, message, fix in STATUSES[1:]:
        assert message in said and fix in said
    assert main(["report", str(failing), "-o", str(tmp_path / "report"), "-q"]) == 0
    page = (tmp_path / "report" / "report.html").read_text()
    for _, message, fix in STATUSES[1:]:
        assert html.escape(message, quote=False) in page and html.escape(fix) in page


def test_the_scorecard_sums_them_over_its_cases(failing):
    ds = open_archive(failing)
    tally = tally_statuses(tally_statuses({}, ds, ["euler", "hht"]), ds, ["euler"])
    euler = _counted(ds, UNSTABLE)["euler"]
    assert tally[UNSTABLE] == {"euler": 2 * euler}
    assert set(tally[NOT_CONVERGED]) == {"hht"}  # midpoint is not judged
    lines = status_lines(tally)
    assert lines[0].startswith(f"unstable: {2 * euler} cases (euler {2 * euler}): ")
    assert lines[1].endswith(STATUSES[NOT_CONVERGED].fix)


# The codes that have one table each: a status (`rbstudy.numerics.state.STATUSES`) and an
# accuracy verdict (`rbstudy.archive.variables.VERDICTS`), under the names code reads them by.
CODED = {"status", "accuracy", "verdict"}


def _coded_literals(source):
    """Where ``source`` compares a status or a verdict with a number written out: (line, text)."""
    import ast

    def coded(node):
        names = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)}
        keys = {n.value for n in ast.walk(node) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
        return bool((names | keys) & CODED)

    found = []
    for node in ast.walk(parsed(source)):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            numbers = [s for s in sides if isinstance(s, ast.Constant) and type(s.value) is int]
            if numbers and any(coded(s) for s in sides if s not in numbers):
                found.append((node.lineno, ast.unparse(node)))
    return found


def test_statuses_and_verdicts_are_read_by_name_above_the_kernels():
    """Above the compiled kernels, no module compares a status or a verdict with a number
    written out (``ds["status"] == 0``): each code comes from its one table (`OK`, `ACCURATE`)."""
    import pathlib

    package = pathlib.Path(__file__).resolve().parents[1] / "rbstudy"
    found = {
        str(path.relative_to(package)): hits
        for layer in ("physics", "inputs", "archive", "pipeline", "analysis", "commands")
        for path in sorted((package / layer).rglob("*.py"))
        if (hits := _coded_literals(path.read_text()))
    }
    found.update({"cli.py": hits} if (hits := _coded_literals((package / "cli.py").read_text())) else {})
    assert not found, found
    # the check itself can fail
    planted = 'bad = ds["status"] != 0\nworse = verdict == 3\nfine = len(x) == 1\n'
    assert [line for line, _ in _coded_literals(planted)] == [1, 2]
