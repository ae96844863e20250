"""The findings (`rbstudy.analysis.findings`) and `rbstudy summary`, on every shipped study.

Every shipped config is swept as a reduced copy (five schemes, three steps, two values of
every other axis, five output intervals), and each finding is recomputed here from the
archive's variables with numpy alone: the recommendation, the coincidences and the verdicts'
numbers. A finding that is not true is as wrong as a wrong error value.
"""

import json
import re

import numpy as np
import pytest
import yaml
from helpers import CONFIGS, copy_node_tables

from rbstudy.analysis.findings import findings, recommendations
from rbstudy.archive.reader import open_archive
from rbstudy.cli import main
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study

SHIPPED = sorted(path.stem for path in CONFIGS.glob("*.yaml"))
# What a reduced copy keeps of each swept axis.
# "all" becomes these: cheap ones, and those with the shipped configs' options (alpha, composition)
_SCHEMES = ["euler", "leapfrog", "rk4", "hht", "splitting"]
_STEPS, _VALUES, _INTERVALS = 3, 2, 5


def _reduced_axis(name, axis):
    if name == "scheme":
        return _SCHEMES if axis == "all" else axis[:3]
    if isinstance(axis, list):
        return axis[: _STEPS if name == "dt" else _VALUES]
    if "halving" in axis:
        return {**axis, "count": _STEPS}
    if "zip" == name:
        return {
            key: {inner: _reduced_axis(inner, value) for inner, value in zipped.items()}
            for key, zipped in axis.items()
        }
    kind, (low, high, _) = next(iter(axis.items()))  # logspace / linspace
    return {kind: [low, high, _VALUES]}


def _reduced(config):
    config["sweep"] = {name: _reduced_axis(name, axis) for name, axis in config.get("sweep", {}).items()}
    config["scene"]["duration"] = _INTERVALS * config["output"]["interval"]
    return config


@pytest.fixture(scope="module")
def archives(tmp_path_factory):
    """Study name -> the archive of its reduced copy."""
    folder = tmp_path_factory.mktemp("shipped")
    copy_node_tables(folder)
    paths = {}
    for name in SHIPPED:
        config = _reduced(yaml.safe_load((CONFIGS / f"{name}.yaml").read_text()))
        path = folder / f"{name}.yaml"
        path.write_text(yaml.safe_dump(config, sort_keys=False))
        paths[name] = run_study(load_study(path), folder / "out", quiet=True).path
    return paths


def _others(ds):
    return [d for d in ds["status"].dims if d not in ("scheme", "dt")]


def _first_axes(ds):
    """The scheme and dt dimensions that are swept, in that order."""
    return [d for d in ("scheme", "dt") if d in ds["status"].dims]


def _pooled_cost(ds):
    """Each case's steps at its run's calibrated seconds per body-step (an archive before
    them: at its scheme's seconds per step pooled over every dt), numpy only, in the
    dimension order of ``status``."""
    dims = ds["status"].dims
    shape = ds["status"].shape

    def spread(name):
        values = ds[name]
        return np.broadcast_to(
            values.transpose(*[d for d in dims if d in values.dims]).values.reshape(
                [shape[k] if d in values.dims else 1 for k, d in enumerate(dims)]
            ),
            shape,
        ).astype(float)

    run_time, steps = spread("run_time"), spread("n_steps")
    if "step_seconds" in ds:
        return steps * spread("step_seconds")
    if "dt" not in dims:
        return run_time
    axis = dims.index("dt")
    return steps * run_time.sum(axis, keepdims=True) / steps.sum(axis, keepdims=True)


def _spread_like_status(ds, name):
    """Variable ``name`` broadcast to the dimension order of ``status`` (0 where absent)."""
    if name not in ds:
        return np.zeros(ds["status"].shape)
    return np.nan_to_num(ds[name].broadcast_like(ds["status"]).transpose(*ds["status"].dims).values)


def _expected_picks(ds):
    """The cheapest accurate (scheme, dt, seconds) per value of the other axes, numpy only;
    of the candidates whose cost ranges (step_seconds_uncertainty) overlap the cheapest's,
    each scheme's cheapest only, the one of least final orientation error."""
    status, accuracy = ds["status"], ds["accuracy"]
    order = _first_axes(ds) + _others(ds)
    good = (accuracy.values == 0) & (status.values == 0)
    good = np.moveaxis(good, [status.dims.index(d) for d in order], range(len(order)))
    cost = np.moveaxis(_pooled_cost(ds), [status.dims.index(d) for d in order], range(len(order)))
    moved = [status.dims.index(d) for d in order]
    spread = np.moveaxis(_spread_like_status(ds, "step_seconds_uncertainty"), moved, range(len(order)))
    error = np.abs(ds["final_orientation_error"].broadcast_like(status).values)
    error = np.moveaxis(np.nan_to_num(error, nan=np.inf), moved, range(len(order)))
    lead = len(_first_axes(ds))
    schemes = np.atleast_1d(ds["scheme"].values)
    dts = np.atleast_1d(ds["dt"].values)
    picks = []
    for index in np.ndindex(*good.shape[lead:]):
        here = (Ellipsis, *index)
        seconds = np.where(good[here], cost[here], np.inf)
        if not np.isfinite(seconds).any():
            picks.append(None)
            continue
        least = np.unravel_index(np.argmin(seconds), seconds.shape)
        # a scheme's own steps compare exactly (they share its cost per step's uncertainty):
        # only its cheapest may tie
        first = _first_axes(ds)
        steps = tuple(k for k, d in enumerate(first) if d != "scheme")
        own_least = seconds.min(axis=steps, keepdims=True)
        overlap = seconds * (1 - spread[here]) <= seconds[least] * (1 + spread[here][least])
        tied = overlap & (seconds == own_least)
        best = np.unravel_index(np.argmin(np.where(tied, error[here], np.inf)), seconds.shape)
        at = dict(zip(_first_axes(ds), best, strict=True))
        picks.append((str(schemes[at.get("scheme", 0)]), float(dts[at.get("dt", 0)]), float(seconds[best])))
    return picks


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_the_recommendation_is_the_cheapest_accurate_case(archives, name):
    ds = open_archive(archives[name])
    expected = _expected_picks(ds)
    found = recommendations(ds)
    assert [
        None if r is None else (r.scheme, r.dt, pytest.approx(r.seconds_per_case, rel=1e-12)) for r in found
    ] == expected
    first = findings(ds)[0]
    if not any(expected):
        assert first.kind == "no_recommendation"
        assert "no scheme and step meet" in first.text
        return
    # the whole study's answer: every case of the other axes accurate, least mean cost, the
    # candidates whose cost ranges overlap its one answer, of least worst error
    axes = _first_axes(ds)
    others = _others(ds)
    ok = ((ds["accuracy"] == 0) & (ds["status"] == 0)).all(others).transpose(*axes).values
    pooled = ds["status"].copy(data=_pooled_cost(ds))
    mean = pooled.mean(others).transpose(*axes).values
    spread = ds["status"].copy(data=_spread_like_status(ds, "step_seconds_uncertainty"))
    spread = spread.max(others).transpose(*axes).values
    worst = abs(ds["final_orientation_error"]).max(others).transpose(*axes).values
    if ok.any():
        costs = np.where(ok, mean, np.inf)
        least = np.unravel_index(np.argmin(costs), ok.shape)
        own_least = costs.min(axis=tuple(k for k, d in enumerate(axes) if d != "scheme"), keepdims=True)
        tied = (costs * (1 - spread) <= costs[least] * (1 + spread[least])) & (costs == own_least)
        at = np.unravel_index(np.argmin(np.where(tied, np.nan_to_num(worst, nan=np.inf), np.inf)), ok.shape)
        pick = dict(zip(axes, at, strict=True))
        scheme = str(np.atleast_1d(ds["scheme"].values)[pick.get("scheme", 0)])
        assert first.kind == "recommendation"
        assert first.cases[0]["scheme"] == scheme
        assert first.numbers["dt_s"] == float(np.atleast_1d(ds["dt"].values)[pick.get("dt", 0)])
        assert len(first.numbers["equal_cost"]) == tied.sum() - 1
        assert first.text.startswith(f"recommended: {scheme}" + (" at dt=" if tied.sum() == 1 else ""))


def _agree(a, b):
    finite = np.isfinite(a) & np.isfinite(b)
    if not finite.any() or (np.isnan(a) != np.isnan(b)).any():
        return False
    return bool(
        np.all(np.abs(a[finite] - b[finite]) <= 5e-4 * np.maximum(np.abs(a[finite]), np.abs(b[finite])))
    )


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_coincidences_are_exactly_the_schemes_agreeing_to_three_digits(archives, name):
    ds = open_archive(archives[name])
    found = {tuple(case["scheme"] for case in f.cases) for f in findings(ds) if f.kind == "coincidence"}
    expected = set()
    if "final_orientation_error" in ds and "scheme" in ds["status"].dims:
        errors = ds["final_orientation_error"].transpose("scheme", ...).values
        schemes = [str(s) for s in ds["scheme"].values]
        expected = {
            (schemes[i], schemes[j])
            for i in range(len(schemes))
            for j in range(i + 1, len(schemes))
            if _agree(np.abs(errors[i]), np.abs(errors[j]))
        }
    assert found == expected


@pytest.mark.slow
@pytest.mark.parametrize(("relative", "coincide"), [(2e-4, True), (2e-3, False)])
def test_a_scheme_within_three_digits_of_another_is_named_as_coinciding(archives, relative, coincide):
    """The shipped studies' reduced copies have no coincidence: here leapfrog's errors are
    made euler's times (1 + relative), within and past 3 digits, in every case."""
    ds = open_archive(archives["abaqus_top"])
    errors = ds["final_orientation_error"]
    errors.loc[{"scheme": "leapfrog"}] = errors.sel(scheme="euler") * (1 + relative)
    found = [f for f in findings(ds) if f.kind == "coincidence"]
    assert [tuple(case["scheme"] for case in f.cases) for f in found] == (
        [("euler", "leapfrog")] if coincide else []
    )
    if coincide:
        assert found[0].numbers["largest_relative_difference"] == pytest.approx(relative / (1 + relative))
        assert found[0].text == (
            f"leapfrog gives euler's errors to 3 digits in all "
            f"{errors.sel(scheme='euler').size} cases (their lines overlap)"
        )


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_each_verdict_states_the_archives_failures_and_energy(archives, name):
    ds = open_archive(archives[name])
    verdicts = {f.cases[0]["scheme"]: f for f in findings(ds) if f.kind == "verdict"}
    for scheme in np.atleast_1d(ds["scheme"].values):
        scheme = str(scheme)
        pick = {"scheme": scheme} if "scheme" in ds["status"].dims else {}
        status = ds["status"].sel(pick).values
        found = verdicts[scheme]
        assert found.text.startswith(scheme)
        failed = int((status != 0).sum())
        assert ("; fails " in found.text) == (failed > 0)
        assert found.numbers.get("failed_cases", 0) == failed
        radioss = int((ds["radioss_dt_limit"].sel(pick).values == 1).sum())
        assert found.numbers.get("past_radioss_limit", 0) == radioss
        if failed:
            load = (ds["dt"] * ds["initial_spin"]).broadcast_like(ds["status"]).sel(pick).values
            real = ds["physical_body"].broadcast_like(ds["status"]).sel(pick).values == 1
            first = load[(status != 0) & real]
            assert (
                found.numbers["first_failed_dt_w0"] == pytest.approx(first.min())
                if first.size
                else np.isnan(found.numbers["first_failed_dt_w0"])
            )
        measured = [
            np.isfinite(ds[name].sel(pick).values[status == 0]).any()
            for name in ("max_energy_error", "max_momentum_magnitude_error")
            if name in ds
        ]
        assert ("; keeps " in found.text) == any(measured)  # none stored under a moment
        kept = (
            np.nanmax(ds["max_energy_error"].sel(pick).values[status == 0], initial=0) < 1e-10
            if "max_energy_error" in ds
            else True
        )
        if "energy_error" in ds and not kept:
            end = ds["energy_error"].sel(pick).isel(time=-1).values[status == 0]
            end = end[np.abs(end) >= 1e-10]  # NaN and round-off left out
            if end.size:
                largest = end[np.argmax(np.abs(end))] / float(ds["time"][-1])
                assert found.numbers["energy_rate_per_s"] == pytest.approx(largest)
                word = "gains" if np.all(end > 0) else "loses" if np.all(end < 0) else "gains or loses"
                assert f"; {word} energy, up to " in found.text


@pytest.mark.slow
def test_the_study_question_states_the_order_per_value_of_the_swept_option(archives):
    ds = open_archive(archives["hht_damping"])
    question = next(f for f in findings(ds) if f.kind == "question")
    assert question.text.startswith("hht over alpha 0, -0.05: order ")
    assert len(question.numbers["order"]) == 2  # one per alpha, not a folded range


@pytest.mark.slow
def test_summary_json_keeps_its_contract(archives, capsys):
    assert main(["summary", str(archives["abaqus_top"]), "--format", "json"]) == 0
    document = json.loads(capsys.readouterr().out)
    assert set(document) == {"study", "findings", "recommended", "schemes"}
    assert document["study"] == "abaqus_top"
    assert all(set(f) == {"kind", "text", "numbers", "cases"} for f in document["findings"])
    ds = open_archive(archives["abaqus_top"])
    expected = _expected_picks(ds)
    ratios = ds["inertia_ratio"].values
    assert [
        (r["scheme"], r["dt"], pytest.approx(r["seconds_per_case"], rel=1e-12), r["inertia_ratio"])
        for r in document["recommended"]
    ] == [(*pick, float(ratio)) for pick, ratio in zip(expected, ratios, strict=True)]
    for record in document["recommended"]:
        case = ds["final_orientation_error"].sel(
            scheme=record["scheme"], dt=record["dt"], inertia_ratio=record["inertia_ratio"]
        )
        assert record["error"] == float(abs(case))
    assert [row["scheme"] for row in document["schemes"]] == _SCHEMES
    assert {"error_rad", "ns_per_body_step", "accurate_up_to_dt_w0"} <= set(document["schemes"][0])


@pytest.mark.slow
def test_no_recommendation_when_no_case_meets_the_bound(tmp_path, capsys):
    config = _reduced(yaml.safe_load((CONFIGS / "abaqus_top.yaml").read_text()))
    config["sweep"]["inertia_ratio"] = [2.0]
    config["output"]["accuracy_bound"] = 1e-12  # below every scheme's error at these steps
    path = tmp_path / "abaqus_top.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    archive = run_study(load_study(path), tmp_path / "out", quiet=True).path
    assert main(["summary", str(archive)]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == "no scheme and step meet the accuracy bound 1e-12 in any case"
    assert "recommended" not in out
    assert main(["summary", str(archive), "--format", "json"]) == 0
    assert all(r["scheme"] is None for r in json.loads(capsys.readouterr().out)["recommended"])


def test_summary_refuses_a_file_that_is_no_archive_in_one_line(tmp_path, capsys):
    text = tmp_path / "notes.nc"
    text.write_text("not netCDF\n")
    assert main(["summary", str(text), "--format", "json"]) == 1
    captured = capsys.readouterr()
    assert captured.out == ""
    assert captured.err == (
        f"rbstudy: error: {text}: not an rbstudy archive: not a netCDF "
        "file (a text file); give the <study>.nc (or <study>.zarr) written by rbstudy sweep\n"
    )


@pytest.mark.slow
@pytest.mark.parametrize("name", SHIPPED)
def test_each_stated_order_is_the_slope_of_the_errors_over_dt(archives, name):
    """A verdict's order range holds the least-squares slope of log error over log dt, fitted
    here with numpy alone, of every value of the other axes whose errors at the study's three
    steps lie in the asymptotic window (above round-off, below 0.1 rad) on a straight line."""
    ds = open_archive(archives[name])
    if "dt" not in ds["status"].dims or ds.sizes["dt"] < 3:
        pytest.skip(f"{name} sweeps no dt: no order to state")
    checked = 0
    for found in findings(ds):
        if (
            found.kind != "verdict" or "order_low" not in found.numbers or found.text.split(":")[0].count(",")
        ):  # a composition row: its own slice
            continue
        error = ds["final_orientation_error"]
        if "scheme" in error.dims:
            error = error.sel(scheme=found.cases[0]["scheme"])
        error = error.transpose("dt", ...).values.reshape(ds.sizes["dt"], -1)
        dts = np.log10(np.atleast_1d(ds["dt"].values))
        for column in error.T:
            local = np.diff(np.log10(column)) / np.diff(dts) if np.all(column > 0) else None
            # a straight line: its two local slopes agree (else the table fits no range there,
            # and says so with its (k/n))
            if np.all((column > 1e-10) & (column < 0.1)) and np.ptp(local) < 0.3:
                slope = np.polyfit(dts, np.log10(column), 1)[0]
                assert found.numbers["order_low"] - 0.1 <= slope <= found.numbers["order_high"] + 0.1, (
                    found.text,
                    slope,
                )
                checked += 1
    if not checked:
        pytest.skip(f"{name}: no value of the other axes has all its errors in the window")


def test_the_findings_read_their_time_series_reduced_slab_by_slab(tmp_path, monkeypatch):
    """`FINDINGS_REDUCED`: momentum_error's largest sample (NaN where any sample is) and
    energy_error's last, read a few cases at a time, are what the whole series give, and the
    energy rates the findings state from them are the same numbers."""
    import xarray as xr

    from rbstudy.analysis.findings import FINDINGS_REDUCED, energy_rates
    from rbstudy.archive import load

    rng = np.random.default_rng(3)
    series = rng.random((7, 5, 11))
    series[2, 3, 6:] = np.nan  # a blow-up: NaN from its sixth sample on
    series[4, 0, 4] = 10.0  # a largest sample mid-run
    dims = ("spin", "tilt", "time")
    coords = {"spin": np.arange(7.0), "tilt": np.arange(5.0), "time": np.linspace(0.0, 2.0, 11)}
    whole = xr.Dataset(
        {
            "momentum_error": (dims, series),
            "energy_error": (dims, -series),
            "status": (dims[:2], np.zeros((7, 5))),
        },
        coords=coords,
    )
    path = tmp_path / "a.nc"
    whole.to_netcdf(path)
    monkeypatch.setattr(load, "_REDUCTION_SLAB_BYTES", 2 * 5 * 11 * 8)  # two spins a slab: four slabs
    reduced = load.open_results(path, ["momentum_error", "energy_error", "status"], FINDINGS_REDUCED)
    assert reduced.momentum_error.dims == ("spin", "tilt") and "time" not in reduced.dims
    expected = series.max(axis=-1)
    assert np.isnan(reduced.momentum_error.values[2, 3]) and reduced.momentum_error.values[4, 0] == 10.0
    assert np.array_equal(reduced.momentum_error.values, expected, equal_nan=True)
    assert np.array_equal(reduced.energy_error.values, -series[..., -1], equal_nan=True)
    assert float(reduced.energy_error["time"]) == 2.0
    assert np.array_equal(energy_rates(reduced).values, energy_rates(whole).values, equal_nan=True)
    assert np.array_equal(reduced.status.values, whole.status.values)


@pytest.fixture(scope="module")
def stiff(tmp_path_factory):
    """stiff_inertia's archive at its full duration and steps, for three schemes and three
    ratios: the thin rod, the sphere and the unphysical disk of I3/I1 = 1e4."""
    folder = tmp_path_factory.mktemp("stiff")
    config = yaml.safe_load((CONFIGS / "stiff_inertia.yaml").read_text())
    config["sweep"]["scheme"] = ["euler", "rk4", "exact_split"]
    config["sweep"]["inertia_ratio"] = [1e-4, 1.0, 1e4]
    path = folder / "stiff_inertia.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return config, open_archive(run_study(load_study(path), folder / "out", quiet=True).path)


@pytest.mark.slow
def test_no_order_is_fitted_through_errors_at_round_off(stiff):
    """exact_split is exact on a free body: its errors are round-off, which grows with the
    angle the motion sweeps (the disk's precession |L|/I1 = 6.3e4 rad/s over 1 s: 5e-12 to
    1.4e-11 rad, fitted as "order 0.60" before). Recomputed here: every one of its errors is
    within 100 ulps of |w0| T I3/I1 (the largest moment over the smallest), and no order is
    stated; euler's and rk4's orders, fitted here with numpy on the rod, stay 1 and 4."""
    from rbstudy.analysis.summary import format_table, scheme_rows

    config, ds = stiff
    spin = np.linalg.norm(config["scene"]["initial"]["angular_velocity"]["body"])
    duration = config["scene"]["duration"]
    errors = abs(ds["final_orientation_error"]).transpose("scheme", "inertia_ratio", "dt")
    ratios = ds["inertia_ratio"].values
    swept = spin * duration * np.maximum(ratios, 1.0 / ratios)
    exact = errors.sel(scheme="exact_split").values
    assert np.all(exact <= 100 * np.finfo(float).eps * swept[:, None])
    assert exact[-1].max() > 1e-13  # above the old constant floor: it was fitted through
    rows = {row["scheme"]: row for row in scheme_rows(ds)}
    assert rows["exact_split"]["order"] is None
    verdict = next(f for f in findings(ds, list(rows.values())) if f.text.startswith("exact_split:"))
    assert verdict.text.startswith("exact_split: at the floor (round-off);")
    assert "order_low" not in verdict.numbers
    line = next(
        line for line in format_table(list(rows.values())).splitlines() if line.startswith("exact_split")
    )
    assert line.split()[2] == "round-off"
    dts = np.log(ds["dt"].values)
    for scheme, nominal in (("euler", 1), ("rk4", 4)):
        slope = np.polyfit(dts, np.log(errors.sel(scheme=scheme, inertia_ratio=1e-4).values), 1)[0]
        assert slope == pytest.approx(nominal, abs=0.15)
        low, high = rows[scheme]["order"]
        assert low - 0.1 <= slope <= high + 0.1 and abs(low - nominal) < 0.25 and abs(high - nominal) < 0.25


@pytest.mark.slow
def test_kept_drifts_lie_at_their_round_off_floor(stiff):
    """exact_split keeps energy and |L|: its drifts, 1e-16 to 1e-13 after hundreds of steps,
    are round-off at every inertia ratio (above the constant 1e-15 floor of the energy they
    were fitted as "no asymptotic range"), each within `ROUND_OFF_ULPS` a step, recomputed."""
    from rbstudy.analysis.summary import ROUND_OFF_ULPS, at_floor, error_measure, round_off_of

    _, ds = stiff
    for key in ("energy", "momentum_magnitude"):
        errors = error_measure(ds, key)
        floors = round_off_of(ds, key, errors)
        kept = errors.sel(scheme="exact_split").transpose("inertia_ratio", "dt")
        steps = ds["n_steps"].broadcast_like(errors).sel(scheme="exact_split").transpose(*kept.dims)
        assert np.all(kept.values <= ROUND_OFF_ULPS * np.finfo(float).eps * steps.values)
        assert kept.values.max() > 1e-15
        below = floors.sel(scheme="exact_split").transpose(*kept.dims).values
        assert [at_floor(row, floor) for row, floor in zip(kept.values, below, strict=True)] == [
            "round-off"
        ] * len(kept)


def _recovered(text, values):
    """The positions along an axis of swept value texts ``values`` that a list of them as the
    findings write it (after the axis's name) names: whole, ``a to b, 17 values, every value
    swept``, ``all 17 values but x, y``, or runs ``a to b, c and d, e (k of the n ...)``."""
    if text.endswith(", every value swept"):
        return set(range(len(values)))
    if text.startswith("all "):
        return set(range(len(values))) - {values.index(v) for v in text.split(" but ", 1)[1].split(", ")}
    held = set()
    for item in text.split(" (", 1)[0].split(", "):
        if " to " in item:
            low, high = item.split(" to ")
            held |= set(range(values.index(low), values.index(high) + 1))
        else:
            held |= {values.index(v) for v in item.split(" and ")}
    return held


def test_a_list_of_values_is_told_without_losing_one():
    """Every subset of an axis of 17 values (all of them, all but a few, a few, runs with
    gaps), as `_where` tells it, names exactly its values."""
    from rbstudy.analysis.places import axis_text as _axis_text

    ratios = list(np.logspace(-4, 4, 17))
    axis = {"inertia_ratio": ratios}
    texts = [_axis_text("inertia_ratio", axis, [k]).split(" ", 1)[1] for k in range(17)]
    rng = np.random.default_rng(41)
    subsets = [list(range(17)), [0, 1, 2, 3, 4, 5, 6, 7, 9, 10], [k for k in range(17) if k != 8], [3]]
    subsets += [
        sorted(rng.choice(17, size, replace=False).tolist()) for size in range(1, 17) for _ in range(5)
    ]
    for held in subsets:
        text = _axis_text("inertia_ratio", axis, held)
        assert text.startswith("inertia_ratio ") and "..." not in text, text
        assert _recovered(text.split(" ", 1)[1], texts) == set(held), text
    assert _axis_text("inertia_ratio", axis, list(range(17))) == (
        "inertia_ratio 0.0001 to 10000, 17 values, every value swept"
    )
    assert _axis_text("inertia_ratio", axis, [k for k in range(17) if k != 8]) == (
        "inertia_ratio all 17 values but 1"
    )


@pytest.mark.slow
def test_each_recommendation_names_every_value_it_holds_for(tmp_path):
    """stiff_inertia's 17 ratios: the values each "cheapest at" finding names are exactly the
    ratios whose cheapest accurate case (recomputed with numpy) is its answer. rk4 alone: its
    cheapest case is its largest accurate dt, which the stiffer disks shrink, whatever the
    timings (dt = 0.01 s up to I3/I1 = 31.6, then smaller, then none)."""
    config = yaml.safe_load((CONFIGS / "stiff_inertia.yaml").read_text())
    config["sweep"]["scheme"] = ["rk4"]
    path = tmp_path / "stiff_inertia.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    ds = open_archive(run_study(load_study(path), tmp_path / "out", quiet=True).path)
    texts = [
        f"{float(f'{v:.3g}'):.0f}" if v >= 1e3 else f"{v:.3g}" for v in ds["inertia_ratio"].values.tolist()
    ]
    expected = {}
    for k, pick in enumerate(_expected_picks(ds)):
        expected.setdefault(None if pick is None else pick[:2], set()).add(k)
    found = [
        f for f in findings(ds) if f.text.startswith(("cheapest at ", "no scheme and step meet the bound"))
    ]
    assert len(found) == len(expected) >= 3
    for finding in found:
        where = finding.text.split(" at ", 1)[1].split(": ", 1)[0]
        assert where.startswith("inertia_ratio ") and "..." not in where, finding.text
        held = _recovered(where.split(" ", 1)[1], texts)
        answer = (
            None
            if finding.kind == "no_recommendation"
            else (
                finding.cases[0]["scheme"],
                finding.cases[0]["dt"],
            )
        )
        assert held == expected[answer], finding.text


def _abaqus_top_variant(folder, name, **changes):
    """A copy of the default study with ``changes`` (dotted key -> value) swept into
    ``folder/name``; its archive's path."""
    config = yaml.safe_load((CONFIGS / "abaqus_top.yaml").read_text())
    config["run"] = {"scheme": "rk4", "dt": 0.01}  # without hht's alpha: hht is not swept here
    for key, value in changes.items():
        *path, last = key.split(".")
        mapping = config
        for part in path:
            mapping = mapping[part]
        mapping[last] = value
    target = folder / name
    target.mkdir()
    path = target / "abaqus_top.yaml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return run_study(load_study(path), target / "out", quiet=True).path


@pytest.fixture(scope="module")
def cost_archives(tmp_path_factory):
    """Two small copies of the default study: its own dt grid (the answer at its largest
    dt), and a grid up to dt = 0.32 s, where no scheme meets the bound."""
    folder = tmp_path_factory.mktemp("cost")
    schemes = ["euler", "leapfrog", "midpoint", "rk4", "rkmk4"]
    return {
        "capped": _abaqus_top_variant(
            folder,
            "capped",
            **{
                "sweep.scheme": schemes,
                "sweep.dt": {"halving": 0.01, "count": 3},
                "sweep.inertia_ratio": [0.5, 2.0],
            },
        ),
        "wide": _abaqus_top_variant(
            folder,
            "wide",
            **{
                "sweep.scheme": ["euler", "midpoint", "rk4"],
                "sweep.dt": [0.01, 0.02, 0.04, 0.08, 0.16, 0.32],
                "sweep.inertia_ratio": [0.5, 2.0],
                "output.interval": 0.32,
                "scene.duration": 2.56,
            },
        ),
    }


def _with_costs(ds, seconds, uncertainty):
    """``ds`` with each scheme's calibrated seconds per body-step set (scheme -> s) and one
    relative ``uncertainty``."""
    ds = ds.copy()
    values = np.array([seconds[str(name)] for name in ds["scheme"].values])
    ds["step_seconds"] = ds["step_seconds"].copy(
        data=np.broadcast_to(
            values.reshape([-1 if d == "scheme" else 1 for d in ds["step_seconds"].dims]),
            ds["step_seconds"].shape,
        ).copy()
    )
    ds["step_seconds_uncertainty"] = ds["step_seconds_uncertainty"].copy(
        data=np.full(ds["step_seconds_uncertainty"].shape, uncertainty)
    )
    return ds


def _mean_cost(ds, scheme, dt):
    """The mean over the other axes of n_steps x step_seconds of (scheme, dt), numpy only."""
    case = ds.sel(scheme=scheme, dt=dt)
    return float(np.mean(case["n_steps"].values * case["step_seconds"].values))


def _worst_error(ds, scheme, dt):
    return float(np.max(np.abs(ds["final_orientation_error"].sel(scheme=scheme, dt=dt).values)))


@pytest.mark.slow
def test_costs_within_the_calibrations_uncertainty_are_one_answer_said_as_one(cost_archives):
    """rk4 and rkmk4 at 1% apart with 2% uncertainty: a tie, named as one, represented by
    the smaller worst error; at 5% apart the cheaper alone. Recomputed from the archive."""
    ds = open_archive(cost_archives["capped"])
    # euler, leapfrog dearer here: at dt = 0.01 s they meet the bound too, at its edge
    costs = {"euler": 5e-7, "leapfrog": 5e-7, "midpoint": 3e-7, "rk4": 2e-7}
    tie = _with_costs(ds, {**costs, "rkmk4": 2.02e-7}, 0.02)
    first, second = sorted(["rk4", "rkmk4"], key=lambda scheme: _worst_error(ds, scheme, 0.01))
    found = findings(tie)[0]
    assert found.text.startswith(
        f"recommended: {first} or {second}, equal cost, at dt=0.01 s, "
        f"{_mean_cost(tie, first, 0.01):.2g} s a case, error {_worst_error(ds, first, 0.01):.3g} rad "
        "(bound 0.01, every case)"
    )
    assert found.numbers["equal_cost"] == [{"scheme": second, "dt_s": 0.01}]
    assert found.cases == ({"scheme": first, "dt": 0.01},)
    apart = findings(_with_costs(ds, {**costs, "rkmk4": 2.1e-7}, 0.02))[0]
    assert apart.text.startswith(
        f"recommended: rk4 at dt=0.01 s, {_mean_cost(tie, 'rk4', 0.01):.2g} s a case"
    )
    assert apart.numbers["equal_cost"] == []
    # per value of the other axes too: each value's line names the tie
    for pick in recommendations(tie):
        assert {pick.scheme, *(scheme for scheme, _ in pick.tied)} == {"rk4", "rkmk4"}


def test_a_wide_uncertainty_ties_schemes_never_a_scheme_with_its_own_smaller_step(cost_archives):
    """Costs measured on a busy machine are uncertain to 50%: schemes whose costs overlap are
    one answer, but a scheme's candidates share its cost per step, so its step and its half
    (exactly twice the cost) are never a tie (they had been, making the answer a list of
    every scheme at two steps). Recomputed from the archive."""
    ds = open_archive(cost_archives["capped"])
    costs = {"euler": 5e-7, "leapfrog": 5e-7, "midpoint": 3e-7, "rk4": 2e-7, "rkmk4": 9e-7}
    wide = _with_costs(ds, costs, 0.5)
    cheapest = min(costs, key=costs.get)
    accurate = (wide["accuracy"] == 0) & (wide["status"] == 0)
    meets = accurate.all("inertia_ratio")
    # overlapping ranges with rk4's at dt = 0.01 s, each scheme at its own cheapest step
    expected = []
    for scheme, per_step in costs.items():
        steps = [dt for dt in wide["dt"].values if bool(meets.sel(scheme=scheme, dt=dt))]
        if scheme == cheapest or not steps:
            continue
        dt = max(steps)
        cost = per_step * round(2.0 / dt)
        if cost * 0.5 <= costs[cheapest] * round(2.0 / 0.01) * 1.5:
            expected.append({"scheme": scheme, "dt_s": float(dt)})
    found = findings(wide)[0]
    said = found.numbers["equal_cost"] + [{"scheme": found.cases[0]["scheme"], "dt_s": found.cases[0]["dt"]}]
    assert sorted(said, key=str) == sorted([*expected, {"scheme": cheapest, "dt_s": 0.01}], key=str)
    assert len({entry["scheme"] for entry in said}) == len(said), "a scheme named at two steps"
    assert any(entry["dt_s"] == 0.01 and entry["scheme"] == "midpoint" for entry in said)
    # why so many: said where the answer is, and only where the costs were measured so
    assert "measured while other programs kept the machine busy, uncertain to 50%" in found.text
    quiet = findings(_with_costs(ds, costs, 0.1))[0]
    assert "busy" not in quiet.text


def test_a_tie_whose_representative_changes_between_values_is_one_answer(cost_archives):
    """euler and leapfrog of equal cost, the smaller error euler's at one inertia ratio and
    leapfrog's at the other: one answer, told once ("euler or leapfrog" at one value and
    "leapfrog or euler" at the next had been two lines, and a third for the study), named by
    the one with the smaller worst error over both values, recomputed here."""
    ds = _with_costs(
        open_archive(cost_archives["capped"]),
        {"euler": 1e-7, "leapfrog": 1e-7, "midpoint": 1e-6, "rk4": 1e-6, "rkmk4": 1e-6},
        0.05,
    )
    errors, accuracy = ds["final_orientation_error"].copy(), ds["accuracy"].copy()
    chosen = {("euler", 0.5): 1e-3, ("leapfrog", 0.5): 2e-3, ("euler", 2.0): 3e-3, ("leapfrog", 2.0): 1e-3}
    for (scheme, ratio), error in chosen.items():
        at = {"scheme": scheme, "dt": 0.01, "inertia_ratio": ratio}
        errors.loc[at], accuracy.loc[at] = error, 0
    ds["final_orientation_error"], ds["accuracy"] = errors, accuracy
    reps = {ratio: min(("euler", "leapfrog"), key=lambda s: chosen[s, ratio]) for ratio in (0.5, 2.0)}
    assert reps == {0.5: "euler", 2.0: "leapfrog"}  # the representative changes between values
    worst = {s: max(chosen[s, r] for r in (0.5, 2.0)) for s in ("euler", "leapfrog")}
    first, second = sorted(worst, key=worst.get)
    said = [f for f in findings(ds) if f.kind == "recommendation"]
    assert len(said) == 1, [f.text for f in said]
    assert said[0].text.startswith(f"recommended: {first} or {second}, equal cost, at dt=0.01 s")
    assert f"error {worst[first]:.3g} rad" in said[0].text


def test_the_tables_step_cost_is_the_calibrated_one_that_timing_noise_leaves_alone(cost_archives):
    """The table's "ns per step" is the cost the findings rank by: each scheme's calibrated
    seconds a step, recomputed from the archive; the run's measured times, scrambled here as
    timing noise scrambles them between runs, move nothing (they moved the column before).
    The archive is read as the table's readers read it (`SUMMARY_VARIABLES`): a reading
    without step_seconds would give run_time's column."""
    from rbstudy.analysis.summary import SUMMARY_VARIABLES, scheme_rows

    whole = open_archive(cost_archives["capped"])
    calibrated = {
        str(name): float(np.median(whole["step_seconds"].sel(scheme=name).values)) * 1e9
        for name in whole["scheme"].values
    }
    ds = open_archive(cost_archives["capped"], SUMMARY_VARIABLES, verify=False)
    noisy = ds.copy()
    rng = np.random.default_rng(0)
    noisy["run_time"] = ds["run_time"] * rng.uniform(0.5, 2.0, ds["run_time"].shape)
    for dataset in (ds, noisy):
        rows = {row["scheme"]: row["ns_per_step"] for row in scheme_rows(dataset)}
        assert rows == pytest.approx(calibrated)


@pytest.mark.parametrize(("error", "edge"), [(0.00995, True), (0.0098, False)])
def test_an_answer_at_the_bounds_edge_is_marked(cost_archives, error, edge):
    ds = _with_costs(
        open_archive(cost_archives["capped"]),
        {"euler": 5e-7, "leapfrog": 5e-7, "midpoint": 3e-7, "rk4": 2e-7, "rkmk4": 4e-7},
        0.02,
    )
    values = ds["final_orientation_error"].copy()
    values.loc[{"scheme": "rk4", "dt": 0.01}] = error
    ds["final_orientation_error"] = values
    bound = ds.attrs["accuracy_bound"]
    assert bound == 0.01
    found = findings(ds)[0]
    assert found.cases == ({"scheme": "rk4", "dt": 0.01},)
    assert found.numbers["at_bound_edge"] is edge
    if edge:
        assert f"error {error:.3g} rad: within 1% of the bound 0.01 (every case)" in found.text
    else:
        assert f"error {error:.3g} rad (bound 0.01, every case)" in found.text
        assert "within" not in found.text


def test_an_answer_at_the_largest_swept_dt_says_it_is_capped_by_the_grid(cost_archives):
    for name, capped in (("capped", True), ("wide", False)):
        ds = open_archive(cost_archives[name])
        largest = float(ds["dt"].max())
        answers = [f for f in findings(ds) if f.kind == "recommendation"]
        assert answers
        for found in answers:
            at_largest = found.numbers["dt_s"] == largest
            assert at_largest is capped  # the wide grid's 0.32 s meets the bound nowhere
            assert found.numbers["capped_by_grid"] is at_largest
            assert ("capped by the grid" in found.text) is at_largest
        if capped:
            assert (
                "capped by the grid: dt=0.01 s is the largest swept, a larger one may also meet the bound"
                in (answers[0].text)
            )


def test_an_archive_without_calibrated_costs_says_its_cost_is_run_time(cost_archives):
    ds = open_archive(cost_archives["capped"]).drop_vars(["step_seconds", "step_seconds_uncertainty"])
    found = findings(ds)[0]
    assert found.kind == "recommendation"
    assert found.text.endswith(
        "; costed by run_time, which moves between runs (sweep again to store calibrated step costs)"
    )
    assert found.numbers["cost_model"] == "run_time"


def test_the_findings_compute_the_per_scheme_table_once(cost_archives, monkeypatch):
    """The orders the findings tell along inertia_ratio come from each scheme's fits at each
    value of the other axes, made once: the per-scheme table is computed once, not once more
    per value (the default study computed it five times, 1.36 s of its 1.5 s of findings),
    and each value's orders are those of a table of that value's cases alone."""
    from rbstudy.analysis import summary

    ds = open_archive(cost_archives["capped"])
    tables = []
    table = summary._scheme_rows
    monkeypatch.setattr(summary, "_scheme_rows", lambda ds: tables.append(ds.sizes) or table(ds))
    findings(ds)
    assert len(tables) == 1
    monkeypatch.undo()
    from rbstudy.analysis.summary import orders_along, scheme_rows

    along = orders_along(ds, "inertia_ratio")
    for k in range(ds.sizes["inertia_ratio"]):
        for row in scheme_rows(ds.isel(inertia_ratio=k)):
            fields = along[row["scheme"]][k]
            assert fields == {key: row[key] for key in fields}
            assert row["fits"] and row["tries"] == 1  # one value of the other axes: fitted


@pytest.mark.slow
def test_ten_runs_of_the_default_study_give_one_recommendation(tmp_path, capsys):
    """The default study swept ten times over (``--force``), as a user would: the same
    answer each time, its cost from the calibrated step costs, not the runs' timers."""
    said = []
    for _ in range(10):
        assert main(["sweep", str(CONFIGS / "abaqus_top.yaml"), "--out", str(tmp_path), "--force"]) == 0
        # each finding one text (a wrapped one's lines start with two spaces)
        texts = re.sub(r"\n  ", " ", capsys.readouterr().out).splitlines()
        answers = [text for text in texts if text.startswith(("recommended: ", "cheapest at "))]
        assert answers[0].startswith("recommended: ")
        said.append([re.sub(r", [0-9.e+-]+ s a case", "", text) for text in answers])  # without the cost
    assert all(answers == said[0] for answers in said), said
