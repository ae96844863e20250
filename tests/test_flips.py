"""The flips of a body turning near its intermediate axis, stored and said in words
(`rbstudy.analysis.flips`): the counts against an independent solution (scipy's DOP853 at a
tight tolerance, sampled at the same times), the findings' numbers against a recomputation
from the archive, the sampling floor named for what it is."""

import json

import numpy as np
import pytest
from helpers import write_study
from scipy.integrate import solve_ivp

from rbstudy.analysis.convergence_legend import FittedLine, fit_text
from rbstudy.analysis.findings import findings
from rbstudy.analysis.measures import ERROR_MEASURES
from rbstudy.analysis.overlaps import together
from rbstudy.archive.reader import open_archive
from rbstudy.cli import main
from rbstudy.physics.analytic import flip_interval
from rbstudy.physics.metrics import OrderFit

INERTIA = (1.0, 2.0, 3.0)
SPIN = (1e-3, 1.0, 1e-3)
DURATION, INTERVAL = 120.0, 0.1
STEPS = [0.1, 0.05, 0.025, 0.0125]


def _exact_middle_rates(times):
    """The intermediate-axis rate of the free body at ``times``, by DOP853 at rtol 1e-12."""
    i1, i2, i3 = INERTIA

    def euler(_, w):
        return [(i2 - i3) * w[1] * w[2] / i1, (i3 - i1) * w[2] * w[0] / i2, (i1 - i2) * w[0] * w[1] / i3]

    solved = solve_ivp(euler, (0.0, times[-1]), SPIN, "DOP853", t_eval=times, rtol=1e-12, atol=1e-14)
    return solved.y[1]


@pytest.fixture(scope="module")
def flip_study(tmp_path_factory):
    folder = tmp_path_factory.mktemp("flips")
    config = write_study(
        folder,
        name="flips",
        scene={
            "body": {"mass": 1.0, "inertia": list(INERTIA)},
            "initial": {"angular_velocity": {"body": list(SPIN)}},
            "duration": DURATION,
        },
        output={"interval": INTERVAL},
        sweep={"scheme": ["rk4", "euler", "midpoint"], "dt": STEPS},
    )
    assert main(["sweep", str(config), "--out", str(folder / "out"), "--quiet"]) == 0
    path = folder / "out" / "flips" / "flips.nc"
    with open_archive(path) as ds:
        ds = ds.load()
    return ds, path


@pytest.mark.slow
def test_the_exact_flips_are_an_independent_solution_s(flip_study):
    ds, _ = flip_study
    times = ds["time"].values
    rates = _exact_middle_rates(times)
    independent = np.count_nonzero(np.signbit(rates[1:]) != np.signbit(rates[:-1]))
    assert np.all(ds["flip_count_exact"].values == independent)
    # about one flip an interval, as the closed form has it
    assert abs(independent - DURATION / flip_interval(INERTIA, SPIN)) <= 1


@pytest.mark.slow
def test_the_flip_findings_are_the_archive_s_numbers(flip_study, capsys):
    ds, path = flip_study
    said = [f for f in findings(ds) if f.kind == "flip"]
    study, *schemes = said
    exact = flip_interval(INERTIA, SPIN)
    assert f"every {exact:.4g} s (exact)" in study.text
    assert study.numbers["flip_interval_exact_s"] == [pytest.approx(exact, rel=1e-12)] * 2
    lost_or_added = (ds["flip_count"] != ds["flip_count_exact"]) & np.isfinite(ds["flip_count"])
    assert not lost_or_added.any() and "every scheme kept every flip" in study.text
    for finding in schemes:
        scheme = finding.numbers["scheme"]
        errors = np.abs(ds["flip_interval_error"].sel(scheme=scheme).values)
        finest = int(np.argmin(ds["dt"].values))
        assert finding.numbers["flip_interval_error_s"] == errors[finest]
        run = ds["flip_count"].sel(scheme=scheme).values
        counts = ds["flip_count_exact"].sel(scheme=scheme).values
        assert finding.numbers["lost_cases"] == int(np.sum(run < counts))
        assert finding.numbers["added_cases"] == int(np.sum(run > counts))
        if finding.numbers["lost_cases"] + finding.numbers["added_cases"] == 0:
            assert "every flip kept" in finding.text
    by_name = {f.numbers["scheme"]: f for f in schemes}
    # rk4's interval errors are the sampling's (each crossing placed between samples 0.1 s
    # apart), below the measure's floor at every dt: said so, no order fitted
    assert np.all(np.abs(ds["flip_interval_error"].sel(scheme="rk4").values) < ERROR_MEASURES["flip"].floor)
    assert by_name["rk4"].numbers["order"] is None and "at the sampling floor" in by_name["rk4"].text
    assert by_name["midpoint"].numbers["order"] == pytest.approx(2.0, abs=0.1)
    assert by_name["euler"].numbers["order"] == pytest.approx(1.0, abs=0.1)
    # euler blows up at the largest step: its flips are counted over the runs that ended
    assert ds["status"].sel(scheme="euler", dt=STEPS[0]) != 0
    assert "every flip kept in the 3 of 4 cases that ran to the end" in by_name["euler"].text
    # the words are the summary's too, in every form
    assert main(["summary", str(path), "--format", "json"]) == 0
    listed = json.loads(capsys.readouterr().out)["findings"]
    assert [f["text"] for f in listed if f["kind"] == "flip"] == [f.text for f in said]


def test_a_flip_interval_at_its_floor_is_at_the_sampling_floor():
    """Flips are timed between samples: below the measure's floor the error is the sampling's,
    and the legend says so, where an orientation error there is round-off."""
    errors = np.array([1e-7, 2e-7, 3e-7])
    no_fit = OrderFit(np.nan, np.zeros(3, bool), np.nan)
    for key, words in (("flip", "at the sampling floor"), ("orientation", "at the round-off floor")):
        spec = ERROR_MEASURES[key]
        floors = np.full(3, spec.floor if key == "flip" else 1e-6)
        line = FittedLine("rk4", 0, errors, no_fit, False, np.full(3, np.nan), floors, spec.floor_kind)
        assert fit_text(line) == words
    # lines drawn together at the floor say which floor
    assert together(["rk4", "rkmk4"], [errors, errors], 1e-5, "the sampling floor") == (
        "rk4 = rkmk4 (at the sampling floor: at most 1e-05)"
    )


@pytest.mark.slow
def test_flips_lost_or_added_are_counted_and_said(flip_study):
    """A case whose run lost two flips and one that added one (planted in the archive's
    counts) are said with the cases they rest on."""
    ds, _ = flip_study
    planted = ds.copy(deep=True)
    counts = planted["flip_count"]
    exact = float(planted["flip_count_exact"].values.ravel()[0])
    counts.loc[{"scheme": "midpoint", "dt": STEPS[0]}] = exact - 2
    counts.loc[{"scheme": "midpoint", "dt": STEPS[1]}] = exact + 1
    said = next(f for f in findings(planted) if f.kind == "flip" and f.numbers.get("scheme") == "midpoint")
    assert "lost flips in 1 of all 4 cases (up to 2 a case); added flips in 1 of all 4 cases" in said.text
    assert (said.numbers["lost_cases"], said.numbers["added_cases"]) == (1, 1)
    headline = next(f for f in findings(planted) if f.kind == "flip")
    assert "; midpoint lost or added flips (below)" in headline.text


def test_conditioning_near_the_separatrix_is_said_and_recomputed(flip_study):
    """The body of w0 = (1e-3, 1, 1e-3) lies near the separatrix: the headline gives its k'^2,
    recomputed here from the inertia and spin, and its float64 floor as ulps of the angle it
    turns, recomputed from the archive."""
    ds, _ = flip_study
    headline = next(f for f in findings(ds) if f.kind == "flip")
    inertia, omega = np.array([1.0, 2.0, 3.0]), np.array([1e-3, 1.0, 1e-3])
    m = inertia * omega
    energy2, momentum2 = float(m @ omega), float(m @ m)
    # k'^2 = (I3 - I1) d2 / ((I3 - I2) d1), d_j = G^2 - 2 E I_j
    expected = (3.0 - 1.0) * (momentum2 - energy2 * 2.0) / ((3.0 - 2.0) * (momentum2 - energy2 * 1.0))
    assert headline.numbers["separatrix_distance"] == pytest.approx(expected, rel=1e-6)
    floor = float(ds["float64_floor"].max())
    turned = float(ds["initial_spin"].max()) * headline.numbers["duration_s"]
    ulps = floor / (np.finfo(float).eps * turned)
    assert f"near the separatrix (k'^2 = {expected:.1g})" in headline.text
    assert f"by {floor:.2g} rad ({ulps:.2g} ulps of the" in headline.text
