"""The contracts between the layers: the driver's results by name, the variables table, the
reference kinds, and the structured input errors."""

import dataclasses
import pathlib
import re

import netCDF4
import numpy as np
import pytest
from helpers import abaqus_mapping, write_study
from scipy.spatial.transform import Rotation

from rbstudy.archive.variables import FEATURES, VARIABLES
from rbstudy.errors import ConfigError, InputError
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import run_batch
from rbstudy.physics.analytic import REFERENCE_KINDS
from rbstudy.physics.references import COMPUTE
from rbstudy.physics.scenes import Body, Scene
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.pipeline.execute import run_study
from rbstudy.schemes import SCHEMES

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


def test_archived_codes_keep_their_meaning():
    """Archives store codes: the names behind them are append-only."""
    assert REFERENCE_KINDS[:6] == (
        "symmetric_top",
        "axial_moment",
        "dop853",
        "none",
        "exact_asymmetric",
        "exact_split_composition",
    )
    assert S.STATUS_NAMES[:3] == ("ok", "unstable", "not_converged")


def documented_flags(variable):
    """The codes and names docs/config.md's table of variables gives ``variable``'s flags
    ("0 ok, 1 unstable (...), 2 not_converged"), as a tuple of names in code order."""
    row = next(
        line for line in (DOCS / "config.md").read_text().splitlines() if line.startswith(f"| `{variable}` ")
    )
    pairs = re.findall(r"(?:: |, )(\d+) ([a-z][a-z0-9_]*)", row.split("| flags |")[1])
    assert [int(code) for code, _ in pairs] == list(range(len(pairs))), row
    return tuple(name for _, name in pairs)


@pytest.mark.parametrize("variable", [v.name for v in VARIABLES.values() if v.flags])
def test_the_documentation_names_each_flag_as_the_archive_stores_it(variable):
    """config.md once read "0 an allow_unphysical stress body, 1 a real one" where the archive
    says unphysical_stress_body and physical: a reader matching the two found nothing."""
    assert documented_flags(variable) == tuple(VARIABLES[variable].flags)


def test_an_archive_says_what_its_codes_mean_as_the_documentation_does(tmp_path):
    """The flags an archive stores (read with netCDF4, no decoding) carry the meanings the
    documentation gives their codes, and the codes stored are those of what happened: euler
    on the symmetric top over 5 s finishes at dt = 0.01 s, blows up at 0.25 s (dt |w| = 1.6),
    and the top's reference is its closed form."""
    config = write_study(
        tmp_path,
        scene={**abaqus_mapping(), "duration": 5.0},
        output={"interval": 0.25},
        run={"scheme": "euler", "dt": 0.01},
        sweep={"dt": [0.01, 0.25]},
    )
    path = run_study(load_study(config), tmp_path / "out", quiet=True).path
    with netCDF4.Dataset(path) as ds:
        ds.set_auto_mask(False)
        meanings = {}
        for name in ("status", "reference", "accuracy", "radioss_dt_limit"):
            variable = ds[name]
            meanings[name] = tuple(variable.flag_meanings.split())
            assert meanings[name] == documented_flags(name), name
            assert list(variable.flag_values) == list(range(len(meanings[name]))), name
        assert list(ds["dt"][:]) == [0.01, 0.25]
        assert [meanings["status"][code] for code in ds["status"][:]] == ["ok", "unstable"]
        assert meanings["reference"][int(ds["reference"][...])] == "symmetric_top"


def test_every_reference_kind_is_computed_and_every_need_is_a_feature():
    # the integrations of a loaded body end as the composition, DOP853 (the composition could
    # not be had) or none (neither could)
    assert set(COMPUTE) | {"none", "dop853"} == set(REFERENCE_KINDS)
    for variable in VARIABLES.values():
        assert variable.needs <= set(FEATURES), variable.name


def test_every_driver_result_is_stored_under_its_name_and_type():
    for name, dtype in S.RESULT_FIELDS:
        assert VARIABLES[name].dtype == dtype and VARIABLES[name].dims == (), name


def test_a_result_left_unset_is_a_bug_not_a_number():
    """NaN cast to int8 is 0, the code of "ok": a scheme that fills no status must fail."""

    def run_nothing(
        start, stop, state0, params, options, h, n_steps, every, bound, samples, results, halt, clock
    ):
        samples[:] = 0.0

    silent = dataclasses.replace(SCHEMES["euler"], name="silent", run_bodies_inplace=run_nothing)
    state0 = np.zeros((2, S.N_STATE))
    state0[:, S.QUATERNION + 3] = 1.0
    params = np.ones((2, S.N_PARAM))
    params[:, S.KNOTS] = 0.0  # constant loads
    with pytest.raises(RuntimeError, match="scheme 'silent' left the result 'status' unset"):
        run_batch(silent, state0, params, np.zeros((2, S.N_OPTION)), 0.1, 2, 1, threads=1)


def test_dop853_reports_energy_and_momentum_drift_apart():
    """Each drift equals its own measure taken independently from the samples (it used to
    report one combined drift as both)."""
    scene = Scene(
        body=Body(mass=1.0, inertia=(1.0, 2.0, 3.0)),
        quaternion=tuple(Rotation.from_rotvec([0.3, -0.2, 0.5]).as_quat()),
        omega_body=(0.6, 1.5, 0.9),
        duration=20.0,
    )
    run = simulate([scene], "dop853", 0.05, 0.05)
    w = run.omega_body[0]
    inertia = np.array(scene.body.inertia)
    energy = 0.5 * np.sum(inertia * w * w, axis=1)
    momentum = np.linalg.norm(inertia * w, axis=1)
    expected_energy = np.max(np.abs(energy / energy[0] - 1.0))
    expected_momentum = np.max(np.abs(momentum / momentum[0] - 1.0))
    assert abs(run.results["max_energy_error"][0] / expected_energy - 1.0) < 1e-3
    assert abs(run.results["max_momentum_magnitude_error"][0] / expected_momentum - 1.0) < 1e-3
    assert abs(expected_energy / expected_momentum - 1.0) > 0.5  # two measures, not one


def test_an_input_error_carries_its_place_and_fix():
    error = InputError("must be > 0, got -1.0", "give a positive mass", key="scene.body.mass")
    assert str(error) == "scene.body.mass: must be > 0, got -1.0; give a positive mass"
    placed = error.located("study.yaml", "sweep (body_mass[1] = -1.0)", ConfigError)
    assert isinstance(placed, ConfigError)
    assert (placed.source, placed.key, placed.message, placed.fix) == (
        "study.yaml",
        "sweep (body_mass[1] = -1.0): scene.body.mass",
        error.message,
        error.fix,
    )
    inner = InputError("bad row", source="nodes.csv", key="line 3")
    assert inner.located("study.yaml", "scene.nodes").source == "nodes.csv"  # the specific file


def test_a_dotted_path_through_a_number_is_one_line(tmp_path):
    path = write_study(tmp_path, sweep={"scene.body.mass.x": [1.0]})
    with pytest.raises(ConfigError) as error:
        load_study(path)
    assert str(error.value) == (
        f"{path}: sweep: scene.body.mass.x: "
        "scene.body.mass holds 1.0, not a mapping or list; sweep a "
        "path that exists in the study"
    )


def test_a_short_axis_names_the_key_it_needs(tmp_path):
    scene = {"body": {"inertia": [1.0, 2.0, 3.0]}, "duration": 0.5}
    path = write_study(tmp_path, scene=scene, sweep={"spin": [1.0]})
    with pytest.raises(ConfigError, match=r"sweep: scene.initial.angular_velocity: spin needs"):
        load_study(path)
