"""Every registered scheme: observed order, claimed invariants, batch = case by case, loads."""

import math

import numpy as np
import pytest
from helpers import (
    EXACT_FLOW_TOLERANCE,
    EXACT_FOR_FREE_BODIES,
    FIXED_STEP,
    LOADED,
    ROUND_OFF_FLOOR,
    final_orientation_errors,
    independent_reference,
)

from rbstudy.errors import SchemeError
from rbstudy.inputs.scenes import scene_from_mapping
from rbstudy.physics.metrics import asymptotic_order, omega_error, orientation_error
from rbstudy.physics.references import reference_solution
from rbstudy.physics.simulate import simulate
from rbstudy.schemes import BUILTIN, SCHEMES, get_scheme

ORDER_TOLERANCE = 0.25


def assert_order(dts, errors, nominal):
    """The fitted order over the asymptotic range is within 0.25 of ``nominal``."""
    order, used, _ = asymptotic_order(dts, errors, floor=ROUND_OFF_FLOOR)
    assert used.sum() >= 3, f"too few points in the asymptotic range: {errors}"
    assert abs(order - nominal) <= ORDER_TOLERANCE, f"order {order:.3f}, errors {errors}"


def assert_order_on_a_free_body(name, dts, errors):
    """The nominal order, or round-off at every dt for a scheme exact for free bodies."""
    if name in EXACT_FOR_FREE_BODIES:
        assert np.max(errors) <= EXACT_FLOW_TOLERANCE, errors
    else:
        assert_order(dts, errors, SCHEMES[name].order)


@pytest.mark.parametrize("name", FIXED_STEP)
def test_observed_order_on_abaqus_top(name, abaqus_scene):
    dts = 0.01 / 2.0 ** np.arange(5)
    errors = final_orientation_errors(abaqus_scene, name, dts, 0.01)
    assert_order_on_a_free_body(name, dts, errors)


@pytest.mark.parametrize("name", FIXED_STEP)
def test_observed_order_on_asymmetric_body(name, asymmetric_scene):
    dts = 0.04 / 2.0 ** np.arange(5)
    errors = final_orientation_errors(asymmetric_scene, name, dts, 0.04)
    assert_order_on_a_free_body(name, dts, errors)


@pytest.mark.parametrize("name", FIXED_STEP)
def test_loads_keep_the_order(name):
    """Moments in body and space axes, a body-fixed force and gravity: still nominal order,
    in orientation and in the centre of mass (against the composed reference, or DOP853 for
    the scheme it is composed of)."""
    scene = scene_from_mapping(LOADED, source="test")
    dts = 0.08 / 2.0 ** np.arange(5)
    runs = [simulate([scene], name, dt, 0.08) for dt in dts]
    reference = independent_reference(scene, runs[0].time, name)
    rotation = [orientation_error(r.quaternion[0, -1], reference.quaternion[-1]) for r in runs]
    travel = np.linalg.norm(reference.position[-1] - reference.position[0])
    position = [np.linalg.norm(r.position[0, -1] - reference.position[-1]) / travel for r in runs]
    assert_order(dts, rotation, SCHEMES[name].order)
    assert_order(dts, position, SCHEMES[name].order)


@pytest.mark.parametrize("name", [n for n in FIXED_STEP if SCHEMES[n].keeps])
def test_claimed_invariants_to_round_off(name, asymmetric_scene):
    """Over 10,000 steps at h|w| ~ 0.05 the claimed invariants stay at round-off."""
    run = simulate([asymmetric_scene.with_changes(duration=300.0)], name, 0.03, 3.0)
    assert run.results["status"][0] == 0
    keeps = SCHEMES[name].keeps
    if "energy" in keeps:
        assert run.results["max_energy_error"][0] < 1e-12
    if {"momentum_magnitude", "momentum_vector"} & set(keeps):
        assert run.results["max_momentum_magnitude_error"][0] < 1e-12
    if "momentum_vector" in keeps:
        from rbstudy.physics.metrics import momentum_error

        vector = momentum_error(run.quaternion[0], run.omega_body[0], np.array(asymmetric_scene.body.inertia))
        assert np.max(vector) < 1e-12


def test_midpoint_keeps_energy_and_space_momentum_vector(asymmetric_scene):
    from rbstudy.physics.metrics import energy_error, momentum_error

    scene = asymmetric_scene.with_changes(duration=1000.0)
    run = simulate([scene], "midpoint", 0.1, 10.0)  # 10,000 steps, h |w| ~ 0.18
    assert run.results["n_steps"][0] == 10_000
    inertia = np.array(scene.body.inertia)
    assert np.max(np.abs(energy_error(run.omega_body[0], inertia))) < 1e-12
    assert np.max(momentum_error(run.quaternion[0], run.omega_body[0], inertia)) < 1e-12


def test_splitting_keeps_space_momentum_vector(asymmetric_scene):
    from rbstudy.physics.metrics import momentum_error

    scene = asymmetric_scene.with_changes(duration=1000.0)
    run = simulate([scene], "splitting", 0.1, 10.0)
    inertia = np.array(scene.body.inertia)
    assert np.max(momentum_error(run.quaternion[0], run.omega_body[0], inertia)) < 1e-12


@pytest.mark.parametrize("order", ["123", "312", "213"])
def test_no_squish_equals_dlm_to_round_off(order, asymmetric_scene):
    options = {"axis_order": order}
    dlm = simulate([asymmetric_scene], "splitting", 0.02, 0.2, options)
    nsq = simulate([asymmetric_scene], "no_squish", 0.02, 0.2, options)
    assert np.max(orientation_error(nsq.quaternion, dlm.quaternion)) < 1e-12
    assert np.max(omega_error(nsq.omega_body, dlm.omega_body)) < 1e-12


def test_axis_order_changes_the_answer(asymmetric_scene):
    a = simulate([asymmetric_scene], "splitting", 0.02, 0.2, {"axis_order": "123"})
    b = simulate([asymmetric_scene], "splitting", 0.02, 0.2, {"axis_order": "213"})
    assert np.max(orientation_error(a.quaternion, b.quaternion)) > 1e-6


@pytest.mark.parametrize("name", list(BUILTIN))
def test_batch_equals_case_by_case_bit_for_bit(name, abaqus_scene, asymmetric_scene):
    scenes = [
        abaqus_scene.with_changes(duration=1.0),
        asymmetric_scene.with_changes(duration=1.0),
        scene_from_mapping(LOADED, source="test").with_changes(duration=1.0),
    ] * 3
    batch = simulate(scenes, name, 0.01, 0.1)
    for i, scene in enumerate(scenes[:3]):
        alone = simulate([scene], name, 0.01, 0.1)
        assert np.array_equal(batch.quaternion[i], alone.quaternion[0])
        assert np.array_equal(batch.omega_body[i], alone.omega_body[0])
        assert np.array_equal(batch.position[i], alone.position[0])
        assert batch.results["iterations"][i] == alone.results["iterations"][0]


def test_hht_negative_alpha_damps_and_is_first_order_for_a_rigid_body(abaqus_scene):
    """With no internal forces HHT-alpha is Newmark with gamma = 1/2 - alpha: first order,
    and the nutation amplitude (|w1 + i w2| in the body) decays instead of staying at A."""
    dts = 0.01 / 2.0 ** np.arange(5)
    errors = final_orientation_errors(abaqus_scene, "hht", dts, 0.01, {"alpha": -0.1})
    assert_order(dts, errors, 1)
    damped = simulate([abaqus_scene], "hht", 0.01, 0.01, {"alpha": -0.1})
    undamped = simulate([abaqus_scene], "hht", 0.01, 0.01, {"alpha": 0.0})
    amplitude = lambda run: np.hypot(run.omega_body[0, -1, 0], run.omega_body[0, -1, 1])  # noqa: E731
    assert amplitude(damped) < 0.99 * 0.25
    assert abs(amplitude(undamped) - 0.25) < 1e-3


@pytest.mark.parametrize(
    "options, message",
    [
        ({"alpha": 0.2}, "option 'alpha': got 0.2; expected a number in [-0.333333, 0]"),
        ({"beta": 0.1}, "scheme 'hht' has no option 'beta'; its options: alpha"),
    ],
)
def test_bad_scheme_options_are_named(options, message):
    with pytest.raises(
        SchemeError,
        match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)").replace("]", r"\]"),
    ):
        get_scheme("hht").option_row(options)


def test_unknown_scheme_lists_the_valid_ones():
    with pytest.raises(SchemeError) as info:
        get_scheme("verlet")
    assert "unknown scheme 'verlet'; valid schemes: " in str(info.value)
    assert all(name in str(info.value) for name in SCHEMES)


def test_constant_axial_moment_is_exact_for_splitting_schemes():
    """Spin about e3 with a constant axial moment: w3 grows linearly, exactly."""
    scene = scene_from_mapping(
        {
            "body": {"inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.0, 0.0, 3.0]}},
            "loads": {"moment_body": [0.0, 0.0, 0.4]},
            "duration": 2.0,
        },
        source="test",
    )
    run = simulate([scene], "splitting", 0.01, 0.1)
    reference = reference_solution(scene, run.time)
    assert reference.name == "axial_moment"
    assert np.allclose(run.omega_body[0, :, 2], 3.0 + 0.2 * run.time, rtol=1e-14)
    assert np.max(orientation_error(run.quaternion[0], reference.quaternion)) < 1e-12


def test_gravity_parabola_and_free_rotation():
    scene = scene_from_mapping(
        {
            "body": {"mass": 3.0, "inertia": [1.0, 1.0, 2.0]},
            "initial": {"angular_velocity": {"body": [0.25, 0.0, 2 * math.pi]}, "velocity": [1.0, 2.0, 3.0]},
            "loads": {"gravity": [0.0, 0.0, -9.81], "force_space": [0.3, 0.0, 0.0]},
            "duration": 2.0,
        },
        source="test",
    )
    acceleration = np.array([0.1, 0.0, -9.81])
    for name in ("leapfrog", "splitting", "rk4", "hht"):
        run = simulate([scene], name, 0.01, 0.5)
        reference = reference_solution(scene, run.time)
        assert reference.name == "symmetric_top"
        error = run.position[0] - reference.position
        if name == "leapfrog":
            # v(-1/2) = v0 start: x_n = exact + a h t / 2, the first-order term, exactly
            expected = np.outer(run.time, acceleration) * 0.01 / 2
            assert np.allclose(error, expected, atol=1e-12)
        else:  # a constant force is integrated exactly by these
            assert np.max(np.abs(error)) < 1e-12
    assert math.isclose(reference.position[-1][2], 3.0 * 2.0 - 0.5 * 9.81 * 4.0)
