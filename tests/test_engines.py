"""MuJoCo's integrators as schemes (rbstudy/engines/mujoco.py): the conventions of its state,
agreement with rbstudy's own schemes where the formulations coincide, the order through a
sweep, and the install hint where mujoco is absent."""

import importlib
import sys

import numpy as np
import pytest
from conftest import LOADED, abaqus_mapping, final_orientation_errors, write_study
from scipy.spatial.transform import Rotation

from rbstudy.errors import SchemeError
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import run_batch
from rbstudy.physics.scenes import param_rows, scene_from_mapping
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import SCHEMES, get_scheme, unavailable_schemes

MUJOCO = ("mujoco_euler", "mujoco_implicitfast", "mujoco_implicit", "mujoco_rk4")
EXAMPLE = __import__("pathlib").Path(__file__).resolve().parents[1] / "examples" / "semi_implicit"


def test_without_mujoco_each_scheme_is_unavailable_with_the_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco raises ImportError
    monkeypatch.delitem(sys.modules, "rbstudy.engines.mujoco", raising=False)
    monkeypatch.setattr(SCHEMES, "_groups", {})  # loaded again on first use
    missing = unavailable_schemes()
    for name in MUJOCO:
        assert name not in SCHEMES
        assert missing[name].fix == 'pip install "mujoco>=4.0" (rbstudy\'s extra "engines")'
        with pytest.raises(SchemeError, match=r'needs the mujoco package; '
                                              r'pip install "mujoco>=4.0"'):
            get_scheme(name)


mujoco = pytest.importorskip("mujoco")


def _scene(**mapping):
    return scene_from_mapping(mapping, "test")


def _run(scheme, scenes, dt, n_steps):
    """Every step of ``scenes`` under ``scheme``: samples (B, n_steps + 1, N_STATE)."""
    chosen = get_scheme(scheme)
    return run_batch(chosen, np.array([scene.state_row() for scene in scenes]),
                     param_rows(scenes), np.zeros((len(scenes), S.N_OPTION)), dt, n_steps,
                     1).samples


@pytest.mark.parametrize("scheme", MUJOCO)
def test_a_body_at_rest_stays_where_it_is(scheme):
    """At rest, at an arbitrary place and orientation: every step leaves the state as it was
    (the quaternion's order is checked by the constant spins below)."""
    turned = Rotation.from_rotvec([0.3, -1.1, 0.7])
    scene = _scene(body={"mass": 2.0, "inertia": [1.0, 2.0, 3.0]}, duration=1.0,
                   initial={"position": [1.0, -2.0, 0.5],
                            "orientation": {"quaternion": turned.as_quat().tolist()},
                            "angular_velocity": {"body": [0.0, 0.0, 0.0]}})
    samples = _run(scheme, [scene], 0.01, 20)[0]
    assert np.all(np.isfinite(samples))
    np.testing.assert_allclose(samples - samples[0], 0.0, atol=1e-15)


@pytest.mark.parametrize("scheme", MUJOCO)
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_constant_spin_turns_the_body_about_its_own_axis(scheme, axis):
    """A spin about a principal axis is a steady rotation: R(t) = R0 exp(t [w]x) with w in
    the body frame. scipy's rotations give it; had MuJoCo's angular velocity been read in
    the world frame, the body would have turned about R0^T w instead (0.9 rad off here).
    The centre of mass moves at its constant world velocity."""
    turned = Rotation.from_rotvec([0.3, -1.1, 0.7])
    spin = np.zeros(3)
    spin[axis] = 2.5
    scene = _scene(body={"mass": 2.0, "inertia": [1.0, 2.0, 3.0]}, duration=1.0,
                   initial={"orientation": {"quaternion": turned.as_quat().tolist()},
                            "angular_velocity": {"body": spin.tolist()},
                            "velocity": [0.5, -0.25, 1.0]})
    dt, n_steps = 0.01, 80
    samples = _run(scheme, [scene], dt, n_steps)[0]
    times = dt * np.arange(n_steps + 1)
    expected = turned * Rotation.from_rotvec(times[:, None] * spin)
    reached = Rotation.from_quat(samples[:, S.QUATERNION:S.QUATERNION + 4])
    assert np.max((expected.inv() * reached).magnitude()) < 1e-12
    np.testing.assert_allclose(samples[:, S.OMEGA:S.OMEGA + 3], np.tile(spin, (n_steps + 1, 1)),
                               atol=1e-12)
    np.testing.assert_allclose(samples[:, S.POSITION:S.POSITION + 3],
                               times[:, None] * [0.5, -0.25, 1.0], atol=1e-12)
    wrong = Rotation.from_rotvec(times[:, None] * spin) * turned  # w taken in the world frame
    assert np.max((wrong.inv() * reached).magnitude()) > 0.5


def _scenes():
    return [_scene(**{**abaqus_mapping(), "duration": 2.0}),
            _scene(**{**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 2.0}),
            _scene(**LOADED)]


def _example_scheme():
    """The example plug-in's compiled scheme, imported from its folder (not installed)."""
    sys.path.insert(0, str(EXAMPLE))
    try:
        return importlib.import_module("rbstudy_semi_implicit.compiled").SCHEME
    finally:
        sys.path.remove(str(EXAMPLE))


def test_implicit_integrators_are_the_linearised_backward_euler_of_the_example():
    """MuJoCo's implicit and implicitfast, and the example plug-in written from the formula
    in its docstring, agree to round-off on a symmetric, an asymmetric and a loaded body."""
    scenes = _scenes()
    example = _example_scheme()
    states = np.array([scene.state_row() for scene in scenes])
    arguments = (states, param_rows(scenes), np.zeros((len(scenes), S.N_OPTION)), 0.01, 200, 1)
    expected = run_batch(example, *arguments).samples
    for scheme in ("mujoco_implicit", "mujoco_implicitfast"):
        got = run_batch(get_scheme(scheme), *arguments).samples
        assert np.max(np.abs(got - expected)) < 1e-12, scheme


def _difference(a, b, scenes, dt):
    return np.max(np.abs(simulate(scenes, a, dt, 0.01).output.samples
                         - simulate(scenes, b, dt, 0.01).output.samples), axis=(1, 2))


def test_rk4_and_euler_agree_with_rbstudys_to_the_order_of_the_step():
    """Where the formulations coincide, the difference shrinks with the schemes' order:
    RK4 against rk4 as h^4 on free bodies (the loaded one: as h, its loads held over
    MuJoCo's step); MuJoCo's semi-implicit Euler against rbstudy's explicit euler as h."""
    scenes = _scenes()
    coarse, fine = (_difference("mujoco_rk4", "rk4", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), [4.0, 4.0, 1.0], atol=0.1)
    assert np.all(coarse[:2] < 1e-7)
    coarse, fine = (_difference("mujoco_euler", "euler", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), 1.0, atol=0.15)


@pytest.mark.parametrize("scheme, order", [("mujoco_rk4", 4), ("mujoco_implicit", 1),
                                           ("mujoco_euler", 1)])
def test_each_shows_its_order_against_the_exact_solution(scheme, order):
    scene = _scene(**{**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 2.0})
    errors = final_orientation_errors(scene, scheme, [0.01, 0.005, 0.0025], 0.01)
    assert abs(np.log2(errors[-2] / errors[-1]) - order) < 0.15


def test_mujoco_schemes_sweep_into_the_archive(tmp_path):
    """Through the pipeline like any scheme: statuses, the engine's version in the archive,
    and orders from the archived errors."""
    import xarray as xr

    from rbstudy.cli import main
    config = write_study(tmp_path, name="engines", sweep={
        "scheme": ["mujoco_rk4", "mujoco_implicitfast"], "dt": [0.01, 0.005, 0.0025]},
        scene={**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 1.0})
    assert main(["sweep", str(config), "--out", str(tmp_path), "--quiet"]) == 0
    with xr.open_dataset(tmp_path / "engines" / "engines.nc") as ds:
        assert (ds["status"] == 0).all()
        assert set(ds["scheme_origin"].values) == {
            f"rbstudy's adapter of mujoco {mujoco.__version__}"}
        errors = ds["final_orientation_error"]
        for scheme, order in (("mujoco_rk4", 4), ("mujoco_implicitfast", 1)):
            e = errors.sel(scheme=scheme).values  # dt ascending: the finest first
            assert abs(np.log2(e[1] / e[0]) - order) < 0.2, scheme


@pytest.mark.parametrize("scheme", MUJOCO)
def test_a_state_mujoco_refuses_is_a_blow_up_of_that_body_alone(scheme, tmp_path, monkeypatch):
    """A body whose velocity MuJoCo judges unusable stops as unstable at its first step; the
    body beside it runs on, and MuJoCo leaves no log file behind."""
    monkeypatch.chdir(tmp_path)
    fine = _scene(**{**abaqus_mapping(), "duration": 1.0})
    wild = _scene(body={"mass": 1.0, "inertia": [1.0, 2.0, 3.0]}, duration=1.0,
                  initial={"angular_velocity": {"body": [0.0, 0.0, 0.0]},
                           "velocity": [2e10, 0.0, 0.0]})
    chosen = get_scheme(scheme)
    output = run_batch(chosen, np.array([fine.state_row(), wild.state_row()]),
                       param_rows([fine, wild]), np.zeros((2, S.N_OPTION)), 0.01, 50, 1)
    assert list(output.results["status"]) == [0, 1]
    assert output.results["failure_time"][1] == pytest.approx(0.01)
    assert np.all(np.isfinite(output.samples[0]))
    assert not list(tmp_path.iterdir())  # no MUJOCO_LOG.TXT
