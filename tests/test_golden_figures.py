"""The peers' public cases in the golden set: OpenRadioss's QA ROTA and Drake's free-body
benchmark, each with the figure its source asserts, which the card checks every scheme
against (`judge_figure`)."""

import numpy as np
import pytest
import xarray as xr

from rbstudy.analysis.conformance import judge_figure
from rbstudy.analysis.summary import TERMINAL_WIDTH
from rbstudy.cli import main
from rbstudy.pipeline.golden import GOLDEN
from rbstudy.pipeline.store import open_results

CASES = {case.name: case for case in GOLDEN}


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    """rk4, midpoint and euler on the two peers' cases and the Abaqus top, three steps."""
    out = tmp_path_factory.mktemp("figures")
    assert main(["conformance", "--cases", "radioss_rota,drake_free_body,abaqus_top",
                 "--schemes", "rk4,midpoint,euler", "--steps", "3", "--out", str(out),
                 "--quiet"]) == 0
    with xr.open_dataset(out / "conformance.nc") as ds:
        return out, ds.load()


def _golden(out, case):
    return open_results(out / f"conformance_{case}" / f"conformance_{case}.nc")


def test_the_cases_state_their_sources_assertions():
    rota, drake = CASES["radioss_rota"].figure, CASES["drake_free_body"].figure
    assert rota.url.endswith("qa-tests/miniqa/KIN_CONSTRAINTS/RBODY/ROTA")
    cycles, energy = rota.checks
    assert (cycles.measure, cycles.expected) == ("cycles", 10001)
    assert (energy.measure, energy.expected, energy.at) == ("rotational_energy", 2.0, 10.0)
    assert "drake" in drake.url and drake.url.endswith("multibody_plant_free_body_test.cc")
    # tol(t) = (1 + 4 * 256 t / 10 s) 1e-3, the test's own; w within twice it
    assert drake.checks[0].tolerance + drake.checks[0].growth * 10.0 == pytest.approx(1.025)
    assert drake.checks[1].tolerance + drake.checks[1].growth * 10.0 == pytest.approx(2.05)
    assert CASES["abaqus_top"].figure is None


@pytest.mark.slow
def test_second_and_fourth_order_schemes_pass_and_reproduce_the_figures(card):
    _, ds = card
    for scheme in ("rk4", "midpoint"):
        for case in ("radioss_rota", "drake_free_body"):
            assert int(ds["passed"].sel(scheme=scheme, case=case)) == 1, (scheme, case)
            assert int(ds["figure"].sel(scheme=scheme, case=case)) == 1, (scheme, case)
    # explicit Euler blows up on the cylinder at Drake's step: it does not reproduce it
    assert int(ds["figure"].sel(scheme="euler", case="drake_free_body")) == 0
    assert "failed at dt = 0.03125 s" in str(
        ds["figure_text"].sel(scheme="euler", case="drake_free_body").values)
    # a case of rbstudy's own asserts no figure
    assert (ds["figure"].sel(case="abaqus_top") == -1).all()
    assert "cycles 10001 (asserted 10001)" in str(
        ds["figure_text"].sel(scheme="rk4", case="radioss_rota").values)


@pytest.mark.slow
def test_the_card_says_figure_yes_or_no_within_the_terminal(card, capsys):
    out, _ = card
    assert main(["conformance", "--cases", "radioss_rota,drake_free_body,abaqus_top",
                 "--schemes", "rk4,midpoint,euler", "--steps", "3", "-o", str(out), "-q"]) == 0
    printed = capsys.readouterr().out
    assert "figure yes" in printed and "figure no" in printed
    assert "x 3 time steps (radioss_rota: 1);" in printed
    assert max(map(len, printed.splitlines())) <= TERMINAL_WIDTH
    page = (out / "conformance.html").read_text()
    assert CASES["radioss_rota"].figure.url in page and "figure: at dt = 0.001 s" in page


@pytest.mark.slow
def test_a_wrong_cycle_count_or_energy_is_not_the_figure(card):
    out, _ = card
    figure = CASES["radioss_rota"].figure
    ds = _golden(out, "radioss_rota")
    assert judge_figure(ds, "rk4", figure).passed
    ds["n_steps"].loc[{"scheme": "rk4"}] = 9999
    assert judge_figure(ds, "rk4", figure).passed is False
    ds = _golden(out, "radioss_rota")
    ds["omega_body"].loc[{"scheme": "rk4"}] *= 1.0001  # energy 2.0004: past 2.0000 +- 5e-5
    verdict = judge_figure(ds, "rk4", figure)
    assert verdict.passed is False and verdict.value == pytest.approx(4.0004 / 0.5, rel=1e-3)


@pytest.mark.slow
def test_drakes_tolerance_grows_linearly_in_time(card):
    """An error just inside tol(t) late in the run passes; the same error at the start,
    where tol is 1e-3, does not."""
    out, _ = card
    figure = CASES["drake_free_body"].figure
    ds = _golden(out, "drake_free_body")
    dt = float(ds["dt"].max())
    error = ds["orientation_error"].loc[{"scheme": "rk4", "dt": dt}]
    late = 1e-3 + 0.1024 * 9.0
    error[:] = np.where(error["time"] == 9.0, 0.99 * late, 0.0)
    ds["orientation_error"].loc[{"scheme": "rk4", "dt": dt}] = error
    assert judge_figure(ds, "rk4", figure).passed
    error[:] = np.where(error["time"] == error["time"][1], 0.99 * late, 0.0)
    ds["orientation_error"].loc[{"scheme": "rk4", "dt": dt}] = error
    assert judge_figure(ds, "rk4", figure).passed is False


@pytest.mark.slow
def test_exudyns_rk44_reproduces_its_own_figure_asked_of_it_alone(tmp_path):
    """Exudyn's Lie-group test asserts its RK44's own number at h = 1e-3 s: exudyn_rk44 gives
    it on the card; rk4, whose truncation error differs, is not asked for it."""
    pytest.importorskip("exudyn")
    assert main(["conformance", "--cases", "exudyn_heavy_top", "--schemes", "exudyn_rk44,rk4",
                 "--steps", "3", "--out", str(tmp_path), "--quiet"]) == 0
    with xr.open_dataset(tmp_path / "conformance.nc") as ds:
        assert int(ds["figure"].sel(scheme="exudyn_rk44", case="exudyn_heavy_top")) == 1
        assert int(ds["figure"].sel(scheme="rk4", case="exudyn_heavy_top")) == -1
        assert int(ds["passed"].sel(scheme="rk4", case="exudyn_heavy_top")) == 1
    figure = CASES["exudyn_heavy_top"].figure
    golden = _golden(tmp_path, "exudyn_heavy_top")
    golden["omega_space"].loc[{"scheme": "exudyn_rk44"}] *= 1 + 1e-11  # 1.1e-9 rad/s off
    assert judge_figure(golden, "exudyn_rk44", figure).passed is False


@pytest.mark.slow
def test_the_radioss_case_sweeps_the_sources_step_alone(card):
    """It judges no order, so it runs at dt = 1e-3 s only, whatever --steps says."""
    out, _ = card
    ds = _golden(out, "radioss_rota")
    assert ds["dt"].values.tolist() == [1e-3]
    assert "order" not in CASES["radioss_rota"].rules
