"""The float64 floor (`float64_floor`): one ulp of the initial state carried by the exact
motion, measured against a 40-digit evaluation of the same perturbations; the findings and
fits that use it; `validate`'s warning when the accuracy bound lies below it."""

import mpmath as mp
import numpy as np
import pytest
import xarray as xr
import yaml
from free_body_mp import DIGITS, _qmul, exact_state
from helpers import CONFIGS

from rbstudy.analysis.findings import findings
from rbstudy.analysis.measures import FLOOR_FACTOR
from rbstudy.analysis.summary import scheme_rows
from rbstudy.cli import main
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.quaternions import quat_mul
from rbstudy.physics.references import ULP, reference_solution

EPS = float(np.finfo(float).eps)


def plate(duration=1000.0):
    spec = yaml.safe_load((CONFIGS / "long_run_convergence.yaml").read_text())["scene"]
    return scene_from_mapping({**spec, "duration": duration})


def perturbations(quaternion, omega):
    """The initial data `float64_floor` tries, as float arrays: w0 scaled by 1 + eps, moved
    by eps |w0| along each axis, the orientation turned by eps about each body axis."""
    size = np.linalg.norm(omega)
    moved = [(quaternion, omega * (1.0 + EPS))] + [
        (quaternion, omega + EPS * size * np.eye(3)[k]) for k in range(3)
    ]
    return moved + [(quat_mul(quaternion, np.r_[0.5 * EPS * np.eye(3)[k], 1.0]), omega) for k in range(3)]


def mp_angle(a, b):
    with mp.workdps(DIGITS):
        rel = _qmul((-a[0], -a[1], -a[2], a[3]), b)
        return float(2 * mp.atan2(mp.sqrt(rel[0] ** 2 + rel[1] ** 2 + rel[2] ** 2), abs(rel[3])))


@pytest.mark.slow
def test_floor_is_the_sensitivity_of_the_exact_motion_to_one_ulp():
    """The plate over 1000 s: the floor from float64 closed forms against the same seven
    perturbations carried by the exact motion in 40 digits, where nothing rounds. The floor
    is itself a float64 difference of two runs (each good to ~1e-13 at 1000 s): it is an
    order of magnitude, and the test asks that much of it."""
    assert ULP == EPS
    scene = plate()
    quaternion, omega = np.array(scene.quaternion), np.array(scene.omega_body)
    floor = reference_solution(scene, np.linspace(0.0, 1000.0, 3)).floor
    start = exact_state(scene.body.inertia, quaternion, omega, 1000.0)[0]
    exact = max(
        mp_angle(start, exact_state(scene.body.inertia, q, w, 1000.0)[0])
        for q, w in perturbations(quaternion, omega)
    )
    assert 3e-13 < exact < 1e-12  # one ulp of the spin, carried over 1000 s
    assert exact / 2.0 < floor < 2.0 * exact


def test_floor_grows_with_the_run_and_is_nan_for_an_integrated_reference(heavy_loaded_scene):
    short = reference_solution(plate(10.0), np.linspace(0.0, 10.0, 3)).floor
    long = reference_solution(plate(), np.linspace(0.0, 1000.0, 3)).floor
    assert 0.0 <= short < 1e-14 < long
    integrated = reference_solution(heavy_loaded_scene, np.linspace(0.0, 1.0, 11))
    assert integrated.name == "exact_split_composition" and np.isnan(integrated.floor)


@pytest.fixture
def heavy_loaded_scene():
    """An asymmetric body on a pivot: no closed form."""
    spec = yaml.safe_load((CONFIGS / "heavy_top.yaml").read_text())["scene"]
    spec["body"]["inertia"] = [0.2, 0.46875, 0.3]
    return scene_from_mapping({**spec, "duration": 1.0})


STUDY = """
name: plate_rk4
title: rk4 on the plate over 1000 s, compensated, down to the float64 floor
scene:
  body: {mass: 1.0, inertia: [0.35, 0.65, 1.0]}
  initial:
    angular_velocity: {body: [0.6, 1.5, 0.9]}
    orientation: {rotation_vector: [0.3, -0.2, 0.5]}
  duration: 1000.0
output:
  interval: 1.0
  variables: [final_orientation_error]
run: {scheme: rk4, dt: 0.005, options: {compensated: 1}}
sweep:
  dt: {halving: 0.005, count: 7}
"""


@pytest.fixture(scope="module")
def plate_rk4(tmp_path_factory):
    folder = tmp_path_factory.mktemp("floor")
    (folder / "plate_rk4.yaml").write_text(STUDY)
    assert main(["sweep", str(folder / "plate_rk4.yaml"), "--out", str(folder / "out"), "-q"]) == 0
    return xr.open_dataset(folder / "out" / "plate_rk4" / "plate_rk4.nc")


@pytest.mark.slow
def test_rk4_over_1000_s_reaches_the_floor_and_is_not_fitted_there(plate_rk4):
    """rk4 with compensated sums on the plate: the finest errors lie within 3x the floor and
    are said to; the fit runs over the steps above it (its slopes still settle onto 4: the
    dt^5 t^2 phase error of RK4's energy loss, docs/results.md)."""
    ds = plate_rk4
    floor = float(ds["float64_floor"])
    errors = ds["final_orientation_error"].squeeze()
    at_floor = errors["dt"].values[errors.values <= FLOOR_FACTOR * floor]
    assert at_floor.size >= 2 and at_floor.max() < 5e-4
    row = scheme_rows(ds)[0]
    assert row["float64_floor"] == (pytest.approx(floor), pytest.approx(at_floor.max()), False)
    assert row["fit_dt"][0] > at_floor.max()  # no order through the floor
    assert 4.0 <= row["order"][0] <= 4.5
    text = next(f.text for f in findings(ds) if f.text.startswith("rk4: "))
    assert f"at the float64 floor ({floor:.2g} rad) from dt = {at_floor.max():g} s" in text


def test_validate_warns_when_the_bound_lies_below_the_floor(tmp_path, capsys):
    study = tmp_path / "tight.yaml"
    study.write_text(STUDY.replace("interval: 1.0", "interval: 1.0\n  accuracy_bound: 1.0e-13"))
    assert main(["validate", str(study)]) == 0
    out = " ".join(capsys.readouterr().out.split())  # as one line, unwrapped
    assert "warning: output.accuracy_bound: 1e-13 rad lies below the float64 floor of 1 of 1 scenes" in out
    study.write_text(STUDY)
    assert main(["validate", str(study)]) == 0
    assert "float64 floor" not in capsys.readouterr().out
