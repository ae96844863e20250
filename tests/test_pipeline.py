"""The sweep pipeline end to end: the default study's dataset contract and CF compliance,
agreement with direct runs, resume after kill -9, --force, changed configs, the lock, and the
same numbers on a two-worker LocalCluster."""

import dataclasses
import importlib.metadata
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import types

import numpy as np
import pytest
import xarray as xr
import yaml
from helpers import (
    CONFIGS,
    EXACT_FLOW_TOLERANCE,
    EXACT_FOR_FREE_BODIES,
    abaqus_mapping,
    same_numbers,
    sweep_until_a_batch_is_kept,
    write_study,
)

from rbstudy.analysis.plots import all_figures
from rbstudy.analysis.summary import format_table, scheme_rows
from rbstudy.archive import lock, writer
from rbstudy.archive.load import open_results
from rbstudy.archive.lock import study_lock
from rbstudy.archive.variables import LONG_NAME_MAX, VERDICTS
from rbstudy.cli import main
from rbstudy.errors import RbstudyError
from rbstudy.numerics.driver import HALT_FLAG
from rbstudy.physics import references
from rbstudy.physics.analytic import INTEGRATED, REFERENCE_KINDS
from rbstudy.physics.references import composed_steps
from rbstudy.physics.scenes import Body
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline import cluster, execute
from rbstudy.pipeline import estimate as estimate_module
from rbstudy.pipeline.calibration import calibration_path, machine_key, reference_cost, step_cost
from rbstudy.pipeline.cluster import Where
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.estimate import estimate
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import SCHEMES, dop853, get_scheme, scheme_groups


@pytest.fixture(scope="module")
def abaqus_results(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    run_study(load_study(CONFIGS / "abaqus_top.yaml"), root, quiet=True)
    return root / "abaqus_top" / "abaqus_top.nc"


@pytest.mark.slow
def test_default_study_follows_the_dataset_contract(abaqus_results):
    ds = open_results(abaqus_results)
    fixed = scheme_groups()["builtin"]  # what `scheme: all` sweeps: not the published steps
    assert list(ds.sizes) == ["scheme", "dt", "inertia_ratio", "time", "axis", "component", "node"]
    assert list(ds.scheme.values) == fixed
    assert np.allclose(ds.dt, [0.01 / 2**k for k in range(5, -1, -1)])  # ascending
    assert list(ds.sel(dt=slice(0.001, 0.006)).dt.values) == [0.00125, 0.0025, 0.005]
    assert list(ds.inertia_ratio.values) == [0.1, 0.5, 1.5, 2.0]
    assert ds.omega_body.dims == ("scheme", "dt", "inertia_ratio", "time", "axis")
    assert ds.node_displacement.dims[-2:] == ("node", "axis")
    for name in (
        "omega_space",
        "quaternion",
        "energy_error",
        "momentum_error",
        "orientation_error",
        "omega_error",
        "node_error",
        "precession_frequency",
        "precession_frequency_exact",
        "precession_frequency_error",
        "status",
        "failure_time",
        "n_steps",
        "iterations",
        "run_time",
        "max_energy_error",
        "max_momentum_magnitude_error",
        "max_momentum_error",
        "final_orientation_error",
        "accuracy",
    ):
        assert name in ds, name
    assert "position" not in ds  # the top does not translate: absent, not NaN
    assert ds.status.attrs["flag_meanings"] == "ok unstable not_converged"
    assert (ds.status == 0).all() and (ds.run_time > 0).all()
    assert (ds.physical_body == 1).all()  # I3/I1 <= 2 keeps every body physical
    # the benchmark case itself: 200 increments, one Newton iteration each
    bench = ds.sel(scheme="hht", dt=0.01, inertia_ratio=2.0)
    assert int(bench.n_steps) == 200 and int(bench.iterations) == 200
    assert math.isclose(float(bench.precession_frequency_exact), 2 * math.pi)
    assert abs(float(bench.precession_frequency_error)) < 3e-3
    # what belongs to the scene lies along the scene's axis only, not scheme or dt
    assert ds.inertia.dims == ("inertia_ratio", "axis")
    assert ds.node_offset.dims == ("inertia_ratio", "node", "axis")
    for name in ("initial_spin", "physical_body", "reference"):
        assert ds[name].dims == ("inertia_ratio",), name
    assert np.allclose(ds.inertia.sel(axis="z") / ds.inertia.sel(axis="x"), ds.inertia_ratio)
    # the checksums (10 kB of JSON in rbstudy 0.3) are in a group of their own
    assert len(json.dumps(ds.attrs)) < 2048 + len(json.dumps(ds.attrs["config"]))
    assert not {"checksums", "part_checksums"} & set(ds.attrs)
    assert ds.attrs["source"].startswith(f"rbstudy {importlib.metadata.version('rbstudy')}")
    # labels xarray's plots can use whole: "long_name [units]"; the explanation apart
    for name, variable in ds.variables.items():  # the coordinates' too
        assert len(variable.attrs.get("long_name", "")) <= LONG_NAME_MAX, name
    for name, variable in ds.data_vars.items():
        assert 0 < len(variable.attrs["long_name"]) <= LONG_NAME_MAX, name
        assert variable.attrs["description"] not in ("", variable.attrs["long_name"]), name
    # precession W = w3 (I3 - I1) / I1 follows the inertia ratio, and only it
    assert ds.precession_frequency_exact.dims == ("inertia_ratio",)
    assert np.allclose(ds.precession_frequency_exact, 2 * math.pi * (ds.inertia_ratio - 1.0))


@pytest.mark.slow
def test_the_estimate_matches_the_archive_and_its_steps(abaqus_results):
    study = load_study(CONFIGS / "abaqus_top.yaml")
    cost = estimate(study)
    ds = open_results(abaqus_results)
    stored = sum(ds[name].nbytes for name in ds.data_vars)  # what validate promises to store
    assert abs(cost.archive_bytes / stored - 1.0) < 0.01, (cost.archive_bytes, stored)
    assert cost.body_steps == int(ds.n_steps.sum())  # fixed steps: the forecast is exact


@pytest.mark.slow
def test_the_dop853_forecast_is_within_a_factor_two_of_its_steps(tmp_path):
    """The forecast that warns of a reference past its budget: accepted DOP853 steps against
    |w0| T for asymmetric bodies turning 10 to 1000 radians under a small space-fixed moment
    (integrated twice: the composition's steps are forecast exactly); free, the same bodies
    need no integration."""
    for spin in (1.0, 10.0, 100.0):
        scene = {
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "duration": 10.0,
            "initial": {"angular_velocity": {"body": [0.6 * spin, 1.5 * spin, 0.9 * spin]}},
            "loads": {"moment_space": [0.0, 0.0, 0.01]},
        }
        config = write_study(
            tmp_path, name="dop", scene=scene, output={"interval": 0.1}, run={"scheme": "dop853", "dt": 0.1}
        )
        study = load_study(config)
        taken = simulate([study.cases[0].scene], "dop853", 0.1).results["n_steps"][0]
        forecast = estimate(study)
        composed = composed_steps(study.cases[0].scene, 0.1) * 100
        assert forecast.references == 1
        assert forecast.reference_steps == forecast.body_steps + composed
        assert 0.5 < forecast.body_steps / taken < 2.0, (spin, forecast.body_steps, taken)
        del scene["loads"]
        free = estimate(
            load_study(
                write_study(
                    tmp_path,
                    name="dop",
                    scene=scene,
                    output={"interval": 0.1},
                    run={"scheme": "dop853", "dt": 0.1},
                )
            )
        )
        assert free.references == 0 and free.reference_steps == 0


def test_the_forecast_counts_every_reference_run_of_a_loaded_body_at_its_cost(tmp_path, monkeypatch):
    """A space-fixed moment about the spin axis of least inertia spins the body up 40-fold over
    the run: the forecast counts the DOP853 steps of the radians it turns as it speeds up and
    the composition's second run, at a fitted step: within 1.5x of the steps the reference
    takes (counted run by run), DOP853's within 2x, as the forecast of dop853 as a scheme, and
    costs them at DOP853's calibrated (else declared) figure.
    A composition past its step budget is not run, and not charged."""
    scene = {
        "body": {"inertia": [1.0, 2.0, 3.0]},
        "duration": 20.0,
        "initial": {"angular_velocity": {"body": [0.9, 0.05, 0.05]}},
        "loads": {"moment_space": [2.0, 0.0, 0.0]},
    }
    config = write_study(
        tmp_path, name="spun", scene=scene, output={"interval": 0.5}, run={"scheme": "rk4", "dt": 0.05}
    )
    study = load_study(config)
    forecast = estimate(study, cores=1)
    taken = []  # steps of each integration the reference takes

    def composed_run(*args, **kwargs):
        run = simulate(*args, **kwargs)
        taken.append(int(run.results["n_steps"][0]))
        return run

    integrate = dop853.integrate

    def dop853_run(*args, **kwargs):
        run = integrate(*args, **kwargs)
        taken.append(run.steps)
        return run

    monkeypatch.setattr(references, "simulate", composed_run)
    monkeypatch.setattr(references.dop853, "integrate", dop853_run)
    reference = references.reference_solution(study.cases[0].scene, np.arange(41) * 0.5)
    monkeypatch.undo()
    assert reference.name == INTEGRATED and len(taken) == 3  # composed twice, DOP853
    assert 1 / 1.5 < forecast.reference_steps / sum(taken) < 1.5, (forecast.reference_steps, taken)
    composed_cost = step_cost(get_scheme(references.REFERENCE_SCHEME), references.REFERENCE_OPTIONS).seconds
    peer_steps = int(estimate_module._dop853_steps(study.cases.scenes)[0])
    composed_steps_ = forecast.reference_steps - peer_steps
    assert 1.0 < peer_steps / taken[-1] < 2.0  # a spin about a principal axis: ~3.5 steps a radian
    assert forecast.core_seconds - forecast.scheme_seconds == pytest.approx(
        peer_steps * reference_cost().seconds + composed_steps_ * composed_cost, rel=1e-9
    )
    # a spin whose composition needs 1.3e6 steps (past the budget): only DOP853, stopped at its
    # budget, is charged
    scene["initial"]["angular_velocity"]["body"] = [1e4, 0.0, 0.0]
    fast = estimate(load_study(write_study(tmp_path, name="spun", scene=scene, output={"interval": 0.5})))
    assert fast.reference_steps == references.REFERENCE_MAX_STEPS and fast.over_budget == 1


# The one CF-1.11 rule the archive breaks on purpose: a coordinate named `time` must carry a
# calendar reference ("seconds since <epoch>", and then standard_name time), which every
# reader, xarray first, decodes into dates; simulated time is a duration in plain seconds.
TIME_RULE = "Coordinate variable 'time' should have standard_name='time', found: 'None'"


@pytest.mark.slow
def test_default_study_is_cf_compliant_at_strict_criteria(abaqus_results, tmp_path):
    checker = shutil.which("compliance-checker") or os.path.join(
        os.path.dirname(sys.executable), "compliance-checker"
    )
    report = tmp_path / "cf.json"
    subprocess.run(
        [
            checker,
            "--test=cf:1.11",
            "--criteria=strict",
            "-f",
            "json",
            "-o",
            str(report),
            str(abaqus_results),
        ],
        capture_output=True,
        check=False,
    )
    result = json.loads(report.read_text())["cf:1.11"]
    findings = {
        message
        for level in ("high_priorities", "medium_priorities", "low_priorities")
        for check in result[level]
        for message in check["msgs"]
    }
    assert findings <= {TIME_RULE}, findings


@pytest.mark.slow
def test_plain_xarray_opens_time_as_seconds_on_the_decimal_grid(abaqus_results):
    """A user's first line: no decode_times=False, no rounding of the time they ask for."""
    with xr.open_dataset(abaqus_results) as ds:
        assert ds.time.dtype == np.float64 and ds.time.attrs["units"] == "s"
        assert float(ds.sel(time=1.5).time) == 1.5
        assert float(ds.sel(time=0.35).time) == 0.35  # 35 * 0.01 is 0.35000000000000003
        assert ds.sel(time=0.35).omega_body.sizes["axis"] == 3


def test_summary_orders_match_each_scheme(abaqus_results):
    for row in scheme_rows(open_results(abaqus_results)):
        if row["scheme"] in EXACT_FOR_FREE_BODIES:  # round-off at every dt: no order
            assert row["order"] is None and row["error"] <= EXACT_FLOW_TOLERANCE, row
            continue
        nominal = SCHEMES[row["scheme"]].order
        low, high = row["order"]
        assert abs(low - nominal) < 0.25 and abs(high - nominal) < 0.25, row


def test_stored_case_equals_a_direct_run(abaqus_results):
    study = load_study(CONFIGS / "abaqus_top.yaml")
    case = next(
        c for c in study.cases if c.scheme == "rkmk4" and c.dt == 0.0025 and c.scene.body.inertia[2] == 0.5
    )
    direct = simulate([case.scene], "rkmk4", 0.0025, 0.01)
    stored = open_results(abaqus_results).sel(scheme="rkmk4", dt=0.0025, inertia_ratio=0.5)
    assert np.array_equal(stored.quaternion.values, direct.quaternion[0])
    assert np.array_equal(stored.omega_body.values, direct.omega_body[0])


def _small_study(folder, **changes):
    return write_study(
        folder,
        name="small",
        sweep={"scheme": ["euler", "midpoint"], "dt": [0.01, 0.005], "inertia_ratio": [0.5, 2.0], **changes},
    )


@pytest.mark.slow
def test_rerun_reuses_parts_force_recomputes_and_a_changed_config_never_mixes(tmp_path):
    config = _small_study(tmp_path)
    out = tmp_path / "out"
    first = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert (first.computed, first.reused) == (4, 0)
    parts = sorted((out / "small" / "parts").iterdir())
    first.path.unlink()  # as a kill before the consolidation leaves it: parts, no archive
    again = run_study(load_study(config), out, quiet=True, keep_parts=True)
    assert (again.computed, again.reused, again.up_to_date) == (0, 4, False)
    assert sorted((out / "small" / "parts").iterdir()) == parts
    forced = run_study(load_study(config), out, force=True, quiet=True, keep_parts=True)
    assert (forced.computed, forced.reused) == (4, 0)
    changed = run_study(
        load_study(_small_study(tmp_path, inertia_ratio=[0.5, 1.5])), out, quiet=True, keep_parts=True
    )
    assert changed.computed == 4  # no batch of the old config is reused...
    assert not set(parts) & set((out / "small" / "parts").iterdir())  # ...or left behind
    ds = open_results(changed.path)
    reordered = run_study(
        load_study(_small_study(tmp_path, inertia_ratio=[1.5, 0.5])), out, quiet=True, keep_parts=True
    )
    assert reordered.computed == 4  # same cases, other cells: recomputed, never misplaced
    assert np.array_equal(
        open_results(reordered.path).quaternion.sel(inertia_ratio=1.5), ds.quaternion.sel(inertia_ratio=1.5)
    )
    assert list(ds.inertia_ratio.values) == [0.5, 1.5]
    w3 = ds.omega_body.isel(time=0).sel(scheme="euler", dt=0.01, axis="z")
    assert np.allclose(ds.precession_frequency_exact, w3 * (ds.inertia_ratio - 1.0), rtol=1e-14)


def test_a_damaged_part_is_recomputed_not_trusted(tmp_path):
    config = _small_study(tmp_path)
    first = run_study(load_study(config), tmp_path / "out", quiet=True, keep_parts=True)
    reference = tmp_path / "first.nc"
    first.path.rename(reference)  # the run is to resume from its parts
    victim = sorted((tmp_path / "out" / "small" / "parts").glob("*.npz"))[0]
    victim.write_bytes(victim.read_bytes()[:100])  # a crash of the machine after the rename
    again = run_study(load_study(config), tmp_path / "out", quiet=True)
    assert (again.computed, again.reused) == (1, 3)
    same_numbers(reference, again.path)


def test_a_second_sweep_of_the_same_study_refuses_clearly(tmp_path, capsys):
    config = _small_study(tmp_path)
    folder = tmp_path / "out" / "small"
    folder.mkdir(parents=True)
    with study_lock(folder):
        assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 1
    error = capsys.readouterr().err.strip()
    assert "another rbstudy sweep is writing this study" in error and "\n" not in error
    assert not (folder / "small.nc").exists()


@pytest.mark.slow
def test_the_study_lock_names_its_holder_and_dies_with_it(tmp_path):
    """Another process holds the lock: refused at once, naming that process; killed, it
    leaves no lock behind (the system's lock, through filelock)."""
    folder = tmp_path / "study"
    folder.mkdir()
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time\n"
            "from rbstudy.archive.lock import study_lock\n"
            f"lock = study_lock(__import__('pathlib').Path({str(folder)!r}))\n"
            "print('held', flush=True)\ntime.sleep(600)",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline() == "held\n"
        with pytest.raises(RbstudyError) as refused:  # at once: a wait would outlast the test
            study_lock(folder)
        assert f"(pid {holder.pid})" in str(refused.value)
    finally:
        holder.kill()
        holder.wait()
        holder.stdout.close()
    with study_lock(folder):
        assert (folder / lock.PID_FILE).read_text() == str(os.getpid())


def test_the_archive_is_written_while_later_batches_run(tmp_path, monkeypatch):
    """The first part is copied into the archive before the last batch ends: the last batch
    waits for it (before the archive was written after every batch, and it waited in vain)."""
    from rbstudy.pipeline import config as config_module

    monkeypatch.setattr(config_module, "BATCH_MAX_CASES", 2)
    monkeypatch.setattr(execute, "default_threads", lambda: 2)
    study = load_study(write_study(tmp_path, name="rows", sweep={"inertia_ratio": [0.5, 0.8, 1.1, 1.4, 1.7]}))
    copied, copy, compute = threading.Event(), writer.copy_part, execute.compute_batch
    waited = []

    def copying(*args):
        copy(*args)
        copied.set()

    def computing(job, *args):
        if job.scene_rows.max() == len(study.cases) - 1:  # the last batch
            waited.append(copied.wait(timeout=20))
        return compute(job, *args)

    monkeypatch.setattr(writer, "copy_part", copying)
    monkeypatch.setattr(execute, "compute_batch", computing)
    run = run_study(study, tmp_path / "out", quiet=True)
    assert waited == [True]
    assert main(["verify", str(run.path)]) == 0


def test_the_batches_run_in_their_order_so_that_the_archive_never_waits_for_the_first(tmp_path, monkeypatch):
    """One thread runs the batches in the study's order (dask breaks ties by the keys'
    order: by the batch ids alone, the first batch ran last and the archive waited for it)."""
    from rbstudy.pipeline import config as config_module

    monkeypatch.setattr(config_module, "BATCH_MAX_CASES", 1)
    monkeypatch.setattr(execute, "default_threads", lambda: 1)
    study = load_study(write_study(tmp_path, name="rows", sweep={"inertia_ratio": [0.5, 0.8, 1.1, 1.4, 1.7]}))
    delivered, deliver = [], execute.deliver_part

    def delivering(values, target, *args):
        delivered.append(target.batch.id)
        return deliver(values, target, *args)

    monkeypatch.setattr(execute, "deliver_part", delivering)
    run_study(study, tmp_path / "out", quiet=True)
    assert delivered == [batch.id for batch in study.batches]


def test_a_local_run_hands_its_values_to_the_archive_without_reading_its_parts_back(tmp_path, monkeypatch):
    """The archive of a local run takes each batch's values from memory: no part is read back,
    and the archive holds exactly what one written from the part files holds (run_time, a
    CPU time, aside); parts from an earlier run, never in memory, are read."""
    from rbstudy.archive import parts as parts_module

    config = write_study(tmp_path, name="held", sweep={"scheme": ["euler", "rk4"], "dt": [0.01, 0.005]})
    read, read_part = [], parts_module.read_part

    def reading(path, variables):
        read.append(path)
        return read_part(path, variables)

    monkeypatch.setattr(writer, "read_part", reading)
    from_memory = run_study(load_study(config), tmp_path / "memory", quiet=True)
    assert read == []
    monkeypatch.setattr(writer, "HELD_BYTES", 0)  # nothing held: every part read back
    from_files = run_study(load_study(config), tmp_path / "files", quiet=True)
    assert len(read) == len(load_study(config).batches) == 4
    held, written = (open_results(run.path).drop_vars("run_time") for run in (from_memory, from_files))
    held.attrs.pop("history"), written.attrs.pop("history")
    assert held.identical(written)
    assert main(["verify", str(from_memory.path)]) == 0


def test_values_held_for_the_archive_are_bounded():
    batches = [types.SimpleNamespace(id=name) for name in ("a", "b")]
    values = {"case": np.arange(4), "x": np.zeros(4)}  # 64 bytes
    arrivals = writer._Arrivals(batches, {"a": "a.nc", "b": "b.nc"}, {}, held_bytes=100)
    arrivals.computed("a", values)
    arrivals.computed("b", values)  # 128 bytes: over the bound, read from its part
    arrivals.arrived("a", "sha256:a")
    arrivals.arrived("b", "sha256:b")
    (_, _, first), (_, _, second) = list(arrivals)
    assert first is values and second is None


def test_values_held_for_the_archive_own_their_data():
    """A variable that is a view (the last sample of a series) is held as a copy of its own:
    held as a view, it kept its whole series alive, uncounted by the bound."""
    batch = types.SimpleNamespace(id="a", cases=[0, 1, 2, 3])
    study = types.SimpleNamespace(batches=[batch], variables=("final_orientation_error",))
    archive = writer.ArchiveWriter(study, {"a": "a.nc"}, {}, "study.nc", {})
    series = np.zeros((4, 100_000))
    archive.computed(batch, {"final_orientation_error": series[:, -1]})
    archive.arrived("a", "sha256:a")
    ((_, _, held),) = list(archive._arrivals)
    assert held["final_orientation_error"].base is None and held["case"].base is None


def test_the_archive_takes_the_parts_in_order_as_they_arrive_and_stops_when_abandoned():
    batches = [types.SimpleNamespace(id=name) for name in ("a", "b", "c")]
    parts = {"a": "a.nc", "b": "b.nc", "c": "c.nc"}
    arrivals = writer._Arrivals(batches, parts, {"a": "sha256:a", "b": None})
    taken = []
    reader = threading.Thread(target=lambda: taken.extend(arrivals))
    reader.start()
    arrivals.arrived("c", "sha256:c")  # before b: kept until b has arrived
    deadline = time.monotonic() + 10
    while not taken and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.05)  # time enough to take c, were it handed out of order
    assert taken == [("a.nc", "sha256:a", None)]
    arrivals.arrived("b", "sha256:b")
    reader.join(timeout=5)
    assert taken == [("a.nc", "sha256:a", None), ("b.nc", "sha256:b", None), ("c.nc", "sha256:c", None)]
    waiting = writer._Arrivals(batches, {}, {})
    threading.Timer(0.05, waiting.abandon).start()
    with pytest.raises(writer._Abandoned):
        list(waiting)


@pytest.mark.slow
def test_killed_sweep_resumes_to_the_uninterrupted_result(tmp_path):
    sweep = {
        "scheme": ["rkmk4"],
        "dt": [0.01 / k for k in range(1, 11)],
        "inertia_ratio": {"linspace": [0.2, 2.0, 40]},
    }
    config = write_study(tmp_path, name="long", sweep=sweep, scene={**abaqus_mapping(), "duration": 40.0})
    out = tmp_path / "out"
    process, parts = sweep_until_a_batch_is_kept(config, out)
    os.kill(process.pid, signal.SIGKILL)
    process.wait()
    # a part whose digest a kill prevented is recomputed, not reused
    finished = len(list(parts.glob("*.npz.sha256")))
    assert 1 <= finished < 10, f"kill came too late to test resuming ({finished} parts)"
    assert not (out / "long" / "long.nc").exists()
    (parts / ".planted.npz.x.tmp").write_text("half a part")  # as a kill mid-write leaves
    (out / "long" / ".long.nc.x.tmp").write_text("half a dataset")
    resumed = run_study(load_study(config), out, quiet=True)
    assert resumed.reused == finished and resumed.computed == 10 - finished
    assert not list(parts.glob(".*.tmp")) and not list((out / "long").glob(".*.tmp"))
    clean = run_study(load_study(config), tmp_path / "clean", quiet=True)
    same_numbers(resumed.path, clean.path)


@pytest.mark.slow
def test_ctrl_c_ends_a_long_batch_within_a_second_and_resumes_bit_equal(tmp_path):
    """A batch of 1.6e7 body-steps is halted from inside its compiled loop: the process ends
    at once (it used to wait for the kernel), the study's lock is free only then, and the
    rerun computes the halted batch to the numbers of an uninterrupted run."""
    scene = {**abaqus_mapping(), "duration": 40.0}
    config = write_study(
        tmp_path,
        name="long",
        scene=scene,
        output={"interval": 0.1},
        sweep={"scheme": ["rk4"], "dt": [0.01, 1e-5], "inertia_ratio": [0.5, 1.0, 1.5, 2.0]},
    )
    out = tmp_path / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "rbstudy", "sweep", str(config), "--out", str(out), "--quiet"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    parts = out / "long" / "parts"
    deadline = time.monotonic() + 120
    while not (parts.exists() and list(parts.glob("*.sha256"))) and process.poll() is None:
        assert time.monotonic() < deadline, "the short batch did not finish in 120 s"
        time.sleep(0.01)
    time.sleep(0.5)  # the long batch (about 4 s) is in its kernel now
    assert process.poll() is None, "the long batch ended before the interrupt"
    interrupted = time.monotonic()
    process.send_signal(signal.SIGINT)
    _, error = process.communicate(timeout=30)
    ended = time.monotonic() - interrupted
    assert process.returncode == 130 and "interrupted" in error.decode()
    assert ended < 1.0, f"the process took {ended:.2f} s to end after Ctrl-C"
    assert len(list(parts.glob("*.npz"))) == 1  # the halted batch left no part
    resumed = run_study(load_study(config), out, quiet=True)
    assert (resumed.computed, resumed.reused) == (1, 1)
    clean = run_study(load_study(config), tmp_path / "clean", quiet=True)
    same_numbers(resumed.path, clean.path)


@pytest.mark.slow
def test_a_reference_past_its_step_budget_is_no_reference_not_a_hang(tmp_path, monkeypatch):
    """DOP853 stops at its budget: the case is stored, reference "none", its errors NaN and its
    verdict "unjudged" (not accurate, not failed), and the summary reads it. (A body-fixed
    force through the centre leaves the rotation free, but couples nothing the closed forms
    know: the reference is DOP853's.)"""
    monkeypatch.setattr(references, "REFERENCE_MAX_STEPS", 20)
    scene = {
        "body": {"inertia": [1.0, 2.0, 3.0]},
        "duration": 1.0,
        "initial": {"angular_velocity": {"body": [0.6, 15.0, 0.9]}},
        "loads": {"force_body": [0.0, 0.0, 1e-3]},
    }
    config = write_study(
        tmp_path, name="budget", scene=scene, sweep={"scheme": ["rk4", "euler"], "dt": [0.01, 0.005]}
    )
    done = run_study(load_study(config), tmp_path / "out", quiet=True)
    ds = open_results(done.path)
    assert set(ds.reference.values.ravel()) == {REFERENCE_KINDS.index("none")}
    assert np.all(np.isnan(ds.final_orientation_error)) and np.all(ds.status == 0)
    rk4 = ds.accuracy.sel(scheme="rk4").values
    assert set(rk4) == {VERDICTS.index("unjudged")}  # rk4 drifts little: no verdict
    euler = ds.accuracy.sel(scheme="euler").values
    assert set(euler) == {VERDICTS.index("inaccurate")}  # euler's drift alone condemns it
    rows = {row["scheme"]: row for row in scheme_rows(ds)}
    assert (rows["rk4"]["inaccurate"], rows["rk4"]["unstable"], rows["rk4"]["unjudged"]) == (0, 0, 2)
    assert rows["rk4"]["error"] is None  # "-", not "failed": nothing failed
    table = format_table(list(rows.values()), wide=True).splitlines()
    rk4 = next(line for line in table if line.startswith("rk4"))
    assert "failed" not in rk4 and "0/2 (2 unjudged)" in rk4
    figures = all_figures(ds, tmp_path / "figures")
    assert "no case has a reference" in figures.absent["convergence_orientation"]


def test_a_failed_run_leaves_later_runs_free_to_finish(tmp_path, monkeypatch):
    """A failing task halts the others (so the command ends at once); the halt must not
    outlive the run: later simulations and references in the process run to their end."""
    config = _small_study(tmp_path)

    def broken(*args):
        raise RbstudyError("the disk broke")

    monkeypatch.setattr(execute, "deliver_part", broken)
    with pytest.raises(RbstudyError, match="the disk broke"):
        run_study(load_study(config), tmp_path / "out", quiet=True)
    monkeypatch.undo()
    assert not HALT_FLAG[0]
    asymmetric = load_study(config).cases[0].scene.with_changes(body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)))
    assert simulate([asymmetric], "rk4", 0.01).results["status"][0] == 0
    assert references.reference_solution(asymmetric, np.arange(51) * 0.01).name == "exact_asymmetric"


def test_a_resume_needs_the_disk_for_what_is_left_only(tmp_path, monkeypatch):
    from rbstudy.pipeline import estimate as forecast

    config = _small_study(tmp_path)
    study = load_study(config)
    run_study(study, tmp_path / "out", quiet=True, keep_parts=True).path.unlink()
    left = forecast.disk_needed(study, [])  # the archive alone: every part is there
    assert left < forecast.disk_needed(study, study.batches)
    monkeypatch.setattr(forecast, "_free_bytes", lambda folder: left)
    again = run_study(study, tmp_path / "out", quiet=True)
    assert (again.computed, again.reused) == (0, 4)
    monkeypatch.setattr(forecast, "_free_bytes", lambda folder: left - 1)
    again.path.unlink()
    with pytest.raises(RbstudyError, match="MiB on disk for its parts and archive"):
        run_study(study, tmp_path / "out", quiet=True, force=True)


@pytest.mark.slow
def test_two_worker_local_cluster_and_a_running_scheduler_give_the_same_numbers(tmp_path):
    from distributed import LocalCluster

    config = _small_study(tmp_path)
    threaded = run_study(load_study(config), tmp_path / "threaded", quiet=True)
    cluster = run_study(load_study(config), tmp_path / "cluster", where=Where(workers=2), quiet=True)
    same_numbers(threaded.path, cluster.path)
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as running:
        remote = run_study(
            load_study(config),
            tmp_path / "remote",
            where=Where(scheduler=running.scheduler_address),
            quiet=True,
        )
    same_numbers(threaded.path, remote.path)


def test_an_unreachable_scheduler_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", "1s")
    config = _small_study(tmp_path)
    assert (
        main(
            [
                "sweep",
                str(config),
                "--out",
                str(tmp_path / "out"),
                "--quiet",
                "--scheduler",
                "tcp://127.0.0.1:9",
            ]
        )
        == 1
    )
    error = capsys.readouterr().err.strip()
    assert "--scheduler tcp://127.0.0.1:9: cannot connect" in error and "\n" not in error
    assert not (tmp_path / "out" / "small").exists()  # no empty folder, .lock or parts/ left


def test_unstable_cases_are_results_not_crashes(tmp_path, capsys):
    config = write_study(
        tmp_path,
        name="blowup",
        scene={
            "body": {"inertia": [1.0, 2.0, 3.0]},
            "initial": {"angular_velocity": {"body": [0.1, 10.0, 0.1]}},
            "duration": 2.0,
        },
        output={"interval": 0.1},
        run={"scheme": "euler", "dt": 0.1},
        sweep={"scheme": ["euler", "midpoint"], "dt": [0.1, 0.01]},
    )
    assert main(["sweep", str(config), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    ds = open_results(tmp_path / "out" / "blowup" / "blowup.nc")
    euler = ds.sel(scheme="euler", dt=0.1)
    assert int(euler.status) == 1 and 0 < float(euler.failure_time) <= 2.0
    assert int(ds.status.sel(scheme="midpoint", dt=0.01)) == 0
    euler_row = next(
        line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("euler ")
    )  # the table row
    assert "1/2" in euler_row  # one of its two cases unstable
    assert ds.reference.attrs["flag_meanings"].split()[int(euler.reference)] == "exact_asymmetric"


def test_unwritable_results_folder_is_one_line(tmp_path):
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    with pytest.raises(RbstudyError, match="cannot write results there"):
        run_study(load_study(_small_study(tmp_path)), blocked, quiet=True)


def test_node_velocity_is_the_rate_of_the_stored_node_positions(tmp_path):
    """node_velocity (v + R (w x s)) against central differences of node_displacement on a
    fine rk4 run of the Abaqus top thrown upwards under gravity: an independent derivative."""
    interval = 1e-3
    scene = {**abaqus_mapping(), "duration": 0.5}
    scene["initial"] = {**scene["initial"], "velocity": [1.0, -2.0, 3.0]}
    scene["loads"] = {"gravity": [0.0, 0.0, -9.81]}
    config = write_study(
        tmp_path,
        name="nodes",
        scene=scene,
        output={"interval": interval},
        run={"scheme": "rk4", "dt": interval},
    )
    ds = open_results(run_study(load_study(config), tmp_path / "out", quiet=True).path)
    assert ds.node_velocity.dims == ("time", "node", "axis")
    assert ds.node_velocity.attrs["units"] == "m s-1"
    x = ds.node_displacement.values  # (T, N, 3)
    rate = (x[2:] - x[:-2]) / (2 * interval)
    velocity = ds.node_velocity.values[1:-1]
    spin = np.linalg.norm(velocity - ds.node_velocity.values[1:-1].mean(axis=1, keepdims=True), axis=-1)
    assert spin.max() > 4.0  # the nodes turn at ~2 pi rad/s at unit distance
    # central differences err by h^2/6 |x'''|, |x'''| ~ (2 pi)^3 at unit distance: 4.1e-5 m/s
    assert np.max(np.abs(rate - velocity)) < 6e-5


@pytest.mark.slow
def test_a_finished_study_keeps_a_compressed_archive_and_no_parts(tmp_path):
    config = _small_study(tmp_path)
    out = tmp_path / "out"
    first = run_study(load_study(config), out, quiet=True)
    assert not (out / "small" / "parts").exists()
    again = run_study(load_study(config), out, quiet=True)
    assert (again.computed, again.up_to_date) == (0, True)  # the archive is current
    import netCDF4

    with netCDF4.Dataset(first.path) as nc:
        assert nc["omega_body"].filters()["zlib"] and nc["omega_body"].filters()["shuffle"]
    retitled = config.read_text().replace("name: small", "name: small\ntitle: New title")
    config.write_text(retitled)
    again = run_study(load_study(config), out, quiet=True)
    assert (again.computed, again.up_to_date) == (0, True)  # the same cases: no recomputation
    assert open_results(again.path).attrs["title"] == "New title"  # but the new description
    assert "New title" in (out / "small" / "study.yaml").read_text()
    changed = run_study(load_study(_small_study(tmp_path, inertia_ratio=[0.5, 1.5])), out, quiet=True)
    assert (changed.computed, changed.up_to_date) == (4, False)


def test_finite_but_meaningless_is_inaccurate_not_ok(tmp_path):
    """The flat disk at |w| = 200 rad/s: euler at dt = 1.25e-4 s ends with status ok but a
    final orientation error of 0.36 rad and 1.7% energy drift. Blow-up stays `unstable`; the
    verdict says `inaccurate`, and "largest accurate dt|w0|" does not count it."""
    scene = {
        "body": {"inertia": [1.0, 1.0, 2.0]},
        "initial": {
            "angular_velocity": {"body": [0.25, 0.0, 200.0]},
            "orientation": {"momentum_axis": [0.0, 0.0, 1.0]},
        },
        "duration": 2.0,
    }
    config = write_study(
        tmp_path,
        name="spin200",
        scene=scene,
        output={"interval": 0.01},
        sweep={"scheme": ["euler", "rk4"], "dt": [1.25e-4, 6.25e-5]},
    )
    ds = open_results(run_study(load_study(config), tmp_path / "out", quiet=True).path)
    assert ds.accuracy.attrs["flag_meanings"] == "accurate inaccurate failed unjudged"
    assert ds.attrs["accuracy_bound"] == 0.01
    euler = ds.sel(scheme="euler", dt=1.25e-4)
    assert int(euler.status) == 0 and float(euler.final_orientation_error) > 0.3
    assert int(euler.accuracy) == 1
    assert int(ds.accuracy.sel(scheme="euler", dt=6.25e-5)) == 0  # 8.3e-3 rad: within 1e-2
    assert (ds.accuracy.sel(scheme="rk4") == 0).all()
    rows = {row["scheme"]: row for row in scheme_rows(ds)}
    assert rows["euler"]["inaccurate"] == 1 and rows["euler"]["unstable"] == 0
    spin = float(ds.initial_spin)  # one scene: one value
    assert rows["euler"]["accurate_hw"] == pytest.approx(6.25e-5 * spin)
    assert rows["rk4"]["accurate_hw"] == pytest.approx(1.25e-4 * spin)


def test_the_verdict_judges_the_largest_error_not_the_last(tmp_path):
    """splitting on the flat disk at 46.2 rad/s, dt = 0.01 s: 0.040 rad off at t = 1.02 s,
    back to 0.004 rad at the end. Judged on the last sample it passed as accurate."""
    scene = yaml.safe_load((CONFIGS / "high_spin.yaml").read_text())["scene"]
    spin = float(np.geomspace(1.0, np.pi / 0.01, 13)[8])  # 46.2 rad/s, a value of the study
    w = np.array(scene["initial"]["angular_velocity"]["body"])
    scene["initial"]["angular_velocity"]["body"] = (w / np.linalg.norm(w) * spin).tolist()
    config = write_study(
        tmp_path, name="wrap", scene=scene, output={"interval": 0.01}, run={"scheme": "splitting", "dt": 0.01}
    )
    ds = open_results(run_study(load_study(config), tmp_path / "out", quiet=True).path)
    assert float(ds.final_orientation_error) < 0.005 < 0.03 < float(ds.orientation_error.max())
    assert int(ds.status) == 0 and int(ds.accuracy) == 1
    assert ds.accuracy.attrs["flag_meanings"] == "accurate inaccurate failed unjudged"


def test_every_file_is_synced_before_and_after_its_rename(tmp_path, monkeypatch):
    """A machine crash must not leave a renamed but empty part: the file is fsynced before
    the rename, its folder after."""
    from rbstudy.archive import files

    calls = []
    real_replace = os.replace
    monkeypatch.setattr(
        files.os, "fsync", lambda fd: calls.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
    )
    monkeypatch.setattr(
        files.os, "replace", lambda a, b: (calls.append(("replace", str(b))), real_replace(a, b))
    )
    target = tmp_path / "x.txt"
    files.write_text_atomic("data", target)
    assert [kind for kind, _ in calls] == ["fsync", "replace", "fsync"]
    assert calls[0][1].endswith(".tmp") and calls[2][1] == str(tmp_path)
    assert target.read_text() == "data"


@pytest.mark.parametrize("shape", [(7,), (3, 5), (4, 3, 5), (2, 3, 4, 2)])
def test_every_run_of_consecutive_cases_is_written_as_few_slabs_in_order(shape):
    """A part whose cases are not one block of the grid is written slab by slab: every run
    of consecutive cases of every grid up to four dimensions is covered exactly, in order,
    by at most 2 ndim - 1 slabs."""
    from rbstudy.archive.writer import _slabs

    grid = np.arange(math.prod(shape)).reshape(shape)
    for first in range(grid.size + 1):
        for stop in range(first, grid.size + 1):
            slabs = _slabs(first, stop, shape)
            assert len(slabs) <= 2 * len(shape) - 1
            covered = [grid[index].ravel() for index in slabs]
            assert np.array_equal(np.concatenate(covered) if covered else [], np.arange(first, stop))


def test_the_forecast_and_the_archive_cost_a_step_as_calibrated_once_per_machine(tmp_path, monkeypatch):
    """A scheme ready to run is measured once (cached beside the kernels, in a cache folder
    of its own here); the forecast and the archive's step_seconds then take that figure, and
    neither a second forecast nor the sweep measures it again."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    config = write_study(tmp_path, run={"scheme": "leapfrog", "dt": 0.01}, sweep={"dt": [0.01, 0.005]})
    study = load_study(config)
    get_scheme("leapfrog").ensure_compiled()  # ready: the forecast measures it
    forecast = estimate(study, cores=1)
    with open(calibration_path(), encoding="utf-8") as file:
        figure = json.load(file)[machine_key()]["leapfrog rbstudy"]
    assert figure["seconds"] > 0 and figure["uncertainty"] >= 0.1
    assert forecast.scheme_seconds == pytest.approx(forecast.body_steps * figure["seconds"], rel=1e-12)
    stamp = os.stat(calibration_path()).st_mtime_ns
    assert estimate(study, cores=1).scheme_seconds == forecast.scheme_seconds
    ds = open_results(run_study(study, tmp_path / "out", quiet=True).path)
    assert os.stat(calibration_path()).st_mtime_ns == stamp  # measured once
    assert np.all(ds.step_seconds.values == figure["seconds"])
    assert np.all(ds.step_seconds_uncertainty.values == figure["uncertainty"])
    assert ds.step_seconds.attrs["units"] == "s"


def test_the_forecast_takes_the_block_rate_where_a_batch_fills_blocks(tmp_path):
    """Batches of 16 bodies or more step in blocks across SIMD lanes (numerics/block.py),
    3-6x the rate of one body after another: the forecast takes each scheme's block rate
    there, and the single-body rate for a smaller batch, a lever or a force turning with the
    body (the single-body loop), and `compensated` (kernels of their own)."""
    leapfrog = get_scheme("leapfrog")

    def kernel_seconds(count, scene=None, options=None):
        run = {"scheme": "leapfrog", "dt": 0.01, **({"options": options} if options else {})}
        config = write_study(
            tmp_path,
            name="blocks",
            scene=scene,
            run=run,
            sweep={"scene.body.mass": np.linspace(1.0, 2.0, count).tolist()},
        )
        forecast = estimate(load_study(config), cores=1)
        return forecast.scheme_seconds / forecast.body_steps

    # at this machine's calibrated cost where there is one (the declared one else), the
    # block's scaled alike
    single = step_cost(leapfrog).seconds
    scale = single / leapfrog.step_seconds
    assert kernel_seconds(64) == pytest.approx(leapfrog.block_step_seconds * scale)
    assert kernel_seconds(8) == pytest.approx(single)
    lever = {**abaqus_mapping(), "duration": 0.5, "loads": {"nodes": {"2": {"force_space": [0.0, 0.0, 0.1]}}}}
    turning = {**abaqus_mapping(), "duration": 0.5, "loads": {"force_body": [0.0, 0.0, 0.1]}}
    assert kernel_seconds(64, lever) == pytest.approx(single)
    assert kernel_seconds(64, turning) == pytest.approx(single)
    compensated = leapfrog.seconds_per_step({"compensated": 1}) * scale
    assert kernel_seconds(64, options={"compensated": 1}) == pytest.approx(compensated)
    # a scheme without a block step keeps its one rate
    assert get_scheme("exact_split").block_seconds_per_step() is None
    # a block rate that is not a finite number above 0 would reach the forecast as it is
    for bad in (float("nan"), 0.0, -1e-8):
        with pytest.raises(ValueError, match="block_step_seconds is"):
            dataclasses.replace(leapfrog, block_step_seconds=bad)
