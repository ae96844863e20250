"""`rbstudy conformance` on a shrunk golden set: the rules judge real runs, the scorecard is
printed, archived and drawn as a page."""

import base64
import html
import importlib
import importlib.metadata
import pathlib
import re
import shutil
import subprocess

import numpy as np
import pytest
import xarray as xr

from rbstudy.analysis.card_page import TROUBLE
from rbstudy.analysis.conformance import RULES
from rbstudy.cli import main
from rbstudy.pipeline.golden import GOLDEN
from rbstudy.schemes import SCHEMES
from rbstudy.schemes._plugins import GROUP

EXAMPLE = pathlib.Path(__file__).resolve().parents[1] / "examples" / "semi_implicit"
PLUGIN = "semi_implicit_numpy"


@pytest.fixture(scope="module")
def scorecard(tmp_path_factory):
    """euler, midpoint and rk4 on the Abaqus top and the flipping T-handle, three steps."""
    out = tmp_path_factory.mktemp("conformance")
    code = main(
        [
            "conformance",
            "--cases",
            "abaqus_top,t_handle",
            "--schemes",
            "euler",
            "--schemes",
            "midpoint,rk4",
            "--steps",
            "3",
            "--out",
            str(out),
            "--quiet",
        ]
    )
    assert code == 0
    with xr.open_dataset(out / "conformance.nc") as ds:
        return out, ds.load()


@pytest.mark.slow
def test_the_scorecard_names_the_code_that_made_it_as_archives_do(scorecard):
    """``rbstudy 0.4.0 (commit abc1234)`` from a checkout, as each golden archive says."""
    out, ds = scorecard
    with xr.open_dataset(out / "conformance_abaqus_top" / "conformance_abaqus_top.nc") as golden:
        assert ds.attrs["source"] == golden.attrs["source"]
    assert ds.attrs["source"].startswith(f"rbstudy {importlib.metadata.version('rbstudy')}")


def _rule(ds, scheme, case, rule):
    return int(ds["rule_passed"].sel(scheme=scheme, case=case, rule=rule))


@pytest.mark.slow
def test_sound_schemes_pass_every_rule_with_their_orders(scorecard):
    _, ds = scorecard
    for scheme, order in (("midpoint", 2), ("rk4", 4)):
        assert (ds["passed"].sel(scheme=scheme) == 1).all()
        assert float(ds["value"].sel(scheme=scheme, case="abaqus_top")) == pytest.approx(order, abs=0.1)
    # midpoint claims the energy and L: checked; rk4 claims nothing
    assert _rule(ds, "midpoint", "abaqus_top", "invariants") == 1
    assert _rule(ds, "rk4", "abaqus_top", "invariants") == -1
    assert _rule(ds, "rk4", "t_handle", "flip") == 1


@pytest.mark.slow
def test_explicit_euler_fails_where_it_gains_energy_and_shows_no_order(scorecard):
    """On the T-handle explicit Euler gains a quarter of its energy and blows up at the
    coarsest step: it fails the energy and the order rules. Its failure does not fail the
    failure rule: leapfrog, the other rbstudy scheme of order 1, swept beside it though not
    named, blows up there too."""
    _, ds = scorecard
    assert int(ds["passed"].sel(scheme="euler", case="t_handle")) == 0
    assert _rule(ds, "euler", "t_handle", "energy") == 0
    assert float(ds["rule_value"].sel(scheme="euler", case="t_handle", rule="energy")) > 0.1
    assert _rule(ds, "euler", "t_handle", "order") == 0
    assert _rule(ds, "euler", "t_handle", "failure") == 1
    text = str(ds["rule_text"].sel(scheme="euler", case="t_handle", rule="failure").values)
    assert "no rbstudy scheme of order 1 finished (leapfrog)" in text
    assert list(ds["scheme"].values) == ["euler", "midpoint", "rk4"]  # the baseline unjudged
    # the flip rule is judged where the case finished: within a step at the finer two
    assert _rule(ds, "euler", "t_handle", "flip") == 1


@pytest.mark.slow
def test_the_scorecard_is_printed_archived_and_drawn(scorecard, capsys):
    out, ds = scorecard
    assert list(ds["rule"].values) == list(RULES)
    assert (out / "golden" / "conformance_t_handle.yaml").exists()  # rerunnable studies
    page = (out / "conformance.html").read_text()
    assert page.count('class="pass"') == int((ds["passed"] == 1).sum())
    assert page.count('class="fail"') == int((ds["passed"] == 0).sum())
    assert ds.attrs["wall_seconds"] > 0


@pytest.mark.slow
def test_a_rerun_reuses_the_golden_archives(scorecard, capsys):
    out, ds = scorecard
    archive = out / "conformance_t_handle" / "conformance_t_handle.nc"
    written = archive.stat().st_mtime_ns
    assert (
        main(
            [
                "conformance",
                "--cases",
                "abaqus_top,t_handle",
                "--schemes",
                "euler,midpoint,rk4",
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
    assert "euler" in printed and "FAIL" in printed
    with xr.open_dataset(out / "conformance.nc") as again:
        np.testing.assert_array_equal(again["passed"].values, ds["passed"].values)
    assert archive.stat().st_mtime_ns == written  # up to date: not computed again


@pytest.mark.slow
def test_each_case_is_said_with_the_kernel_time_forecast_for_the_cases_left(scorecard, capsys):
    """The default conformance ran 19.5 min showing only each case's bar: each case is now
    said as it starts, "case k of n", with the forecast kernel time of it and the cases
    after it, as a sweep's forecast line gives each study's."""
    out, _ = scorecard
    capsys.readouterr()
    argv = ["conformance", "--cases", "abaqus_top,t_handle", "--schemes", "euler,midpoint,rk4"]
    assert main([*argv, "--steps", "3", "-o", str(out)]) == 0
    said = [line for line in capsys.readouterr().err.splitlines() if ": case " in line]
    assert len(said) == 2, said
    # the forecasts, as a sweep's forecast line words them
    from rbstudy.pipeline.config import load_study
    from rbstudy.pipeline.estimate import duration_text, estimate

    seconds = [
        estimate(load_study(out / "golden" / f"conformance_{case}.yaml")).wall_seconds
        for case in ("abaqus_top", "t_handle")
    ]
    assert said == [
        f"conformance: case 1 of 2, abaqus_top: kernels {duration_text(seconds[0])}, "
        f"{duration_text(sum(seconds))} with the 1 after it (forecast)",
        f"conformance: case 2 of 2, t_handle: kernels {duration_text(seconds[1])} (forecast)",
    ]


@pytest.mark.slow
def test_a_card_is_the_same_judged_alone_or_beside_others(scorecard, tmp_path, monkeypatch):
    """The example plug-in's numpy scheme, of order 1, finishes on the T-handle where euler
    blows up. Judged beside it, euler still gets the card it gets alone (and beside midpoint
    and rk4), and the plug-in the card it gets alone: the failure rule compares with
    rbstudy's own schemes of the order only, which every golden study sweeps."""
    monkeypatch.syspath_prepend(str(EXAMPLE))
    importlib.import_module("rbstudy_semi_implicit.vectorised")  # here: no probing child
    entry = importlib.metadata.EntryPoint(PLUGIN, "rbstudy_semi_implicit.vectorised:SCHEME", GROUP)
    monkeypatch.setattr(
        importlib.metadata, "entry_points", lambda group=None: [entry] if group == GROUP else ()
    )
    monkeypatch.setattr(SCHEMES, "_groups", {})  # the registry loads the plug-in afresh

    def card(*schemes):
        out = tmp_path / "_".join(schemes)
        assert (
            main(
                [
                    "conformance",
                    "--cases",
                    "t_handle",
                    "--schemes",
                    ",".join(schemes),
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
            return {
                scheme: ds[["passed", "rule_passed", "rule_text"]].sel(scheme=scheme).load()
                for scheme in schemes
            }

    alone = {**card("euler"), **card(PLUGIN)}
    together = card("euler", PLUGIN)
    beside_others = scorecard[1].sel(scheme="euler", case=["t_handle"])
    for scheme in ("euler", PLUGIN):
        xr.testing.assert_equal(together[scheme], alone[scheme])  # attrs: wall time
    xr.testing.assert_equal(alone["euler"], beside_others[["passed", "rule_passed", "rule_text"]])
    failure = together["euler"]["rule_passed"].sel(case="t_handle", rule="failure")
    assert int(failure) == 1  # the plug-in's survival is not held against euler
    assert int(together[PLUGIN]["passed"].sel(case="t_handle")) == 0  # order 0.6, not 1


def test_bad_options_are_one_line_errors(tmp_path, capsys):
    for argv, said in (
        (["--cases", "nope"], "--cases: no golden case 'nope'; the cases: abaqus_top, "),
        (["--steps", "2"], "--steps: give 3 to 8 time steps"),
        (["--steps", "9"], "--steps: give 3 to 8 time steps"),
        (["--schemes", "rk4,rk4"], "--schemes: rk4 is given twice; name it once"),
        (["--cases", "t_handle", "--cases", "t_handle"], "--cases: t_handle is given twice"),
        (
            ["--schemes", "dop853"],
            "--schemes: dop853 chooses its own steps: it has no order in dt to judge; leave it out",
        ),
        (["--schemes", "nope"], "unknown scheme 'nope'"),
    ):
        assert main(["conformance", "--out", str(tmp_path), *argv]) == 1
        error = capsys.readouterr().err
        assert error.startswith(f"rbstudy: error: {said}") or said in error, error
        assert error.count("\n") == 1 and "('" not in error
    assert not list(tmp_path.iterdir())  # nothing written


def test_every_golden_case_names_known_rules():
    assert {rule for case in GOLDEN for rule in case.rules} <= set(RULES)
    assert len({case.name for case in GOLDEN}) == len(GOLDEN) == 12


# Each rule on a golden archive with one thing made wrong, so that the rule must see it.


def _golden(scorecard, case="t_handle"):
    from rbstudy.archive.load import open_results

    out, _ = scorecard
    return open_results(out / f"conformance_{case}" / f"conformance_{case}.nc")


def _judge(ds, case="t_handle"):
    from rbstudy.analysis.conformance import score_case

    return score_case(ds, next(c for c in GOLDEN if c.name == case).rules)


@pytest.mark.slow
def test_the_order_rule_falls_back_on_the_finest_usable_pair(scorecard):
    """rk4's errors made too large at the coarsest steps for an asymptotic fit: the finest
    pair of usable steps still shows order 4; the coarsest pair would not."""
    ds = _golden(scorecard)
    errors = ds["final_orientation_error"]
    dts = ds["dt"].values  # finest first: 0.0125, 0.025, 0.05
    errors.loc[{"scheme": "rk4"}] = [3e-4 / 16, 3e-4, 0.9]
    verdict = _judge(ds)["rk4"].verdicts["order"]
    assert verdict.passed and verdict.value == pytest.approx(4.0)
    assert f"between dt = {dts[0]:g} and {dts[1]:g} s" in verdict.text


@pytest.mark.slow
def test_round_off_at_every_step_passes_as_exact_but_a_falling_error_does_not(scorecard):
    ds = _golden(scorecard)
    errors = ds["final_orientation_error"]
    errors.loc[{"scheme": "rk4"}] = [1.5e-9, 5e-12, 2e-12]  # round-off, growing with steps
    assert "exact" in _judge(ds)["rk4"].verdicts["order"].text
    errors.loc[{"scheme": "rk4"}] = [2e-10, 4e-10, 8e-10]  # small, but falling as h: order 1
    verdict = _judge(ds)["rk4"].verdicts["order"]
    assert verdict.passed is False and "exact" not in verdict.text


@pytest.mark.slow
def test_a_lost_invariant_a_missing_flip_and_an_energy_gain_each_fail(scorecard):
    ds = _golden(scorecard)
    ds["max_energy_error"].loc[{"scheme": "midpoint", "dt": ds["dt"].values[0]}] = 1e-6
    ds["flip_interval_error"].loc[{"scheme": "rk4", "dt": ds["dt"].values[1]}] = np.nan
    ds["energy_error"].loc[{"scheme": "rk4", "dt": ds["dt"].values[2]}] = 2e-3
    cells = _judge(ds)
    assert cells["midpoint"].verdicts["invariants"].passed is False
    assert "lost energy" in cells["midpoint"].verdicts["invariants"].text
    assert cells["rk4"].verdicts["flip"].passed is False
    assert cells["rk4"].verdicts["energy"].passed is False
    assert cells["rk4"].verdicts["energy"].value == pytest.approx(2e-3)


@pytest.mark.slow
def test_a_failure_fails_beside_a_survivor_of_the_same_order(scorecard):
    """midpoint given euler's order for the test: it finished every step where euler blew
    up, so euler's failure now fails the rule, and the verdict names the survivor."""
    ds = _golden(scorecard)
    ds["nominal_order"].loc[{"scheme": "midpoint"}] = 1
    verdict = _judge(ds)["euler"].verdicts["failure"]
    assert verdict.passed is False and "midpoint (order 1) finished at dt = 0.05 s" in verdict.text


@pytest.mark.slow
def test_invariants_are_not_judged_where_no_case_finished(scorecard):
    ds = _golden(scorecard)
    ds["status"].loc[{"scheme": "midpoint"}] = 1  # as an archive holds a blow-up: no error
    ds["final_orientation_error"].loc[{"scheme": "midpoint"}] = np.nan
    cell = _judge(ds)["midpoint"]
    assert cell.verdicts["invariants"].passed is None
    assert cell.verdicts["order"].passed is False and not cell.passed


def test_an_unwritable_out_is_a_one_line_error(tmp_path, capsys):
    blocked = tmp_path / "file"
    blocked.write_text("")
    assert (
        main(["conformance", "--cases", "abaqus_top", "--schemes", "rk4", "--out", str(blocked / "sub")]) == 1
    )
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "choose another folder with --out" in error


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """euler and jolt (a published step: not rbstudy's builtin) on the Abaqus top and the
    T-handle, three steps: the card's page, its archive, and its folder."""
    out = tmp_path_factory.mktemp("card_page")
    argv = ["conformance", "--cases", "abaqus_top,t_handle", "--schemes", "euler,jolt"]
    assert main([*argv, "--steps", "3", "--out", str(out), "--quiet"]) == 0
    with xr.open_dataset(out / "conformance.nc") as ds:
        return out, (out / "conformance.html").read_text(), ds.load()


@pytest.mark.slow
def test_the_page_says_each_cases_answer_and_what_goes_wrong_as_the_archives_do(page):
    """The findings in words, recomputed: each case's answer is its golden study's own
    recommendation (read again from its archive), and the line of jolt, the one scheme that
    is not rbstudy's own, names each rule it failed with exactly the cases the scorecard's
    archive marks failed."""
    from rbstudy.analysis.findings import BUSY_CLAUSE, findings
    from rbstudy.archive.reader import open_archive

    out, text, ds = page
    text = html.unescape(text)  # jinja escapes the apostrophes of the words
    for case in ds["case"].values:
        study = open_archive(out / f"conformance_{case}" / f"conformance_{case}.nc")
        answer = next(f.text for f in findings(study) if "recommendation" in f.kind)
        assert answer.partition(BUSY_CLAUSE)[0] in text, case
    troubles = re.findall(r"<li>(jolt \(.*?)</li>", text)
    failed = ds["rule_passed"].sel(scheme="jolt") == 0
    passed = int(ds["passed"].sel(scheme="jolt").sum())
    if not failed.any():
        assert troubles == []
        return
    assert len(troubles) == 1 and troubles[0].startswith(f"jolt ({passed}/{ds.sizes['case']}): ")
    for rule in ds["rule"].values:
        cases = [str(c) for c in ds["case"].values if bool(failed.sel(case=c, rule=rule))]
        phrase = re.search(rf"{re.escape(TROUBLE[str(rule)])} in ([a-z_, ]+)", troubles[0])
        assert (phrase.group(1).split(", ") if phrase else []) == cases, (rule, troubles[0])
    assert "<li>euler" not in text  # rbstudy's own: the yardstick, not a finding


@pytest.mark.slow
def test_the_page_stands_alone_every_figure_embedded_and_every_link_landing(page):
    """One work-precision figure per case, each a PNG inside the page; every link within the
    page lands on an element of the page; a cell links to its case's figure."""
    _, text, ds = page
    images = re.findall(r'<img class="figure" src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert len(images) == ds.sizes["case"]
    for encoded in images:
        assert base64.b64decode(encoded).startswith(b"\x89PNG\r\n\x1a\n")
    ids = set(re.findall(r'id="([^"]+)"', text))
    targets = re.findall(r'href="#([^"]+)"', text)
    assert targets and set(targets) <= ids
    for case in ds["case"].values:
        assert f'href="#figure-{case}"' in text and f'id="figure-{case}"' in text


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("chromium") is None, reason="no chromium on this machine")
def test_the_page_opens_in_headless_chromium_with_every_figure_drawn(page):
    """Loaded by headless Chromium, every figure decodes (the page marks each image it drew)
    and the card's table is there."""
    out, _, ds = page
    dom = subprocess.run(
        [
            "chromium",
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=10000",
            "--dump-dom",
            (out / "conformance.html").as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    assert dom.count('data-drawn="1"') == ds.sizes["case"] and 'data-drawn="0"' not in dom
    assert '<table id="card">' in dom
