"""`rbstudy conformance` on a shrunk golden set: the rules judge real runs, the scorecard is
printed, archived and drawn as a page."""

import numpy as np
import pytest
import xarray as xr

from rbstudy.analysis.conformance import RULES
from rbstudy.cli import main
from rbstudy.pipeline.golden import GOLDEN


@pytest.fixture(scope="module")
def scorecard(tmp_path_factory):
    """euler, midpoint and rk4 on the Abaqus top and the flipping T-handle, three steps."""
    out = tmp_path_factory.mktemp("conformance")
    code = main(["conformance", "--cases", "abaqus_top", "t_handle", "--schemes", "euler",
                 "midpoint", "rk4", "--steps", "3", "--out", str(out), "--quiet"])
    assert code == 0
    with xr.open_dataset(out / "conformance.nc") as ds:
        return out, ds.load()


def _rule(ds, scheme, case, rule):
    return int(ds["rule_passed"].sel(scheme=scheme, case=case, rule=rule))


def test_sound_schemes_pass_every_rule_with_their_orders(scorecard):
    _, ds = scorecard
    for scheme, order in (("midpoint", 2), ("rk4", 4)):
        assert (ds["passed"].sel(scheme=scheme) == 1).all()
        assert float(ds["value"].sel(scheme=scheme, case="abaqus_top")) == pytest.approx(
            order, abs=0.1)
    # midpoint claims the energy and L: checked; rk4 claims nothing
    assert _rule(ds, "midpoint", "abaqus_top", "invariants") == 1
    assert _rule(ds, "rk4", "abaqus_top", "invariants") == -1
    assert _rule(ds, "rk4", "t_handle", "flip") == 1


def test_explicit_euler_fails_where_it_gains_energy_and_shows_no_order(scorecard):
    """On the T-handle explicit Euler gains a quarter of its energy and blows up at the
    coarsest step: it fails the energy and the order rules. Its failure alone does not fail
    the failure rule: no other scheme of order 1 is judged here."""
    _, ds = scorecard
    assert int(ds["passed"].sel(scheme="euler", case="t_handle")) == 0
    assert _rule(ds, "euler", "t_handle", "energy") == 0
    assert float(ds["rule_value"].sel(scheme="euler", case="t_handle", rule="energy")) > 0.1
    assert _rule(ds, "euler", "t_handle", "order") == 0
    assert _rule(ds, "euler", "t_handle", "failure") == 1
    text = str(ds["rule_text"].sel(scheme="euler", case="t_handle", rule="failure").values)
    assert "no scheme of order 1 here finished" in text
    # the flip rule is judged where the case finished: within a step at the finer two
    assert _rule(ds, "euler", "t_handle", "flip") == 1


def test_the_scorecard_is_printed_archived_and_drawn(scorecard, capsys):
    out, ds = scorecard
    assert list(ds["rule"].values) == list(RULES)
    assert (out / "golden" / "conformance_t_handle.yaml").exists()  # rerunnable studies
    page = (out / "conformance.html").read_text()
    assert page.count("class='pass'") == int((ds["passed"] == 1).sum())
    assert page.count("class='fail'") == int((ds["passed"] == 0).sum())
    assert ds.attrs["wall_seconds"] > 0


def test_a_rerun_reuses_the_golden_archives(scorecard, capsys):
    out, ds = scorecard
    archive = out / "conformance_t_handle" / "conformance_t_handle.nc"
    written = archive.stat().st_mtime_ns
    assert main(["conformance", "--cases", "abaqus_top", "t_handle", "--schemes", "euler",
                 "midpoint", "rk4", "--steps", "3", "--out", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "euler" in printed and "FAIL" in printed
    with xr.open_dataset(out / "conformance.nc") as again:
        np.testing.assert_array_equal(again["passed"].values, ds["passed"].values)
    assert archive.stat().st_mtime_ns == written  # up to date: not computed again


def test_bad_options_are_one_line_errors(tmp_path, capsys):
    for argv, said in ((["--cases", "nope"], "no golden case 'nope'"),
                       (["--steps", "2"], "at least 3 time steps"),
                       (["--schemes", "dop853"], "chooses its own steps"),
                       (["--schemes", "nope"], "unknown scheme 'nope'")):
        assert main(["conformance", "--out", str(tmp_path), *argv]) == 1
        error = capsys.readouterr().err
        assert said in error and error.count("\n") == 1


def test_every_golden_case_names_known_rules():
    assert {rule for case in GOLDEN for rule in case.rules} <= set(RULES)
    assert len({case.name for case in GOLDEN}) == len(GOLDEN) == 8
