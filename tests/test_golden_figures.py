"""The peers' public cases in the golden set: OpenRadioss's QA ROTA, Drake's free-body
benchmark and floating-body test, Exudyn's Lie-group test, each with the figure its source
asserts, which the card checks every scheme against (`judge_figure`)."""

import numpy as np
import pytest
import xarray as xr
from scipy.spatial.transform import Rotation

from rbstudy.analysis.conformance import judge_figure
from rbstudy.analysis.summary import TERMINAL_WIDTH
from rbstudy.archive.load import open_results
from rbstudy.cli import main
from rbstudy.pipeline.golden import GOLDEN

CASES = {case.name: case for case in GOLDEN}
_CARD_CASES = "radioss_rota,drake_free_body,drake_floating_body,abaqus_top"


@pytest.fixture(scope="module")
def card(tmp_path_factory):
    """rk4, midpoint and euler on three peers' cases and the Abaqus top, three steps."""
    out = tmp_path_factory.mktemp("figures")
    assert (
        main(
            [
                "conformance",
                "--cases",
                _CARD_CASES,
                "--schemes",
                "rk4,midpoint,euler",
                "--steps",
                "3",
                "--out",
                str(out),
                "--quiet",
            ]
        )
        == 0
    )
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
        ds["figure_text"].sel(scheme="euler", case="drake_free_body").values
    )
    # a case of rbstudy's own asserts no figure
    assert (ds["figure"].sel(case="abaqus_top") == -1).all()
    assert "cycles 10001 (asserted 10001)" in str(
        ds["figure_text"].sel(scheme="rk4", case="radioss_rota").values
    )


@pytest.mark.slow
def test_the_card_says_figure_yes_or_no_within_the_terminal(card, capsys):
    out, _ = card
    assert (
        main(
            [
                "conformance",
                "--cases",
                _CARD_CASES,
                "--schemes",
                "rk4,midpoint,euler",
                "--steps",
                "3",
                "-o",
                str(out),
                "-q",
            ]
        )
        == 0
    )
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
    assert (
        main(
            [
                "conformance",
                "--cases",
                "exudyn_heavy_top",
                "--schemes",
                "exudyn_rk44,rk4",
                "--steps",
                "3",
                "--out",
                str(tmp_path),
                "--quiet",
            ]
        )
        == 0
    )
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


def test_drakes_floating_body_asks_each_element_as_compare_matrices_does():
    """Drake's floating_body_test.cc: at 10 s, R_WB, w_WB and p_WBcm within 1e-5 max(1,
    |element|); w_WB against the torque-free symmetric top written independently (the
    symmetry axis turning about L at |L| / I), p_WBcm against the parabola."""
    figure = CASES["drake_floating_body"].figure
    assert figure.url.endswith("multibody/tree/test/floating_body_test.cc") and figure.scheme is None
    checks = {check.measure: check for check in figure.checks}
    assert all(check.at == 10.0 and check.growth == 0.0 for check in figure.checks)
    assert (checks["orientation_error"].expected, checks["orientation_error"].tolerance) == (0, 1e-5)
    inertia, axial, omega0 = 0.04, 0.02, np.ones(3)  # B = W at t = 0, so w_B(0) = w_W(0)
    momentum = np.array([inertia, inertia, axial]) * omega0
    axis = Rotation.from_rotvec(momentum / inertia * 10.0).apply([0.0, 0.0, 1.0])
    omega = momentum / inertia + (1 / axial - 1 / inertia) * (momentum @ axis) * axis
    position = (10.0, 0.0, -0.5 * 9.81 * 100.0)  # v(0) = (1, 0, 0) m/s, g = 9.81 m/s^2 down z
    for name, exact in (("omega_space", omega), ("position", position)):
        for component, value in zip("xyz", exact, strict=True):
            check = checks[f"{name}_{component}"]
            assert check.expected == pytest.approx(value, abs=1e-12)
            assert check.tolerance == pytest.approx(1e-5 * max(1.0, abs(value)), rel=1e-12)


@pytest.mark.slow
def test_the_floating_body_passes_for_rbstudys_schemes_and_only_rk4_meets_drakes_1e5(card):
    """At the card's 1/80 s, rk4 reproduces Drake's figure; midpoint passes every rule but
    misses 1e-5 (its orientation error is 7e-4 rad at 10 s); euler does neither."""
    _, ds = card
    for scheme in ("rk4", "midpoint"):
        assert int(ds["passed"].sel(scheme=scheme, case="drake_floating_body")) == 1, scheme
    figure = ds["figure"].sel(case="drake_floating_body")
    assert (
        int(figure.sel(scheme="rk4")),
        int(figure.sel(scheme="midpoint")),
        int(figure.sel(scheme="euler")),
    ) == (1, 0, 0)
    said = str(ds["figure_text"].sel(scheme="rk4", case="drake_floating_body").values)
    assert said.startswith("at dt = 0.0125 s: orientation_error") and "position_z -490.5" in said


@pytest.mark.slow
def test_a_component_past_drakes_relative_allowance_is_not_the_figure(card):
    """p_z = -490.5 m is allowed 4.9e-3 m, w_x = 1.41 rad/s 1.41e-5 rad/s: a miss just
    inside passes, just outside fails (an absolute 1e-5 would fail the first)."""
    out, _ = card
    figure = CASES["drake_floating_body"].figure

    def judged(variable, axis, shift):
        ds = _golden(out, "drake_floating_body")
        ds[variable].loc[{"scheme": "rk4", "time": 10.0, "axis": axis}] += shift
        return judge_figure(ds, "rk4", figure).passed

    assert judged("position", "z", 4.8e-3) and not judged("position", "z", 5.0e-3)
    assert judged("omega_space", "x", 1.3e-5) and not judged("omega_space", "x", 1.5e-5)


@pytest.mark.slow
def test_drakes_rk3_reproduces_its_floating_body_figure_and_its_rk2_does_not(tmp_path):
    """The figure is of the motion, asked of every scheme: fixed-step RK3 at 1/80 s is
    within it (orientation 6.9e-6 rad); RK2 misses w_WB by up to 1.8e-5 rad/s."""
    pytest.importorskip("pydrake")
    assert (
        main(
            [
                "conformance",
                "--cases",
                "drake_floating_body",
                "--schemes",
                "drake_rk3,drake_rk2",
                "--steps",
                "3",
                "--out",
                str(tmp_path),
                "--quiet",
            ]
        )
        == 0
    )
    with xr.open_dataset(tmp_path / "conformance.nc") as ds:
        figure = ds["figure"].sel(case="drake_floating_body")
        assert (int(figure.sel(scheme="drake_rk3")), int(figure.sel(scheme="drake_rk2"))) == (1, 0)
        assert int(ds["passed"].sel(scheme="drake_rk3", case="drake_floating_body")) == 1


def test_only_the_heavy_top_carries_a_moment():
    """A held load judges the adapter only where a moment acts: the heavy top's weight at its
    node; Drake's floating body falls under gravity at its centre, which turns nothing."""
    assert [case.name for case in GOLDEN if not case.moment_free] == ["exudyn_heavy_top"]


@pytest.mark.slow
def test_the_card_marks_the_heavy_top_cells_that_judge_an_adapters_held_load(tmp_path, capsys):
    """MuJoCo's RK4 shows no order 4 under the heavy top's moment, which its adapter holds
    over each step: the card says so beside the cell and in a footnote, not on rk4's cell nor
    on the moment-free floating body."""
    pytest.importorskip("mujoco")
    assert (
        main(
            [
                "conformance",
                "--cases",
                "exudyn_heavy_top,drake_floating_body",
                "--schemes",
                "mujoco_rk4,rk4",
                "--steps",
                "3",
                "--out",
                str(tmp_path),
                "--quiet",
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    rows = {line.split()[0]: line for line in printed.splitlines()[1:3]}
    assert rows["mujoco_rk4"].split()[2:] == ["FAIL", "order", "*", "order", "4.00,", "figure", "yes"]
    assert "*" not in rows["rk4"]
    assert "\n* the adapter holds the loads of each step's start over the step" in printed
    assert max(map(len, printed.splitlines())) <= TERMINAL_WIDTH
    assert "a cell so marked judges that" in (tmp_path / "conformance.html").read_text()
