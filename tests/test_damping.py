"""The linear damping moment M = -C w (scene.loads.damping_moment): every scheme's order under
it, the energy it takes out, its closed form on a spherical body, and what a study of it
stores and refuses."""

import numpy as np
import pytest
from helpers import ROUND_OFF_FLOOR, write_study

from rbstudy.errors import InputError, SchemeError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.numerics import state as S
from rbstudy.numerics.loads import KIND
from rbstudy.physics.analytic import INTEGRATED
from rbstudy.physics.metrics import asymptotic_order, orientation_error
from rbstudy.physics.references import dop853_reference
from rbstudy.physics.simulate import simulate
from rbstudy.pipeline.config import load_study
from rbstudy.schemes import BUILTIN, SCHEMES

FIXED_STEP = [name for name, scheme in BUILTIN.items() if not scheme.adaptive]
# The symmetric schemes, whose kicks must stay their own inverse under damping to compose.
COMPOSABLE = [name for name, scheme in BUILTIN.items() if any(option.sets_order for option in scheme.options)]

# An asymmetric body tumbling under damping of a different strength about each axis and a
# moment fixed in space (so that a kick's other loads and its damping act together).
DAMPED = {
    "body": {"inertia": [1.0, 2.0, 3.0]},
    "initial": {
        "angular_velocity": {"body": [0.6, 1.5, 0.9]},
        "orientation": {"rotation_vector": [0.3, -0.2, 0.5]},
    },
    "loads": {"damping_moment": [0.3, 0.5, 0.8], "moment_space": [0.0, 0.15, 0.0]},
    "duration": 2.0,
}


def _orders(scene, name, dts, interval, options=None):
    """The fitted order of the final orientation error against DOP853 at 1e-13, and the
    errors."""
    runs = [simulate([scene], name, dt, interval, options) for dt in dts]
    reference = dop853_reference(scene, runs[0].time)
    errors = [orientation_error(run.quaternion[0, -1], reference.quaternion[-1]) for run in runs]
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    return order, used, errors


@pytest.mark.parametrize("name", FIXED_STEP)
def test_every_scheme_keeps_its_order_under_damping(name):
    scene = scene_from_mapping(DAMPED, source="test")
    order, used, errors = _orders(scene, name, 0.08 / 2.0 ** np.arange(5), 0.08)
    assert used.sum() >= 3 and abs(order - SCHEMES[name].order) <= 0.25, (order, errors)


@pytest.mark.parametrize("name", COMPOSABLE)
def test_the_symmetric_schemes_compose_to_order_4_under_damping(name):
    """The damped kick is the exact flow of its part, its own inverse at -d: a plain d M
    would leave the composition at order 2 (and the plain scheme at order 1)."""
    scene = scene_from_mapping(DAMPED, source="test")
    order, used, errors = _orders(scene, name, 0.2 / 2.0 ** np.arange(5), 0.2, {"composition": 4})
    assert used.sum() >= 3 and abs(order - 4.0) <= 0.25, (order, errors)


def test_the_energy_decays_at_the_rate_the_damping_takes_out():
    """dE/dt = -w.Cw (the space moment of DAMPED left out: it would work on the body too):
    the run's energy against the time integral of the damping's power along the run."""
    scene = scene_from_mapping({**DAMPED, "loads": {"damping_moment": [0.3, 0.5, 0.8]}}, source="test")
    dt = 1e-3
    run = simulate([scene], "rk4", dt, dt)
    w = run.field("omega_body")[0]
    inertia = np.array(scene.body.inertia)
    damping = np.array(scene.loads.damping_moment)
    energy = 0.5 * np.einsum("ti,i,ti->t", w, inertia, w)
    power = -np.einsum("ti,i,ti->t", w, damping, w)
    # Simpson's rule over pairs of steps: its error, ~dt^4, sits far below the decay
    lost = dt / 3.0 * (power[0:-1:2] + 4.0 * power[1::2] + power[2::2])
    assert energy[-1] < 0.5 * energy[0]  # it does decay
    np.testing.assert_allclose(energy[2::2] - energy[0], np.cumsum(lost), rtol=1e-9, atol=0.0)
    # and at every sample, the rate by central differences
    rate = (energy[2:] - energy[:-2]) / (2.0 * dt)
    np.testing.assert_allclose(rate, power[1:-1], rtol=1e-5)


@pytest.mark.parametrize("name", list(BUILTIN))
def test_a_spherical_body_decays_as_its_closed_form(name):
    """C = c I on a sphere of inertia J: w(t) = w0 exp(-c t / J), along w0 all the time.
    The splitting schemes whose free flow is exact on a sphere (midpoint, exact_split) meet
    it to round-off at any step; the others converge to it at their order."""
    c, inertia, w0 = 0.7, 2.0, np.array([0.3, -1.0, 2.0])
    scene = scene_from_mapping(
        {
            "body": {"inertia": [inertia] * 3},
            "initial": {"angular_velocity": {"body": w0.tolist()}},
            "loads": {"damping_moment": [c] * 3},
            "duration": 2.0,
        },
        source="test",
    )
    dts = 0.2 / 2.0 ** np.arange(5)
    errors = []
    for dt in dts:
        run = simulate([scene], name, dt, 0.2)
        exact = w0 * np.exp(-c * run.time / inertia)[:, None]
        errors.append(np.max(np.abs(run.field("omega_body")[0] - exact)) / np.linalg.norm(w0))
    if max(errors) <= ROUND_OFF_FLOOR:
        return  # exact at every step (dop853 at its 1e-13 tolerance too)
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3 and abs(order - SCHEMES[name].order) <= 0.25, (order, errors)


def test_a_damped_study_stores_no_conservation_error_and_sweeps_the_damping(tmp_path):
    """The damping turns the body: no closed form, so the reference is integrated; energy
    and momentum are not conserved, so their errors are not stored. Swept like any scene
    key, each case carries its coefficients in its parameter row."""
    scene = {**DAMPED, "loads": {"damping_moment": [0.3, 0.0, 0.8]}, "duration": 0.5}
    study = load_study(
        write_study(
            tmp_path,
            scene=scene,
            sweep={"scene.loads.damping_moment.0": [0.0, 0.3], "scene.loads.damping_moment.2": [0.0, 0.8]},
        )
    )
    assert not {"energy_error", "momentum_error", "max_energy_error", "flip_interval"} & set(study.variables)
    assert "orientation_error" in study.variables
    scenes = study.cases.scenes
    assert list(scenes.reference_kinds) == ["exact_asymmetric"] + [INTEGRATED] * 3
    assert list(scenes.moment_free) == [True, False, False, False]
    slot = slice(KIND["damping_moment"].offset, KIND["damping_moment"].offset + 3)
    rows = [case.scene.param_row() for case in study.cases]
    assert [row[slot].tolist() for row in rows] == [
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.8],
        [0.3, 0.0, 0.0],
        [0.3, 0.0, 0.8],
    ]
    assert all(len(row) == S.N_PARAM for row in rows)


def test_a_negative_damping_is_refused_by_its_key(tmp_path):
    scene = {**DAMPED, "loads": {"damping_moment": [0.3, -0.5, 0.8]}}
    with pytest.raises(InputError) as caught:
        load_study(write_study(tmp_path, scene=scene))
    assert str(caught.value).endswith(
        "scene.loads.damping_moment: got [0.3, -0.5, 0.8], below 0; give values >= 0 (N m s): "
        "it only takes energy out"
    )


def test_exudyn_refuses_the_damping_it_has_no_load_for():
    pytest.importorskip("exudyn")
    scene = scene_from_mapping({**DAMPED, "duration": 0.1}, source="test")
    with pytest.raises(SchemeError) as caught:
        simulate([scene], "exudyn_rk44", 0.01, 0.05)
    assert str(caught.value) == (
        "scheme exudyn_rk44 cannot take scene.loads.damping_moment; "
        "Exudyn has no such load: leave the scheme out"
    )


def test_hht_s_newton_takes_the_damping_s_jacobian():
    """Damping stiff at the step (h C / I up to 3): with the term C in its Jacobian, HHT's
    Newton converges in a few iterations a step; without it, a fixed-point-like iteration,
    it did not converge at dt = 0.1 and 0.05 and took 14 a step at 0.01."""
    scene = scene_from_mapping(
        {**DAMPED, "loads": {"damping_moment": [40.0, 60.0, 90.0]}, "duration": 1.0}, source="test"
    )
    for dt in (0.1, 0.05, 0.01):
        run = simulate([scene], "hht", dt, 0.1)
        assert run.results["status"][0] == 0, dt
        assert run.results["iterations"][0] <= 3 * run.results["n_steps"][0], dt
