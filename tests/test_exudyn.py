"""Exudyn's solvers as schemes (rbstudy/engines/exudyn.py): what each computes, told by
agreement with rbstudy's schemes where the formulations coincide, their orders against the
exact solution, the spectral radius's damping, what Exudyn refuses, and that it writes and
prints nothing."""

import numpy as np
import pytest
from engine_cases import compared_scenes, difference, make_scene, swept_errors
from helpers import LOADED, abaqus_mapping, final_orientation_errors
from scipy.spatial.transform import Rotation

from rbstudy.errors import SchemeError
from rbstudy.numerics import state as S
from rbstudy.physics.scenes import param_rows
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import get_scheme

exudyn = pytest.importorskip("exudyn")

INERTIA = np.array([1.0, 2.0, 3.0])


def _asymmetric(duration):
    """I = (1, 2, 3) tumbling about no principal axis (tests/conftest.py's asymmetric body)."""
    return make_scene(
        body={"inertia": INERTIA.tolist()},
        duration=duration,
        initial={
            "angular_velocity": {"body": [0.6, 1.5, 0.9]},
            "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
        },
    )


def _energy_change(samples):
    """The relative change of the rotational energy over ``samples`` (T, N_STATE)."""
    w = samples[:, S.OMEGA : S.OMEGA + 3]
    energy = 0.5 * (INERTIA * w * w).sum(axis=1)
    return energy[-1] / energy[0] - 1.0


def test_rk44_on_the_lie_group_is_rkmk4_to_the_fifth_order():
    """Exudyn's RK44 with its Lie-group update and rbstudy's Runge-Kutta-Munthe-Kaas agree
    beyond their order on free bodies (the difference falls as h^5: the same h^4 error term);
    under constant loads, which Exudyn evaluates at every stage, to 1e-13."""
    scenes = compared_scenes()
    coarse, fine = (difference("exudyn_rk44", "rkmk4", scenes, dt) for dt in (0.01, 0.005))
    assert np.all(coarse < 1e-10)
    np.testing.assert_allclose(np.log2(coarse[:2] / fine[:2]), 5.0, atol=0.15)
    assert coarse[2] < 1e-12


# Exudyn's TestModels/explicitLieGroupIntegratorTest.py (github.com/jgerstmayr/EXUDYN,
# main/pythonDev/TestModels): a body of mass 15 with the inertia of a heavy top about its
# fixed point, free, its weight at the body point (0, 1, 0), spun at (0, 150, -4.61538)
# rad/s; the y component of the angular velocity in space at t = 2 s. Its comments give
# Exudyn's RK44 at h = 1e-3 and the value that RK67 and DOPRI5 converge to, both asserted
# below (the file's own assertion is on a sum of sensor values).
EXUDYN_RK44_OMEGA_Y = -106.16651966442174
EXUDYN_CONVERGED_OMEGA_Y = -106.16380414306643  # DOPRI5, atol 1e-14


def _space_spin_y(scheme):
    mass = 15.0
    top = make_scene(
        body={"mass": mass, "inertia": [0.234375 + mass, 0.46875, 0.234375 + mass]},
        duration=2.0,
        nodes={"top": [0.0, 1.0, 0.0]},
        initial={"angular_velocity": {"body": [0.0, 150.0, -4.61538]}},
        loads={"nodes": {"top": {"force_space": [0.0, 0.0, -mass * 9.81]}}},
    )
    end = simulate([top], scheme, 1e-3, 2.0).output.samples[0, -1]
    return Rotation.from_quat(end[S.QUATERNION : S.QUATERNION + 4]).apply(end[S.OMEGA : S.OMEGA + 3])[1]


def test_exudyns_own_test_of_its_lie_group_rk44_is_reproduced():
    """exudyn_rk44 gives Exudyn's own figure to 1e-13 (the weight at a body point goes in
    as Exudyn's load there, evaluated at every stage); rbstudy's reference, DOP853, gives
    the converged one to 1e-11: the same body in both codes."""
    assert _space_spin_y("exudyn_rk44") == pytest.approx(EXUDYN_RK44_OMEGA_Y, rel=1e-13)
    assert _space_spin_y("dop853") == pytest.approx(EXUDYN_CONVERGED_OMEGA_Y, rel=1e-11)


@pytest.mark.parametrize(
    "scheme, order", [("exudyn_genalpha", 2), ("exudyn_rk44", 4), ("exudyn_midpoint", 2)]
)
@pytest.mark.slow
def test_each_shows_its_order_on_an_asymmetric_body(scheme, order):
    errors = final_orientation_errors(_asymmetric(4.0), scheme, [0.01, 0.005, 0.0025], 0.04)
    np.testing.assert_allclose(np.log2(errors[:-1] / errors[1:]), order, atol=0.1)


@pytest.mark.parametrize("scheme, order", [("exudyn_genalpha", 2), ("exudyn_rk44", 4)])
def test_constant_loads_are_exudyns_own_and_keep_the_order(scheme, order):
    """The loaded body (moments and forces in space and body axes, gravity): Exudyn evaluates
    its loads at every stage and iterate, so its schemes keep their order (held over the
    step, as loads tabulated in time are, they would be of order 1)."""
    errors = final_orientation_errors(make_scene(**LOADED), scheme, [0.01, 0.005, 0.0025], 0.01)
    np.testing.assert_allclose(np.log2(errors[:-1] / errors[1:]), order, atol=0.1)


def test_loads_tabulated_in_time_are_held_over_the_step():
    """A moment tabulated as a constant in time is the constant moment held over each step:
    the two runs differ by O(h)."""
    held = {"moment_body": {"table": [[0.0, 0.2, -0.1, 0.3], [5.0, 0.2, -0.1, 0.3]]}}
    scenes = [make_scene(**{**LOADED, "loads": loads}) for loads in ({"moment_body": [0.2, -0.1, 0.3]}, held)]
    coarse, fine = (
        np.max(np.abs(np.diff(simulate(scenes, "exudyn_rk44", dt, 0.01).output.samples, axis=0)))
        for dt in (0.01, 0.005)
    )
    assert coarse > 1e-4
    assert np.log2(coarse / fine) == pytest.approx(1.0, abs=0.1)


def test_on_the_abaqus_top_generalized_alpha_is_of_hhts_order_with_a_larger_error():
    """The Abaqus top (2 s) under Exudyn's generalized alpha and rbstudy's HHT (the Abaqus
    step): both of order 2, but Exudyn's error is 13 times HHT's at its default radius. HHT
    turns the frame by the exponential map and keeps the spin w3 exactly; Exudyn integrates
    the Euler parameters as coordinates, which misses the fast spin's phase by O(h^2)."""
    top = make_scene(**abaqus_mapping())
    errors = {
        scheme: final_orientation_errors(top, scheme, [0.01, 0.005, 0.0025], 0.01)
        for scheme in ("exudyn_genalpha", "hht")
    }
    for scheme, e in errors.items():
        np.testing.assert_allclose(np.log2(e[:-1] / e[1:]), 2.0, atol=0.05, err_msg=scheme)
    assert 5.0 < errors["exudyn_genalpha"][0] / errors["hht"][0] < 30.0


def test_generalized_alpha_on_euler_parameters_misses_a_steady_spin_by_h_squared():
    """The Euler parameters are integrated as coordinates, not on the rotation group: a
    spin about a principal axis is not kept exactly (the bound of tests/test_engines.py),
    and the miss falls as h^2. Exudyn's Lie-group solvers keep it to round-off."""
    scene = make_scene(
        body={"inertia": INERTIA.tolist()},
        duration=1.0,
        initial={"angular_velocity": {"body": [0.0, 2.5, 0.0]}},
    )
    misses = {}
    for scheme in ("exudyn_genalpha", "exudyn_midpoint"):
        for dt in (0.01, 0.005):
            run = simulate([scene], scheme, dt, 0.01)
            exact = Rotation.from_rotvec(run.time[:, None] * [0.0, 2.5, 0.0])
            reached = Rotation.from_quat(run.quaternion[0])
            misses[scheme, dt] = np.max((exact.inv() * reached).magnitude())
    assert misses["exudyn_genalpha", 0.01] > 1e-5
    assert np.log2(misses["exudyn_genalpha", 0.01] / misses["exudyn_genalpha", 0.005]) == pytest.approx(
        2.0, abs=0.1
    )
    assert misses["exudyn_midpoint", 0.01] < 1e-12


@pytest.mark.slow
def test_the_spectral_radius_sets_the_damping():
    """Over 20 s at dt = 0.01 s, generalized alpha at spectral radius 0 (the most numerical
    damping) loses ten times the energy it loses at Exudyn's default 0.9; near 1 the index-3
    constraint leaves it unstable (at 0.999 the run stops before 20 s)."""
    changes = {
        rho: simulate([_asymmetric(20.0)], "exudyn_genalpha", 0.01, 1.0, {"spectral_radius": rho})
        for rho in (0.0, 0.9, 0.999)
    }
    damped, default = (_energy_change(changes[rho].output.samples[0]) for rho in (0.0, 0.9))
    assert damped < 0.0
    assert abs(default) < abs(damped) / 10.0
    assert changes[0.999].status_names == ["unstable"]


@pytest.mark.parametrize("value", [1.0, -0.1, "high"])
def test_a_spectral_radius_outside_zero_to_one_is_refused(value):
    with pytest.raises(SchemeError, match=r"option 'spectral_radius'.*\[0, 1\)"):
        get_scheme("exudyn_genalpha").option_row({"spectral_radius": value})


def test_the_explicit_solvers_refuse_euler_parameter_nodes():
    """Why the explicit schemes use rotation-vector nodes: Exudyn's explicit solver refuses a
    node with an algebraic equation (the unit norm of the Euler parameters)."""
    from rbstudy.engines import exudyn as adapter

    kind = adapter._Kind(exudyn.DynamicSolverType.RK44, euler_parameters=True)
    top = make_scene(**abaqus_mapping())
    with pytest.raises(exudyn.ModelError, match="algebraic variables"):
        adapter._Body(kind, kind.node(top.state_row()[None, :])[0], param_rows([top])[0], 0.01, 0.9)


def test_a_failed_newton_stops_that_body_and_nothing_is_written_or_printed(tmp_path, monkeypatch, capfd):
    """A spin too fast for generalized alpha's Newton at this step ends the body as
    not converged; Exudyn leaves no file in the working folder and prints nothing."""
    monkeypatch.chdir(tmp_path)
    wild = make_scene(
        body={"inertia": INERTIA.tolist()},
        duration=0.5,
        initial={"angular_velocity": {"body": [300.0, 1000.0, 200.0]}},
    )
    calm = make_scene(**{**abaqus_mapping(), "duration": 0.5})
    run = simulate([calm, wild], "exudyn_genalpha", 0.01, 0.01)
    assert run.status_names == ["ok", "not_converged"]
    assert run.results["failure_time"][1] == pytest.approx(0.01)
    assert not list(tmp_path.iterdir())
    assert capfd.readouterr() == ("", "")


@pytest.mark.slow
def test_exudyn_schemes_sweep_into_the_archive(tmp_path):
    """Through the pipeline like any scheme: the engine's version in the archive, the
    spectral radius swept as an option, and orders from the archived errors."""
    errors = swept_errors(
        tmp_path,
        ["exudyn_genalpha", "exudyn_rk44"],
        f"rbstudy's adapter of Exudyn {exudyn.__version__}",
        **{"run.options.spectral_radius": [0.5, 0.9]},
    )
    for scheme, order in (("exudyn_genalpha", 2), ("exudyn_rk44", 4)):
        e = errors.sel(scheme=scheme).isel(spectral_radius=-1).values  # finest first
        assert abs(np.log2(e[1] / e[0]) - order) < 0.2, scheme
