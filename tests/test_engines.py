"""The engine adapters (rbstudy/engines/): each engine's schemes listed unavailable with the
install hint where its bindings are absent, and the conventions of its state on a body at rest
and on constant spins, for every adapter whose engine is installed; then MuJoCo's agreement
with rbstudy's own schemes where the formulations coincide, and its order through a sweep.
The other engines' agreements and orders are in tests/test_<engine>.py."""

import sys
from importlib.metadata import requires

import numpy as np
import pytest
from engine_cases import compared_scenes, difference, example_scheme, make_scene, run, swept_errors
from helpers import abaqus_mapping, final_orientation_errors
from packaging.requirements import Requirement
from scipy.spatial.transform import Rotation

from rbstudy.errors import SchemeError
from rbstudy.numerics import state as S
from rbstudy.numerics.driver import run_batch
from rbstudy.physics.scenes import param_rows
from rbstudy.schemes import SCHEMES, get_scheme, unavailable_schemes
from rbstudy.schemes._plugins import ENGINES

MUJOCO = ("mujoco_euler", "mujoco_implicitfast", "mujoco_implicit", "mujoco_rk4")
# Each adapter: the bindings it imports, the package and the rbstudy extra its install hint
# names (the extra must exist in pyproject.toml and hold the package: tested below).
BINDINGS = {
    "rbstudy.engines.mujoco": ("mujoco", "mujoco>=4.0", "mujoco"),
    "rbstudy.engines.bullet": ("pybullet", "pybullet>=3.2.7", "bullet"),
    "rbstudy.engines.exudyn": ("exudyn", "exudyn>=1.13.6", "exudyn"),
    "rbstudy.engines.drake": ("pydrake", "drake>=1.51", "drake"),
    "rbstudy.engines.rapier": ("rapier3d", "rapier3d>=0.36", "rapier"),
}

# Schemes that integrate the rotation's coordinates, not on the rotation group, and so miss a
# steady rotation by O(h^2): their bound on the constant spins (tests/test_<engine>.py shows
# the order), the other schemes' being 1e-12.
STEADY_SPIN_ERROR = {"exudyn_genalpha": 1e-3}  # Euler parameters as coordinates: 2.6e-4
# Engines that compute in float32, and the rounding their state then carries (rad, rad/s):
# the bound of their conventions tests (a steady spin gains up to 4e-7 rad a step), the others'
# being 1e-12 (1e-15 at rest).
FLOAT32 = {"rapier": 1e-4}  # 80 steps of a spin: up to 3.0e-5 rad
# How far an engine's rate of turn under a constant spin may be from the spin (rad/s) at
# dt = 0.01 s: Drake integrates dq/dt = q (0, w)/2 as any ODE, which turns a step by |w| dt
# only to O((|w| dt)^3) (tests/test_drake.py gives each scheme's turn), steadily; the
# others' rate is the spin's.
RATE_TOLERANCE = {"drake": 2e-4, "rapier": 1e-4}  # rapier: its turn is the Cayley map's


def _schemes_of(adapter):
    return [name for name, value in ENGINES.items() if value.split(":")[0] == adapter]


def test_every_adapter_names_its_bindings():
    assert {value.split(":")[0] for value in ENGINES.values()} == set(BINDINGS)


@pytest.mark.parametrize("adapter", sorted(BINDINGS))
def test_the_extra_an_install_hint_names_installs_that_engine(adapter):
    """The hint's extra is in rbstudy's installed metadata, holds the package, and `engines`
    holds that extra."""
    _, package, extra = BINDINGS[adapter]
    needs = [Requirement(line) for line in requires("rbstudy")]

    def of_extra(name):
        return [need for need in needs if need.marker and need.marker.evaluate({"extra": name})]

    assert package in {f"{need.name}{need.specifier}" for need in of_extra(extra)}
    assert extra in next(need.extras for need in of_extra("engines") if need.name == "rbstudy")


@pytest.mark.parametrize("adapter", sorted(BINDINGS))
def test_without_its_engine_each_scheme_is_unavailable_with_the_install_hint(adapter, monkeypatch):
    binding, package, extra = BINDINGS[adapter]
    fix = f'pip install "{package}" (rbstudy\'s extra "{extra}")'
    monkeypatch.setitem(sys.modules, binding, None)  # import <binding> raises ImportError
    monkeypatch.delitem(sys.modules, adapter, raising=False)
    monkeypatch.setattr(SCHEMES, "_groups", {})  # loaded again on first use
    missing = unavailable_schemes()
    for name in _schemes_of(adapter):
        assert name not in SCHEMES
        assert missing[name].fix == fix
        with pytest.raises(SchemeError, match=f"needs the {binding} package; "):
            get_scheme(name)


@pytest.fixture(params=sorted(ENGINES))
def engine_scheme(request):
    """Each engine adapter's scheme, skipped where its engine is not installed."""
    missing = unavailable_schemes().get(request.param)
    if missing is not None:
        pytest.skip(f"{request.param}: {missing.reason}")
    return request.param


def test_a_body_at_rest_stays_where_it_is(engine_scheme):
    """At rest, at an arbitrary place and orientation: every step leaves the state as it was
    (the quaternion's order is checked by the constant spins below)."""
    turned = Rotation.from_rotvec([0.3, -1.1, 0.7])
    scene = make_scene(
        body={"mass": 2.0, "inertia": [1.0, 2.0, 3.0]},
        duration=1.0,
        initial={
            "position": [1.0, -2.0, 0.5],
            "orientation": {"quaternion": turned.as_quat().tolist()},
            "angular_velocity": {"body": [0.0, 0.0, 0.0]},
        },
    )
    samples = run(engine_scheme, [scene], 0.01, 20)[0]
    assert np.all(np.isfinite(samples))
    np.testing.assert_allclose(samples - samples[0], 0.0, atol=FLOAT32.get(engine_scheme, 1e-15))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_a_constant_spin_turns_the_body_about_its_own_axis(engine_scheme, axis):
    """A spin about a principal axis is a steady rotation: R(t) = R0 exp(t [w]x) with w in
    the body frame. scipy's rotations give it; had the engine's angular velocity been read in
    the wrong frame, the body would have turned about R0^T w instead (0.9 rad off here).
    The centre of mass moves at its constant world velocity."""
    turned = Rotation.from_rotvec([0.3, -1.1, 0.7])
    spin = np.zeros(3)
    spin[axis] = 2.5
    scene = make_scene(
        body={"mass": 2.0, "inertia": [1.0, 2.0, 3.0]},
        duration=1.0,
        initial={
            "orientation": {"quaternion": turned.as_quat().tolist()},
            "angular_velocity": {"body": spin.tolist()},
            "velocity": [0.5, -0.25, 1.0],
        },
    )
    dt, n_steps = 0.01, 80
    samples = run(engine_scheme, [scene], dt, n_steps)[0]
    times = dt * np.arange(n_steps + 1)
    reached = Rotation.from_quat(samples[:, S.QUATERNION : S.QUATERNION + 4])
    if engine_scheme.split("_")[0] in RATE_TOLERANCE:  # the engine's turn of one step
        rate = (reached[0].inv() * reached[1]).magnitude() / dt
        assert rate == pytest.approx(2.5, abs=RATE_TOLERANCE[engine_scheme.split("_")[0]])
    else:
        rate = 2.5
    expected = turned * Rotation.from_rotvec(times[:, None] * spin * (rate / 2.5))
    bound = STEADY_SPIN_ERROR.get(engine_scheme, FLOAT32.get(engine_scheme, 1e-12))
    assert np.max((expected.inv() * reached).magnitude()) < bound
    np.testing.assert_allclose(samples[:, S.OMEGA : S.OMEGA + 3], np.tile(spin, (n_steps + 1, 1)), atol=bound)
    np.testing.assert_allclose(
        samples[:, S.POSITION : S.POSITION + 3], times[:, None] * [0.5, -0.25, 1.0], atol=1e-12
    )
    wrong = Rotation.from_rotvec(times[:, None] * spin) * turned  # w taken in the world frame
    assert np.max((wrong.inv() * reached).magnitude()) > 0.5


def test_a_body_in_a_batch_moves_as_it_does_alone(engine_scheme):
    """A body's numbers do not depend on the bodies beside it (an engine that steps a whole
    world at once must keep them apart)."""
    scenes = compared_scenes()
    together = run(engine_scheme, scenes, 0.01, 50)
    for k, scene in enumerate(scenes):
        np.testing.assert_array_equal(run(engine_scheme, [scene], 0.01, 50)[0], together[k])


mujoco = pytest.importorskip("mujoco")


def test_implicit_integrators_are_the_linearised_backward_euler_of_the_example():
    """MuJoCo's implicit and implicitfast, and the example plug-in written from the formula
    in its docstring, agree to round-off on a symmetric, an asymmetric and a loaded body."""
    scenes = compared_scenes()
    example = example_scheme()
    states = np.array([scene.state_row() for scene in scenes])
    arguments = (states, param_rows(scenes), np.zeros((len(scenes), S.N_OPTION)), 0.01, 200, 1)
    expected = run_batch(example, *arguments).samples
    for scheme in ("mujoco_implicit", "mujoco_implicitfast"):
        got = run_batch(get_scheme(scheme), *arguments).samples
        assert np.max(np.abs(got - expected)) < 1e-12, scheme


def test_rk4_and_euler_agree_with_rbstudys_to_the_order_of_the_step():
    """Where the formulations coincide, the difference shrinks with the schemes' order:
    RK4 against rk4 as h^4 on free bodies (the loaded one: as h, its loads held over
    MuJoCo's step); MuJoCo's semi-implicit Euler against rbstudy's explicit euler as h."""
    scenes = compared_scenes()
    coarse, fine = (difference("mujoco_rk4", "rk4", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), [4.0, 4.0, 1.0], atol=0.1)
    assert np.all(coarse[:2] < 1e-7)
    coarse, fine = (difference("mujoco_euler", "euler", scenes, dt) for dt in (0.01, 0.005))
    np.testing.assert_allclose(np.log2(coarse / fine), 1.0, atol=0.15)


@pytest.mark.parametrize("scheme, order", [("mujoco_rk4", 4), ("mujoco_implicit", 1), ("mujoco_euler", 1)])
def test_each_shows_its_order_against_the_exact_solution(scheme, order):
    scene = make_scene(**{**abaqus_mapping(inertia=[1.0, 2.0, 3.0]), "duration": 2.0})
    errors = final_orientation_errors(scene, scheme, [0.01, 0.005, 0.0025], 0.01)
    assert abs(np.log2(errors[-2] / errors[-1]) - order) < 0.15


@pytest.mark.slow
def test_mujoco_schemes_sweep_into_the_archive(tmp_path):
    """Through the pipeline like any scheme: statuses, the engine's version in the archive,
    and orders from the archived errors."""
    errors = swept_errors(
        tmp_path, ["mujoco_rk4", "mujoco_implicitfast"], f"rbstudy's adapter of mujoco {mujoco.__version__}"
    )
    for scheme, order in (("mujoco_rk4", 4), ("mujoco_implicitfast", 1)):
        e = errors.sel(scheme=scheme).values  # dt ascending: the finest first
        assert abs(np.log2(e[1] / e[0]) - order) < 0.2, scheme


def test_an_engines_forecast_is_its_calibrated_cost(tmp_path, monkeypatch):
    """An engine's adapter needs no compiling: the forecast measures it (once per machine) at
    a study's small batch, where each step's calls from Python cost ~0.1 ms a body, 10-30x
    the declared best-batch figure (which forecast "kernels ~0.3 s" for a run of 68 s). The
    forecast is then the study's body-steps at the figures measured, and the archive stores
    the same figures: one calibration for both (a bound on the forecast against the run's
    own time failed on a loaded machine: a timing is no test)."""
    from helpers import write_study

    from rbstudy.archive.load import open_results
    from rbstudy.pipeline import calibration
    from rbstudy.pipeline.config import load_study
    from rbstudy.pipeline.estimate import estimate
    from rbstudy.pipeline.execute import run_study
    from rbstudy.schemes import get_scheme

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))  # nothing measured yet
    schemes = ["mujoco_euler", "mujoco_rk4"]
    config = write_study(
        tmp_path,
        run={"scheme": "mujoco_euler", "dt": 0.01},
        scene={**abaqus_mapping(), "duration": 2.0},
        sweep={"scheme": schemes, "scene.body.mass": [1.0, 2.0, 3.0, 4.0]},
    )
    study = load_study(config)
    assert all(calibration.cached(get_scheme(name)) is None for name in schemes)
    forecast = estimate(study, cores=1)
    measured = {name: calibration.cached(get_scheme(name)) for name in schemes}
    assert all(cost is not None for cost in measured.values()), measured
    steps = 4 * 200  # four bodies of 2 s at dt = 0.01 s, each scheme
    assert forecast.scheme_seconds == pytest.approx(sum(steps * cost.seconds for cost in measured.values()))
    ds = open_results(run_study(study, tmp_path / "out", quiet=True).path)
    for name, cost in measured.items():
        stored = np.unique(ds["step_seconds"].sel(scheme=name).values)
        assert stored == pytest.approx([cost.seconds]), name


@pytest.mark.parametrize("scheme", MUJOCO)
def test_a_state_mujoco_refuses_is_a_blow_up_of_that_body_alone(scheme, tmp_path, monkeypatch):
    """A body whose velocity MuJoCo judges unusable stops as unstable at its first step; the
    body beside it runs on, and MuJoCo leaves no log file behind."""
    monkeypatch.chdir(tmp_path)
    fine = make_scene(**{**abaqus_mapping(), "duration": 1.0})
    wild = make_scene(
        body={"mass": 1.0, "inertia": [1.0, 2.0, 3.0]},
        duration=1.0,
        initial={"angular_velocity": {"body": [0.0, 0.0, 0.0]}, "velocity": [2e10, 0.0, 0.0]},
    )
    chosen = get_scheme(scheme)
    output = run_batch(
        chosen,
        np.array([fine.state_row(), wild.state_row()]),
        param_rows([fine, wild]),
        np.zeros((2, S.N_OPTION)),
        0.01,
        50,
        1,
    )
    assert list(output.results["status"]) == [0, 1]
    assert output.results["failure_time"][1] == pytest.approx(0.01)
    assert np.all(np.isfinite(output.samples[0]))
    assert not list(tmp_path.iterdir())  # no MUJOCO_LOG.TXT
