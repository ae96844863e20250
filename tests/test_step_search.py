"""The step search (`rbstudy sweep --find-step`): the largest step that meets the accuracy
bound, per scheme and value of the other axes, checked by independent sweeps at that step
and at 1.1 times it."""

import contextlib
import html
import io
import json
import math
import re
from types import SimpleNamespace

import netCDF4
import numpy as np
import pytest
import xarray as xr
import yaml
from helpers import CONFIGS, abaqus_mapping, write_study

from rbstudy.analysis.searched import _scheme_texts
from rbstudy.archive.folder import StudyFolder
from rbstudy.cli import main
from rbstudy.pipeline.step_search import _next_steps, _Probes

BOUND = 0.01  # the default study's accuracy bound (rad)


@pytest.mark.parametrize("tolerance", [0.05, 0.01, 0.2])
def test_the_search_ends_on_the_largest_step_meeting_a_monotone_bound_within_its_tolerance(tolerance):
    """Bracketing then bisection, on step counts n over a duration (dt = T / n): whatever
    the least step count that meets the bound and wherever the grid's accurate step lies,
    the search ends on a step that meets it, with a failing one above it within the
    tolerance or one whole division of the duration away."""
    for least in [1, 2, 3, 7, 25, 99, 100, 640, 1001, 12_345]:
        for start in sorted({least, least + 1, 2 * least, 64 * least + 5}):
            lo, hi, probes = start, 0, 0
            while steps := _next_steps(lo, hi, tolerance):
                probes += 1
                assert 0 < steps < lo and (not hi or steps > hi)
                lo, hi = (steps, hi) if steps >= least else (lo, steps)
            assert lo == least if least == 1 else lo >= least, (least, start, lo, hi)
            if least > 1:
                assert hi == least - 1 or lo / hi - 1 <= tolerance, (least, start, lo, hi)
                assert lo / (least - 1) - 1 <= max(tolerance, 1 / (least - 1)) + 1e-12
            assert probes <= 2 * math.log2(start + 1) + 8


def _sweep_printing(args):
    """``rbstudy`` ``args``: (exit code, what it printed)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(args)
    return code, out.getvalue()


def _independent(tmp_path, name, scheme, dt, ratios, duration=2.0):
    """The default study's body at ``ratios`` run by a plain sweep with ``scheme`` at ``dt``
    (samples at every step) over ``duration``: the archive's worst orientation error (rad)
    and whether every case was judged accurate."""
    study = yaml.safe_load((CONFIGS / "abaqus_top.yaml").read_text())
    study["name"] = name
    study["scene"]["duration"] = float(duration)
    study["run"] = {"scheme": scheme, "dt": float(dt)}
    study["output"] = {"interval": float(dt)}
    study["sweep"] = {"inertia_ratio": [float(r) for r in ratios]}
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(study, sort_keys=False))
    code, _ = _sweep_printing(["sweep", str(path), "--out", str(tmp_path / "checks"), "--quiet"])
    assert code == 0
    ds = xr.load_dataset(tmp_path / "checks" / name / f"{name}.nc")
    return float(ds["orientation_error"].max()), bool((ds["accuracy"] == 0).all())


@pytest.mark.slow
def test_find_step_on_the_default_study_is_met_at_its_step_and_not_at_1_1_times_it(tmp_path):
    """The default study swept with --find-step: every scheme's least found step (the one it
    names for every inertia ratio) meets the bound at every ratio in an independent sweep,
    and 1.1 times the step found at each ratio fails there (rounded up to a whole division
    of the duration, as every run's step is); the answer it
    names and its "Nx cheaper" are recomputed from the archive; a rerun
    reuses every probe and prints the same lines."""
    out = tmp_path / "results"
    args = ["sweep", str(CONFIGS / "abaqus_top.yaml"), "--out", str(out), "--find-step", "--quiet"]
    code, printed = _sweep_printing(args)
    assert code == 0
    searched = printed[printed.index("largest step meeting") :]
    found = xr.load_dataset(out / "abaqus_top" / "abaqus_top.nc", group="search")  # in the archive
    grid = xr.load_dataset(out / "abaqus_top" / "abaqus_top.nc")
    assert not (out / "abaqus_top" / "search").exists()  # its working file, removed
    ratios = grid["inertia_ratio"].values
    assert list(found["group_scheme"].values) == list(np.repeat(grid["scheme"].values, len(ratios)))

    for scheme in ["rk4", "hht", "euler"]:
        mine = found["group_scheme"].values == scheme
        steps, failing = found["found_dt"].values[mine], found["failing_dt"].values[mine]
        least = float(steps.min())
        assert least > 0.01 or scheme == "euler"  # past the grid's largest step, 0.01 s
        error, accurate = _independent(tmp_path, f"{scheme}_at", scheme, least, ratios)
        assert accurate and error <= BOUND, (scheme, least, error)
        for ratio, step, fails in zip(ratios, steps, failing, strict=True):
            # runs end on a whole step: 1.1 times the step, up to the next whole division of
            # the duration (2 / 12 s -> 2 / 10 s): a shorter run would have less time to err
            larger = 2.0 / math.floor(2.0 / (1.1 * step) + 1e-9)
            assert fails <= larger * (1 + 1e-12), (scheme, ratio, step, fails)
            error, accurate = _independent(tmp_path, f"{scheme}_over", scheme, larger, [ratio])
            assert not accurate and error > BOUND, (scheme, ratio, step, error)

    # the answer: the cheapest scheme at its least found step, every ratio, recomputed
    seconds = {}
    for scheme in grid["scheme"].values:
        mine = found["group_scheme"].values == scheme
        if np.isfinite(found["found_dt"].values[mine]).all():
            step = found["found_dt"].values[mine].min()
            per_step = grid["step_seconds"].sel(scheme=scheme).values.mean()
            seconds[str(scheme)] = round(2.0 / step) * per_step
    best = min(seconds, key=seconds.get)
    answer = r"\): (\w+)\b.*? at dt=([\d.e-]+) s, ([\d.e+-]+) s a case, ([\d.]+)x cheaper"
    named = re.search(answer, " ".join(searched.split()))  # the lines unwrapped
    assert named, searched
    assert named.group(1) == best
    step = found["found_dt"].values[found["group_scheme"].values == best].min()
    assert float(named.group(2)) == pytest.approx(step, rel=1e-3)
    assert float(named.group(3)) == pytest.approx(seconds[best], rel=0.05)
    # "Nx cheaper than the grid's best (..., S s a case)": S is the recommendation's cost as
    # the findings print it (of the scheme that represents its tie), the least cost on the
    # grid that meets the bound at every ratio or within the calibration's uncertainty of it
    grid_best = re.search(
        r"grid's best \(.*? at dt=0\.01 s, ([\d.e+-]+) s a case\)", " ".join(searched.split())
    )
    recommended = re.search(r"recommended: .*? at dt=0\.01 s, ([\d.e+-]+) s a case", printed)
    assert grid_best and recommended and grid_best.group(1) == recommended.group(1)
    assert float(named.group(4)) == pytest.approx(float(grid_best.group(1)) / seconds[best], rel=0.05)
    meets = ((grid["accuracy"] == 0) & (grid["status"] == 0)).all("inertia_ratio")
    cost = (grid["n_steps"] * grid["step_seconds"]).mean("inertia_ratio").where(meets)
    spread = float(grid["step_seconds_uncertainty"].max())
    assert (
        float(cost.min()) * 0.95 <= float(grid_best.group(1)) <= float(cost.min()) * (1 + 2 * spread) * 1.05
    )
    if best == "exact_split":  # exact for a free body: the whole run in one step meets the bound
        error, accurate = _independent(tmp_path, "answer", best, 2.0, ratios)
        assert accurate and error <= BOUND

    # summary and report tell the same search from the archive
    archive = str(out / "abaqus_top" / "abaqus_top.nc")
    told = re.split(r"\n\d+ probes \(", searched)[0].splitlines()  # without the sweep's own line
    code, summary = _sweep_printing(["summary", archive])
    assert code == 0 and "\n".join(told) in summary
    code, document = _sweep_printing(["summary", archive, "--format", "json"])
    search = json.loads(document)["step_search"]
    assert code == 0 and " ".join(search["lines"]).split() == " ".join(told).split()
    cheapest = search["every_value"][0]
    assert cheapest["scheme"] == best and cheapest["seconds_per_case"] == pytest.approx(
        seconds[best], rel=0.05
    )
    report = tmp_path / "report"
    assert _sweep_printing(["report", archive, "--out", str(report), "--quiet"])[0] == 0
    page = html.unescape(" ".join((report / "report.html").read_text().split()))
    answer = " ".join(" ".join(told).split()).split(" largest steps found")[0]
    assert answer in page

    sealed = (out / "abaqus_top" / "abaqus_top.nc").read_bytes()
    code, again = _sweep_printing(args)
    assert code == 0
    assert (out / "abaqus_top" / "abaqus_top.nc").read_bytes() == sealed  # not rewritten
    probes = found.sizes["probe"]
    assert f"{probes} probes ({probes} reused)" in again
    assert again[again.index("largest step meeting") :] == searched.replace(
        f"{probes} probes (0 reused)", f"{probes} probes ({probes} reused)"
    )


def test_a_step_tolerance_outside_0_and_1_is_refused_in_one_line(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["sweep", str(CONFIGS / "abaqus_top.yaml"), "--find-step", "--step-tolerance", "5"])
    assert stop.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--step-tolerance" in error and "between 0 and 1" in error


@pytest.mark.slow
def test_the_step_search_is_sealed_in_the_archive_and_a_change_to_it_is_caught(tmp_path, capsys):
    """The search travels in the archive, as its group ``search``, under the archive's
    checksums: ``verify`` proves it; a changed probe verdict or a search relabelled as
    another study's is caught by ``verify`` and by ``summary``, which reads it only when
    proven (or, unverified, only when it is of the same study). A sweep that finds its
    archive changed rebuilds it, and the search runs again to the same answer."""
    out = tmp_path / "results"
    config = CONFIGS / "abaqus_top.yaml"
    shrink = ["--set", "sweep.inertia_ratio=[0.5]", "--set", "sweep.dt={halving: 0.01, count: 2}"]
    args = ["sweep", str(config), "--out", str(out), "--find-step", "--quiet", *shrink]
    code, printed = _sweep_printing(args)
    assert code == 0
    archive = out / "abaqus_top" / "abaqus_top.nc"
    assert "kept in " + str(archive) in " ".join(printed.split())
    assert set(xr.load_dataset(archive).data_vars).isdisjoint({"found_dt", "probe", "steps"})
    code, told = _sweep_printing(["verify", str(archive)])
    assert code == 0, told
    with netCDF4.Dataset(archive) as nc:
        sealed = json.loads(nc["integrity"].getncattr("checksums"))
        kept = nc["search"]
        assert {f"search/{name}" for name in kept.variables} <= set(sealed)
        probes = kept.dimensions["probe"].size
    code, told = _sweep_printing(["summary", str(archive)])
    assert code == 0 and "largest step meeting the bound" in told and "group search" in told

    with netCDF4.Dataset(archive, "a") as nc:  # a probe's verdict changed
        verdicts = nc["search"]["accuracy"]
        verdicts[0] = 1 - verdicts[0]
    capsys.readouterr()
    assert main(["verify", str(archive)]) != 0
    assert "variable search/accuracy differs from its checksum" in capsys.readouterr().err
    code, again = _sweep_printing(args)  # the archive rebuilt, the search run again
    assert code == 0
    assert f"{probes} probes (0 reused)" in again
    strip = lambda text: text[text.index("largest step meeting") :].split("probes (")[0]  # noqa: E731
    assert strip(again) == strip(printed)

    with netCDF4.Dataset(archive, "a") as nc:  # relabelled as another study's
        nc["search"].setncattr("batches", "another")
    capsys.readouterr()
    assert main(["summary", str(archive)]) != 0
    assert "the attributes of group search differ" in capsys.readouterr().err
    code, told = _sweep_printing(["summary", str(archive), "--no-verify"])
    assert code == 0 and "largest step meeting the bound" not in told
    told = " ".join(told.split())  # unwrapped
    assert "its step search is of another version of this study; sweep --find-step again" in told


def test_step_tolerance_without_find_step_is_refused_before_the_sweep_runs(tmp_path, capsys):
    """--step-tolerance alone would be ignored: the sweep refuses it in one line, unrun."""
    config = write_study(tmp_path)
    code = main(["sweep", str(config), "--out", str(tmp_path / "out"), "--step-tolerance", "0.1", "-q"])
    assert code == 1
    assert "--find-step" in capsys.readouterr().err.strip().splitlines()[-1]
    assert not (tmp_path / "out" / "study").exists()


@pytest.mark.parametrize("damage", ["garbage", "empty", "truncated", "no probe columns"])
def test_a_damaged_probes_file_is_not_reused(tmp_path, damage):
    """A probes file that does not read back (or lacks its columns) keeps no probe: they are
    run again and the file rewritten, where reading it stopped the sweep with a traceback."""
    path = tmp_path / "search" / "steps.nc"
    path.parent.mkdir()
    written = xr.Dataset({"case": ("probe", [0, 1]), "steps": ("probe", [4, 8])})
    written.attrs["search_identity"] = "this search"
    written.to_netcdf(path)
    if damage == "garbage":
        path.write_bytes(np.random.default_rng(1).bytes(5000))
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:3000])
    folder = StudyFolder(tmp_path, SimpleNamespace(output_format="netcdf"), "study")
    assert _Probes(None, folder, "this search", force=False).rows == {}


def test_a_scheme_searched_at_some_values_of_the_other_axes_only_says_so():
    """A scheme with an accurate swept step at one value of the other axes only: its found
    step is not said to hold at every value (one finite group of two is not every one)."""
    search = SimpleNamespace(
        scheme=np.array(["leapfrog", "leapfrog"], dtype=object),
        found_dt=np.array([math.nan, 0.0714]),
        failing_dt=np.array([math.nan, 0.0833]),
        common={},
        adaptive=(),
        tolerance=0.05,
    )
    texts, nowhere = _scheme_texts(search)
    assert texts == ["leapfrog 0.0714 (next larger step +17%, not at every value)"] and not nowhere


@pytest.mark.slow
def test_find_step_names_adaptive_schemes_as_such_and_reruns_past_a_damaged_file(tmp_path):
    """dop853 meets the bound on the grid but chooses its own steps: it is named as not
    searched for that, not for "no swept step meets the bound"; a tolerance of 0.1% is
    printed as such (not "0%"); a garbage working file left beside the archive is passed
    over: the probes sealed in the archive are reused, with the same answer."""
    config = write_study(
        tmp_path,
        sweep={"scheme": ["rk4", "dop853"], "dt": [0.01, 0.005]},
        scene={**abaqus_mapping(), "duration": 0.5},
    )
    out = tmp_path / "out"
    args = ["sweep", str(config), "--out", str(out), "--find-step", "--step-tolerance", "0.001", "-q"]
    code, printed = _sweep_printing(args)
    assert code == 0
    grid = xr.load_dataset(out / "study" / "study.nc")
    assert (grid["accuracy"].sel(scheme="dop853") == 0).all()  # it meets the bound on the grid
    searched = " ".join(printed[printed.index("largest step meeting") :].split())
    assert "not searched (adaptive: each chooses its own steps): dop853" in searched
    assert "no swept step meets" not in searched
    assert "searched to 0.1%" in searched and "0.1% larger fails" in searched
    probes = xr.load_dataset(out / "study" / "study.nc", group="search").sizes["probe"]
    path = out / "study" / "search" / "steps.nc"
    path.parent.mkdir()
    path.write_bytes(np.random.default_rng(2).bytes(5000))
    code, again = _sweep_printing(args)
    assert code == 0
    rerun = " ".join(again[again.index("largest step meeting") :].split())
    assert rerun == searched.replace(f"{probes} probes (0 reused)", f"{probes} probes ({probes} reused)")
    assert not path.exists()  # the garbage removed with the working file


@pytest.mark.slow
def test_another_tolerance_reuses_the_probes_and_a_blocked_file_is_one_line_after_the_findings(
    tmp_path, capsys
):
    """A probe's verdict does not depend on the tolerance: a search to another one reuses the
    kept probes. A folder where the probes' working file goes refuses a search that runs
    probes in one line, after the findings, which the sweep still prints."""
    config = write_study(tmp_path, sweep={"scheme": ["rk4", "euler"], "dt": [0.01, 0.005]})
    out = tmp_path / "out"
    args = ["sweep", str(config), "--out", str(out), "--find-step", "-q"]
    code, first = _sweep_printing(args)
    assert code == 0
    probes = int(re.search(r"(\d+) probes \(0 reused\)", first).group(1))
    code, wider = _sweep_printing([*args, "--step-tolerance", "0.2"])
    reused = int(re.search(r"\d+ probes \((\d+) reused\)", wider).group(1))
    assert code == 0 and 0 < reused <= probes, wider
    path = out / "study" / "search" / "steps.nc"
    path.mkdir(parents=True)
    capsys.readouterr()
    code, printed = _sweep_printing([*args, "--force"])  # every probe run again, to keep
    error = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and "recommended:" in printed
    assert len(error) == 1 and "cannot write the step search there" in error[0], error
    assert "remove what is in its place" in error[0]
